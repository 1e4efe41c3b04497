"""The ``iap-mjx`` command line: ``presets``, ``show``, ``train``, ``eval``, ``video``, ...

One small function per command; ``build_parser`` wires them to ``argparse`` subparsers, so a
new command is a new ``add_parser`` call and a function. JAX is imported only inside the
commands, after ``main`` has split the CPU into devices and turned on the compilation cache.

It is one module at over 400 lines because the command line is one ``argparse`` tree: most of
the length is ``build_parser`` (half of it ``reproduce``'s options) and one short function per
command, the longest of which (``cmd_reproduce``) only hands each figure to its own module.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
import time
from pathlib import Path
from typing import Any

from iap_mjx import runtime

logger = logging.getLogger("iap_mjx.cli")


def cmd_presets(args: argparse.Namespace) -> int:
    """Lists the presets with their descriptions."""
    from iap_mjx import configs

    width = max(len(name) for name in configs.names())
    for name in configs.names():
        print(f"{name:<{width}}  {configs.describe(name)}")
    return 0


def resolve_target(target: str, overrides: list[str]):
    """The ``TrainConfig`` of a preset name or of a run directory's ``config.json``, with
    ``overrides`` applied (``ValueError`` naming the problem otherwise)."""
    from iap_mjx import configs
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
    builds: every env setting, the policy's settings and its number of parameters."""
    import dataclasses

    try:
        config = resolve_target(args.target, args.overrides)
        from iap_mjx import es

        parts = es.build(config)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    env, policy = parts.env, parts.policy
    view = {
        "config": config.to_dict(),
        "env": {
            "settings": dataclasses.asdict(env.config),
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
    from iap_mjx import configs

    try:
        config = configs.apply_overrides(configs.get(args.preset), args.overrides)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if args.coordinator:
        from iap_mjx.es import distributed

        try:
            distributed.initialize(args.coordinator, args.num_processes, args.process_id)
        except ValueError as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
    import jax

    from iap_mjx import es
    from iap_mjx.viz import artifacts

    run_dir = Path(args.run_dir) if args.run_dir else default_run_dir(args.preset)
    print(f"run directory: {run_dir}", file=sys.stderr)
    try:
        primary = jax.process_index() == 0  # several processes share one run directory: one writes
        env, policy = artifacts.env_and_policy(config)  # built once: the run trains and films these
        video_program = artifacts.compile_video_in_background(env, policy) if primary else None
        result = es.train(config, run_dir=run_dir, progress=not args.no_progress, env=env, policy=policy)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        from iap_mjx.es import checkpoint

        step = checkpoint.latest_step(run_dir)
        saved = f"last checkpoint: iteration {step}" if step is not None else "no checkpoint yet"
        print(
            f"\ninterrupted; {saved}. Resume with: iap-mjx train {args.preset} "
            f"--run-dir {run_dir} {' '.join(args.overrides)}".rstrip(),
            file=sys.stderr,
        )
        return 130
    if not primary:
        return 0
    written = artifacts.write_run_artifacts(result, run_dir, video_program)
    last = next((row for row in reversed(result.history) if "eval_return" in row), None)
    summary = {
        "run_dir": str(run_dir),
        "iterations": config.run.iterations,
        "artifacts": [str(path) for path in written],
    }
    if last is not None:
        summary["eval_return"] = last["eval_return"]
    print(json.dumps(summary))
    return 0


def cmd_eval(args: argparse.Namespace) -> int:
    """Evaluates a run's latest checkpoint on fresh seeds, in the run's env or in the condition
    its ``env.*`` overrides set; prints mean and std return (and the mean of each per-episode
    statistic the env keeps, e.g. the quadruped course's ``walls_passed_mean``)."""
    from iap_mjx import es

    try:
        results = es.evaluate_run_episodes(
            args.run_dir, episodes=args.episodes, seed=args.seed, overrides=tuple(args.overrides)
        )
    except (FileNotFoundError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
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


def in_condition(result: Any, overrides: list[str]) -> Any:
    """A loaded run whose config's env is moved to the condition ``overrides`` set, with the
    policy rebuilt for that env's observations (an IAP policy's parameters do not depend on
    the frame's size; a CNN's do), all checked and built before anything compiles; the run
    itself without overrides. ``ValueError`` if the run's parameters do not fit the policy on
    the condition's observations."""
    import jax

    from iap_mjx.configs.overrides import apply_condition
    from iap_mjx.viz import artifacts

    if not overrides:
        return result
    config = apply_condition(result.config, overrides)
    env, policy = artifacts.env_and_policy(config)
    wanted = jax.eval_shape(policy.init, jax.random.PRNGKey(0))
    fits = jax.tree.structure(wanted) == jax.tree.structure(result.params) and all(
        a.shape == b.shape for a, b in zip(jax.tree.leaves(wanted), jax.tree.leaves(result.params))
    )
    if not fits:
        raise ValueError(
            f"the run's {config.policy.kind!r} parameters do not fit its policy on "
            f"{env.observation_shape} observations ({' '.join(overrides)}); keep the env settings "
            "that shape what the policy sees (env.height, env.width, env.obs_mode) as trained"
        )
    return dataclasses.replace(result, config=config, env=env, policy=policy)


def cmd_attended(args: argparse.Namespace) -> int:
    """Prints what an attention policy's selected patches show, share per geom, over episodes
    of a run's latest checkpoint (in the run's env or the condition its overrides set)."""
    from iap_mjx import es
    from iap_mjx.viz import attended

    try:
        result = in_condition(es.load_run(args.run_dir), args.overrides)
        counts = attended.episode_counts(
            result.env, result.policy, result.params, episodes=args.episodes, seed=args.seed, obs_stats=result.obs_stats
        )
    except (FileNotFoundError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(attended.markdown(counts))
    return 0


def cmd_video(args: argparse.Namespace) -> int:
    """Renders an episode of a run's latest checkpoint: a pixel agent's view with the selected
    patches outlined, or a state agent's env from its video camera."""
    from iap_mjx import es
    from iap_mjx.viz import artifacts

    try:
        result = in_condition(es.load_run(args.run_dir), args.overrides)
        if args.strip:
            path, episode_return = artifacts.write_strip(result, args.strip, seed=args.seed, frames=args.frames)
            print(json.dumps({"strip": str(path), "return": episode_return}))
            return 0
        out = Path(args.out) if args.out else Path(args.run_dir) / "episode.mp4"
        path, episode_return = artifacts.write_video(result, out, seed=args.seed, steps=args.steps)
    except (FileNotFoundError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(json.dumps({"video": str(path), "return": episode_return}))
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    """Reproduces the paper's Figure 1 or 6 (inference time per pass next to return), 7 (patch
    sweep), 8 (wall-clock), its Table 1 with the generalisation conditions, or its quadruped's
    Figures 10, 11 and Table 2."""
    from iap_mjx import patch_sweep, reproduce, table1, wallclock

    try:
        if args.figure == "fig11":
            from iap_mjx import fig11

            markdown = fig11.reproduce_fig11(
                args.out,
                seeds=args.seeds,
                overrides=tuple(args.overrides),
                episodes=args.episodes,
                train=not args.report_only,
                results=args.results,
                export=args.export,
            )
        elif args.figure == "table2":
            from iap_mjx import table2

            settings = parse_settings(args.settings) if args.settings else table2.SETTINGS
            markdown = table2.reproduce_table2(
                args.out,
                settings=settings,
                seed=args.seed,
                overrides=tuple(args.overrides),
                train=not args.report_only,
                results=args.results,
            )
        elif args.figure == "fig10":
            from iap_mjx import fig10

            if args.overrides:
                raise ValueError(f"fig10 draws trained runs as they are; remove {' '.join(args.overrides)}")
            run_dirs = tuple(part.strip() for part in args.run_dirs.split(",")) if args.run_dirs else None
            markdown = fig10.reproduce_fig10(args.out, run_dirs=run_dirs, frames=args.frames, results=args.results)
        elif args.figure == "fig8":
            markdown = wallclock.reproduce_fig8(
                args.out, overrides=tuple(args.overrides), train=not args.report_only, results=args.results
            )
        elif args.figure == "fig7":
            markdown = patch_sweep.reproduce_fig7(
                args.out,
                overrides=tuple(args.overrides),
                episodes=args.episodes,
                train=not args.report_only,
                results=args.results,
            )
        elif args.figure == "table1":
            tasks = tuple(t.strip() for t in args.tasks.split(",")) if args.tasks else table1.TASKS
            markdown = table1.reproduce_table1(
                args.out,
                seeds=args.seeds,
                overrides=tuple(args.overrides),
                episodes=args.episodes,
                train=not args.report_only,
                tasks=tasks,
                results=args.results,
                export=args.export,
                policy=args.policy,
            )
        else:
            markdown = reproduce.reproduce(
                args.figure,
                args.out,
                seeds=args.seeds,
                overrides=tuple(args.overrides),
                passes=args.passes,
                train=not args.report_only,
            )
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        # Every run saved a checkpoint of its last finished iteration; rerunning resumes them.
        print(
            "\ninterrupted; the same command resumes: finished runs are skipped, the others "
            "continue from their last checkpoint",
            file=sys.stderr,
        )
        return 130
    print(markdown)
    return 0


def cmd_figures(args: argparse.Namespace) -> int:
    """Writes a figure set (``mse``: the paper's Figures 3 and 4) as PNGs."""
    from iap_mjx.viz import mse_figures

    for path in mse_figures.write_mse_figures(args.out, draws=args.draws):
        print(path)
    return 0


def parse_settings(text: str) -> tuple[tuple[int, int], ...]:
    """``"1x1,2x2,4x2"`` -> ``((1, 1), (2, 2), (4, 2))``: (patch size, stride) pairs."""
    settings = []
    for part in text.split(","):
        size, _, stride = part.strip().partition("x")
        if not (size.isdigit() and stride.isdigit()):
            raise ValueError(f"--settings {text!r}: each setting is PATCHxSTRIDE, e.g. 1x1,2x2,4x4,4x2")
        settings.append((int(size), int(stride)))
    return tuple(settings)


def _count(text: str) -> int:
    """An argparse type: an int >= 1."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def _index(text: str) -> int:
    """An argparse type: an int >= 0."""
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def build_parser() -> argparse.ArgumentParser:
    """The ``iap-mjx`` parser; each subparser sets ``func`` to its command function."""
    parser = argparse.ArgumentParser(
        prog="iap-mjx", description="Implicit Attention for Pixels on MJX, trained with ES."
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    commands = parser.add_subparsers(dest="command", required=True)

    presets = commands.add_parser("presets", help="list the named presets")
    presets.set_defaults(func=cmd_presets)

    show = commands.add_parser(
        "show",
        help="print a preset's resolved config",
        description="Print the config PRESET (or a run directory's config.json) resolves to "
        "with key=value overrides, every env setting, the policy's settings and "
        "its parameter count, building nothing that compiles.",
    )
    show.add_argument("target", metavar="PRESET", help="a name from `iap-mjx presets`, or a run directory")
    show.add_argument("overrides", nargs="*", metavar="key=value")
    show.set_defaults(func=cmd_show)

    train = commands.add_parser(
        "train",
        help="train a preset",
        description="Train PRESET with key=value overrides (e.g. es.population_size=128 "
        "iterations=50 policy.hidden_sizes=64,64). Re-running with the same "
        "--run-dir resumes from its latest checkpoint; Ctrl-C saves one.",
    )
    train.add_argument("preset", help="a name from `iap-mjx presets`")
    train.add_argument("overrides", nargs="*", metavar="key=value")
    train.add_argument("--run-dir", help="where metrics and checkpoints go (default: runs/PRESET-TIME)")
    train.add_argument("--no-progress", action="store_true", help="no progress bar")
    train.add_argument(
        "--coordinator", metavar="HOST:PORT", help="multi-host: the coordinator address (see iap_mjx.es.distributed)"
    )
    train.add_argument("--num-processes", type=_count, default=1, help="multi-host: processes")
    train.add_argument("--process-id", type=_index, default=0, help="multi-host: this process")
    train.set_defaults(func=cmd_train)

    evaluate = commands.add_parser("eval", help="evaluate a run's latest checkpoint")
    evaluate.add_argument("run_dir")
    evaluate.add_argument(
        "overrides",
        nargs="*",
        metavar="env.key=value",
        help="the evaluation's condition, e.g. env.distraction=none, env.dynamic=true, "
        "env.background_videos=val (held-out backgrounds)",
    )
    evaluate.add_argument("--episodes", type=_count, default=8)
    evaluate.add_argument("--seed", type=int, default=12345, help="evaluation seed (distinct from the training seeds)")
    evaluate.set_defaults(func=cmd_eval)

    video = commands.add_parser(
        "video", help="render an episode (pixel agents: the selected patches outlined; state agents: the env's camera)"
    )
    video.add_argument("run_dir")
    video.add_argument(
        "overrides",
        nargs="*",
        metavar="env.key=value",
        help="the episode's condition, e.g. env.background_videos=val (held-out backgrounds)",
    )
    video.add_argument("--out", help="output .mp4 or .gif (default: RUN_DIR/episode.mp4)")
    video.add_argument("--seed", type=int, default=0, help="episode seed")
    video.add_argument("--steps", type=_count, default=None, help="control steps (default: the episode)")
    video.add_argument(
        "--strip",
        default=None,
        metavar="PNG",
        help="instead of a video, a PNG of --frames frames evenly spaced over the episode",
    )
    video.add_argument("--frames", type=_count, default=6, help="frames in a --strip (default 6)")
    video.set_defaults(func=cmd_video)

    look = commands.add_parser(
        "attended",
        help="what an attention policy's selected patches show, share per geom",
        description="Runs episodes of a run's latest checkpoint and prints the share of "
        "the selected patches' pixels that show each geom of the scene or the "
        "background (sky or distraction picture).",
    )
    look.add_argument("run_dir")
    look.add_argument(
        "overrides", nargs="*", metavar="env.key=value", help="the episodes' condition, e.g. env.background_videos=val"
    )
    look.add_argument("--episodes", type=_count, default=3)
    look.add_argument("--seed", type=int, default=0, help="episode seed")
    look.set_defaults(func=cmd_attended)

    repro = commands.add_parser(
        "reproduce",
        help="the paper's Figure 1, 6 (inference time vs return), 7 (patch sweep), 8 (wall-clock), "
        "Table 1, or the quadruped's Figures 10, 11 and Table 2",
        description="fig1/fig6: times one forward pass of every attention variant and trains each "
        "preset on --seeds seeds. fig7: on dcs-cartpole-swingup, one seed per cell of patch "
        "size {2, 4, 8} x selected patches {5, 10, 20}, then d_qk {2, 4, 8} at the best cell. fig8: "
        "brute force, IAP ReLU and hybrid on dcs-cartpole-swingup against wall-clock seconds, "
        "each method's seconds per iteration measured first (leave the machine alone). "
        "table1: trains dcs-<task> for every Distracting Control "
        "task and seed, then evaluates each finished run in four conditions (training "
        "backgrounds, held-out backgrounds, dynamic, no distraction); --policy cnn does the same "
        "for the convolutional baseline. fig11: trains quadruped-walls-iap, -cnn and -blind on "
        "--seeds seeds, then evaluates each finished run on --episodes courses not seen in "
        "training (walls passed, falls, wall contacts, distance). table2: quadruped-walls-iap at "
        "each --settings patch size and stride, one --seed, reporting the maximum episode return. "
        "fig10: a PNG strip of the camera with the selected patches along one episode of each of "
        "--run-dirs (default: table2's patch 1 and 4 runs in --out). key=value overrides "
        "apply to every preset (e.g. run.iterations=100).",
    )
    repro.add_argument("figure", choices=["fig1", "fig6", "fig7", "fig8", "fig10", "fig11", "table1", "table2"])
    repro.add_argument("overrides", nargs="*", metavar="key=value")
    repro.add_argument("--out", default="results", help="output directory (default: results)")
    repro.add_argument("--seeds", type=_count, default=3)
    repro.add_argument("--passes", type=_count, default=100, help="timed forward passes (fig1, fig6)")
    repro.add_argument(
        "--episodes",
        type=_count,
        default=20,
        help="table1, fig7, fig11: evaluation episodes per condition and run (default 20)",
    )
    repro.add_argument("--tasks", default=None, help="table1: comma-separated suite tasks (default: all six)")
    repro.add_argument(
        "--results",
        default=None,
        metavar="RESULTS.md",
        help="table1, table2, fig7, fig8, fig10, fig11: rewrite this markdown file's section",
    )
    repro.add_argument(
        "--export",
        default=None,
        metavar="DIR",
        help="table1, fig11: copy each run's newest checkpoint, config and metrics to "
        "DIR/<task>-seed<k> (table1, e.g. pretrained/dcs) or DIR/<preset>-seed<k> (fig11, "
        "e.g. pretrained/quadruped), tracked by git",
    )
    repro.add_argument(
        "--settings",
        default=None,
        metavar="PxS,...",
        help="table2: comma-separated patch size x stride (default 1x1,2x2,4x4,4x2)",
    )
    repro.add_argument("--seed", type=_index, default=0, help="table2: the training seed (default 0)")
    repro.add_argument(
        "--run-dirs",
        default=None,
        metavar="DIR,...",
        help="fig10: comma-separated trained quadruped-walls-iap runs (default: "
        "OUT/table2-p1-s1-seed0,OUT/quadruped-walls-iap-seed0)",
    )
    repro.add_argument("--frames", type=_count, default=6, help="fig10: frames per strip (default 6)")
    repro.add_argument(
        "--policy",
        default="iap",
        choices=["iap", "cnn"],
        help="table1: iap (dcs-<task>) or cnn, the same-budget convolutional baseline "
        "(dcs-<task>-cnn), reported beside the IAP runs in --out",
    )
    repro.add_argument(
        "--report-only",
        action="store_true",
        help="train nothing: report the runs already in --out, however far they got",
    )
    repro.set_defaults(func=cmd_reproduce)

    figures = commands.add_parser(
        "figures",
        help="write the paper's figures as PNGs",
        description="mse: Figures 3 and 4 (MSE of the trig, exp and hybrid estimators, "
        "closed forms with Monte Carlo points).",
    )
    figures.add_argument("which", choices=["mse"])
    figures.add_argument("--out", default="figures", help="output directory (default: figures)")
    figures.add_argument("--draws", type=_count, default=100_000, help="Monte Carlo draws per point")
    figures.set_defaults(func=cmd_figures)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point: sets up devices and the compilation cache, then runs the command."""
    runtime.hoist_large_constants()
    runtime.set_host_device_count()
    runtime.enable_compilation_cache()
    runtime.disable_dm_control_rendering()
    args = build_parser().parse_args(argv)
    # Our own messages at INFO; JAX's, orbax's and absl's chatter only from WARNING (-v: all).
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.WARNING,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    logging.getLogger("iap_mjx").setLevel(logging.DEBUG if args.verbose else logging.INFO)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
