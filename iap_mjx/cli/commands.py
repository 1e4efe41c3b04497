"""The commands over presets and run directories: ``presets``, ``show``, ``train``, ``eval``,
``video``, ``attended``, ``figures`` and ``runs``, one function each (``cmd_<command>``) and one
parser builder each (``_add_<command>``), and ``add_commands``, which calls the builders to wire
them into the ``iap-mjx`` parser. JAX is imported inside the commands, after
:func:`iap_mjx.cli.main` has split the CPU into devices and turned on the compilation cache.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import dataclasses
import json
import shlex
import sys
import time
from pathlib import Path
from typing import Any

from iap_mjx import configs
from iap_mjx.cli import arguments
from iap_mjx.cli.arguments import usage_error
from iap_mjx.configs.training import EVAL_SEED


def cmd_presets(args: argparse.Namespace) -> int:
    """Lists the presets with their descriptions."""
    width = max(len(name) for name in configs.names())
    for name in configs.names():
        print(f"{name:<{width}}  {configs.describe(name)}")
    return 0


def resolve_target(target: str, overrides: list[str]):
    """The ``TrainConfig`` of a preset name or of a run directory's ``config.json``, with
    ``overrides`` applied (``ValueError`` naming the problem otherwise)."""
    from iap_mjx.es import metrics_log

    if Path(target).is_dir():
        try:
            config = configs.TrainConfig.from_dict(metrics_log.read_config(target))
        except FileNotFoundError as error:
            raise ValueError(f"{error}: {target!r} is a directory, not a run directory") from None
    else:
        config = configs.get(target)
    return configs.apply_overrides(config, overrides)


def cmd_show(args: argparse.Namespace) -> int:
    """Prints the resolved config of a preset (or run directory) with overrides, and what it
    builds: every env setting, the policy's settings and its number of parameters. A run
    directory is built as its checkpoint is loaded (``es.results.without_initialisation``: the file a
    low level started from need not exist here), and its stored config is printed as it is."""
    try:
        config = resolve_target(args.target, args.overrides)
        from iap_mjx import envs, es
        from iap_mjx.es.results import without_initialisation

        parts = es.build(without_initialisation(config) if Path(args.target).is_dir() else config)
    except ValueError as error:
        return usage_error(error)
    env, policy = parts.env, parts.policy
    view = {
        "config": config.to_dict(),
        "env": {
            "settings": dataclasses.asdict(envs.check_spec(config.env)),
            "observation_shape": env.observation_shape,
            "action_size": env.action_size,
            "env_steps_per_episode": env.episode_length,
        },
        "policy": {
            "settings": dataclasses.asdict(policy) if dataclasses.is_dataclass(policy) else repr(policy),
            "parameters": parts.num_dims,
            **(
                {"parameters_per_level": parts.policy.level_param_counts(parts.template_params)}
                if hasattr(parts.policy, "level_param_counts")
                else {}
            ),
        },
        "env_steps_per_iteration": parts.steps_per_iteration,
    }
    print(json.dumps(view, indent=2, default=str))
    return 0


def default_run_dir(preset: str) -> Path:
    """``runs/<preset>-<UTC time>`` under the current directory."""
    return Path("runs") / f"{preset}-{time.strftime('%Y%m%d-%H%M%S', time.gmtime())}"


def cmd_train(args: argparse.Namespace) -> int:
    """Trains a preset with overrides; resumes if ``--run-dir`` holds a checkpoint."""
    try:
        config = configs.apply_overrides(configs.get(args.preset), args.overrides)
    except ValueError as error:
        return usage_error(error)
    if not args.coordinator and (args.num_processes != 1 or args.process_id != 0):
        return usage_error(
            ValueError("--num-processes and --process-id join several processes: give --coordinator too")
        )
    if args.coordinator:
        from iap_mjx.es import distributed

        try:
            distributed.initialize(args.coordinator, args.num_processes, args.process_id)
        except ValueError as error:
            return usage_error(error)
    import jax

    from iap_mjx import es
    from iap_mjx.es.bookkeeping import check_resumable
    from iap_mjx.viz import artifacts

    run_dir = Path(args.run_dir) if args.run_dir else default_run_dir(args.preset)
    video_program = None
    try:
        primary = jax.process_index() == 0  # several processes share one run directory: one writes
        env, policy = es.make_env_and_policy(config)  # built once: the run trains and films these
        check_resumable(config, run_dir)  # a run directory of another config: refused before any compile
        print(f"run directory: {run_dir}", file=sys.stderr)  # named once every setting is checked
        video_program = artifacts.compile_video_in_background(env, policy) if primary else None
        result = es.train(config, run_dir=run_dir, progress=not args.no_progress, env=env, policy=policy)
    except ValueError as error:
        _settle(video_program)
        return usage_error(error)
    except KeyboardInterrupt:
        _settle(video_program)
        return interrupted(args, run_dir)
    if not primary:
        return 0
    written = artifacts.write_run_artifacts(result, run_dir, video_program)
    print(json.dumps(train_summary(result.history, run_dir, config.run.iterations, written)))
    return 0


def _settle(future: concurrent.futures.Future | None) -> None:
    """Waits for a background compile still running before the command returns: the process
    must not exit with XLA compiling in a daemon thread, which aborts it (exit status 134)."""
    if future is not None and not future.done():
        print("waiting for the video's background compile to end before exiting", file=sys.stderr)
        concurrent.futures.wait([future])


def interrupted(args: argparse.Namespace, run_dir: Path) -> int:
    """After Ctrl-C in ``train``: says which checkpoint stands and the command that resumes
    from it; the exit code 130."""
    from iap_mjx.es import checkpoint

    step = checkpoint.latest_step(run_dir)
    saved = f"last checkpoint: iteration {step}" if step is not None else "no checkpoint yet"
    # the overrides before the options: argparse takes positionals in one run
    resume = shlex.join(["iap-mjx", "train", args.preset, *args.overrides, "--run-dir", str(run_dir)])
    print(f"\ninterrupted; {saved}. Resume with: {resume}", file=sys.stderr)
    return 130


def train_summary(history: list[dict[str, Any]], run_dir: Path, iterations: int, written: list[Path]) -> dict[str, Any]:
    """The JSON line ``train`` prints last: the run directory, its iterations, the artifacts
    written and the last evaluation return (when the run evaluates its centre)."""
    summary: dict[str, Any] = {
        "run_dir": str(run_dir),
        "iterations": iterations,
        "artifacts": [str(path) for path in written],
    }
    last = next((row for row in reversed(history) if "eval_return" in row), None)
    if last is not None:
        summary["eval_return"] = last["eval_return"]
    return summary


def cmd_eval(args: argparse.Namespace) -> int:
    """Evaluates a run's latest checkpoint on fresh seeds, in the run's env or in the condition
    its overrides set (``env.*``, ``policy.blind``); prints mean and std return (and the mean of
    each per-episode statistic the env keeps, e.g. the quadruped course's ``walls_passed_mean``)."""
    from iap_mjx import es  # here, not at import: it loads jax, which main's runtime.setup precedes

    try:
        results = es.evaluate_run_episodes(
            args.run_dir, episodes=args.episodes, seed=args.seed, overrides=tuple(args.overrides)
        )
    except (FileNotFoundError, ValueError) as error:
        return usage_error(error)
    returns = results.pop("return")
    print(
        json.dumps(
            {
                "run_dir": str(args.run_dir),
                "overrides": list(args.overrides),
                "episodes": int(len(returns)),
                "return_mean": float(returns.mean()),
                "return_std": float(returns.std()),
                "returns": [float(r) for r in returns],
                **{f"{name}_mean": float(values.mean()) for name, values in results.items()},
            }
        )
    )
    return 0


def cmd_attended(args: argparse.Namespace) -> int:
    """Prints what an attention policy's selected patches show, share per geom, over episodes
    of a run's latest checkpoint (in the run's env or the condition its overrides set)."""
    from iap_mjx import es
    from iap_mjx.viz import attended

    try:
        result = es.in_condition(es.load_run(args.run_dir), args.overrides)
        counts = attended.episode_counts(
            result.env, result.policy, result.params, episodes=args.episodes, seed=args.seed, obs_stats=result.obs_stats
        )
    except (FileNotFoundError, ValueError) as error:
        return usage_error(error)
    print(attended.markdown(counts))
    return 0


def cmd_video(args: argparse.Namespace) -> int:
    """Renders an episode of a run's latest checkpoint: a pixel agent's view with the selected
    patches outlined, or a state agent's env from its video camera."""
    from iap_mjx import es
    from iap_mjx.viz import artifacts

    try:
        result = es.in_condition(es.load_run(args.run_dir), args.overrides)
        if args.strip:
            path, episode_return = artifacts.write_strip(result, args.strip, seed=args.seed, frames=args.frames)
            print(json.dumps({"strip": str(path), "return": episode_return}))
            return 0
        out = Path(args.out) if args.out else Path(args.run_dir) / "episode.mp4"
        path, episode_return = artifacts.write_episode_video(result, out, seed=args.seed, steps=args.steps)
    except (FileNotFoundError, ValueError) as error:
        return usage_error(error)
    print(json.dumps({"video": str(path), "return": episode_return}))
    return 0


def cmd_figures(args: argparse.Namespace) -> int:
    """Writes a figure set (``mse``: the paper's Figures 3 and 4) as PNGs."""
    from iap_mjx.viz import mse_figures

    for path in mse_figures.write_mse_figures(args.out, draws=args.draws):
        print(path)
    return 0


def cmd_runs(args: argparse.Namespace) -> int:
    """Prints a markdown table of the run directories in ``args.folder``: what each trains, how
    far it has got, its evaluations (``iap_mjx.es.listing``); with ``--results``, also writes
    it as that file's ``runs`` section."""
    from iap_mjx.es import listing
    from iap_mjx.sections import write_section

    folder = Path(args.folder)
    if not folder.is_dir():
        return usage_error(ValueError(f"folder {str(folder)!r}: not a directory"))
    found = listing.run_dirs(folder)
    if not found:
        return usage_error(ValueError(f"folder {str(folder)!r}: no run directory in it (a config.json)"))
    try:
        markdown = listing.table([listing.listed(run) for run in found], relative_to=folder)
    except ValueError as error:
        return usage_error(error)
    if args.results is not None:
        write_section(Path(args.results), "runs", markdown, title=f"# The runs in {folder}")
    print(markdown)
    return 0


def _add_presets(commands: Any) -> None:
    presets = commands.add_parser("presets", help="list the named presets")
    presets.set_defaults(func=cmd_presets, command_parser=presets)


def _add_show(commands: Any) -> None:
    show = commands.add_parser(
        "show",
        help="print a preset's resolved config",
        description="Print the config PRESET (or a run directory's config.json) resolves to "
        "with key=value overrides, every env setting, the policy's settings and "
        "its parameter count, building nothing that compiles.",
    )
    show.add_argument("target", metavar="PRESET", help="a name from `iap-mjx presets`, or a run directory")
    show.add_argument("overrides", nargs="*", metavar="key=value")
    show.set_defaults(func=cmd_show, command_parser=show)


def _add_train(commands: Any) -> None:
    train = commands.add_parser(
        "train",
        help="train a preset",
        description="Train PRESET with key=value overrides (e.g. es.population_size=128 "
        "run.iterations=50 es.sigma=0.05). Re-running with the same "
        "--run-dir resumes from its latest checkpoint; Ctrl-C saves one.",
    )
    train.add_argument("preset", help="a name from `iap-mjx presets`")
    train.add_argument("overrides", nargs="*", metavar="key=value")
    train.add_argument("--run-dir", help="where metrics and checkpoints go (default: runs/PRESET-TIME)")
    train.add_argument("--no-progress", action="store_true", help="no progress bar")
    train.add_argument(
        "--coordinator", metavar="HOST:PORT", help="multi-host: the coordinator address (see iap_mjx.es.distributed)"
    )
    train.add_argument("--num-processes", type=arguments.count, default=1, help="multi-host: processes")
    train.add_argument("--process-id", type=arguments.index, default=0, help="multi-host: this process")
    train.set_defaults(func=cmd_train, command_parser=train)


def _add_run_and_condition(parser: argparse.ArgumentParser, whose: str) -> None:
    """A command's run directory, and the condition its episodes run in (the run's own unless
    overridden: ``iap_mjx.es.results.in_condition``)."""
    parser.add_argument("run_dir")
    parser.add_argument(
        "overrides",
        nargs="*",
        metavar="key=value",
        help=f"the {whose} condition, e.g. env.distraction=none, env.dynamic=true, "
        "env.background_videos=val (held-out backgrounds), policy.blind=true (a hierarchical "
        "policy with its eyes closed)",
    )


def _add_eval(commands: Any) -> None:
    evaluate = commands.add_parser("eval", help="evaluate a run's latest checkpoint")
    _add_run_and_condition(evaluate, "evaluation's")
    evaluate.add_argument("--episodes", type=arguments.count, default=8)
    evaluate.add_argument(
        "--seed",
        type=int,
        default=EVAL_SEED,
        help=f"evaluation seed (default {EVAL_SEED}: the paper's tables', so their episodes; distinct from the "
        "training seeds)",
    )
    evaluate.set_defaults(func=cmd_eval, command_parser=evaluate)


def _add_video(commands: Any) -> None:
    video = commands.add_parser(
        "video", help="render an episode (pixel agents: the selected patches outlined; state agents: the env's camera)"
    )
    _add_run_and_condition(video, "episode's")
    video.add_argument("--out", help="output .mp4 or .gif (default: RUN_DIR/episode.mp4)")
    video.add_argument("--seed", type=int, default=0, help="episode seed")
    video.add_argument(
        "--steps", type=arguments.count, default=None, help="env steps, one action each (default: the episode)"
    )
    video.add_argument(
        "--strip",
        default=None,
        metavar="PNG",
        help="instead of a video, a PNG of --frames frames evenly spaced over the episode",
    )
    video.add_argument("--frames", type=arguments.count, default=6, help="frames in a --strip (default 6)")
    video.set_defaults(func=cmd_video, command_parser=video)


def _add_attended(commands: Any) -> None:
    look = commands.add_parser(
        "attended",
        help="what an attention policy's selected patches show, share per geom",
        description="Runs episodes of a run's latest checkpoint and prints the share of "
        "the selected patches' pixels that show each geom of the scene or the "
        "background (sky or distraction picture).",
    )
    _add_run_and_condition(look, "episodes'")
    look.add_argument("--episodes", type=arguments.count, default=3)
    look.add_argument("--seed", type=int, default=0, help="episode seed")
    look.set_defaults(func=cmd_attended, command_parser=look)


def _add_figures(commands: Any) -> None:
    figures = commands.add_parser(
        "figures",
        help="write the paper's figures as PNGs",
        description="mse: Figures 3 and 4 (MSE of the trig, exp and hybrid estimators, "
        "closed forms with Monte Carlo points).",
    )
    figures.add_argument("which", choices=["mse"])
    figures.add_argument("--out", default="figures", help="output directory (default: figures)")
    figures.add_argument("--draws", type=arguments.count, default=100_000, help="Monte Carlo draws per point")
    figures.set_defaults(func=cmd_figures, command_parser=figures)


def _add_runs(commands: Any) -> None:
    runs = commands.add_parser(
        "runs",
        help="list the run directories in a folder",
        description="A markdown table of every run directory in FOLDER (or below): env, policy, "
        "seed, parameters, checkpoint against the iterations asked for, the last logged "
        "evaluation return and the evaluations stored beside the checkpoint (eval.json). "
        "Reads files only: nothing is built or compiled.",
    )
    runs.add_argument("folder", nargs="?", default="runs", help="default: runs")
    runs.add_argument(
        "--results", default=None, metavar="FILE.md", help="also write the table as this file's runs section"
    )
    runs.set_defaults(func=cmd_runs, command_parser=runs)


def add_commands(commands: Any) -> None:
    """Adds this module's commands to the ``iap-mjx`` subparsers ``commands``, in the order
    ``iap-mjx --help`` lists them; each ``_add_<command>`` sets ``func`` to its command function
    and ``command_parser`` to its parser."""
    _add_presets(commands)
    _add_show(commands)
    _add_train(commands)
    _add_eval(commands)
    _add_video(commands)
    _add_attended(commands)
    _add_figures(commands)
    _add_runs(commands)
