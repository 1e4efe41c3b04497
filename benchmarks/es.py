"""ES sanity benchmark: state-based cheetah-run for a fixed wall-clock budget, ours vs brax's ES.

Trains the preset (default ``cheetah-run-state``) with ``iap_mjx.es.train`` for ``--minutes``
of wall-clock (compile included, compilation cache cold), then gives brax's own ES trainer
(``brax.training.agents.es``) the same env (our MJX cheetah-run behind a brax ``Env``
adapter), the same number of env steps and matching hyperparameters, in the same process.
Writes the ``es`` sections of ``BENCHMARKS.md`` and ``RESULTS.md`` and a curve PNG.

    python benchmarks/es.py --minutes 15
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

import report  # noqa: E402


def brax_adapter(env):
    """Our env behind brax's ``Env`` interface (our ``State`` rides in ``pipeline_state``)."""
    from brax.envs.base import Env as BraxEnv
    from brax.envs.base import State as BraxState

    class Adapter(BraxEnv):
        def reset(self, rng):
            ours = env.reset(rng)
            return BraxState(
                pipeline_state=ours,
                obs=ours.obs,
                reward=ours.reward,
                done=ours.done,
                metrics=dict(ours.metrics),
                info={},
            )

        def step(self, state, action):
            ours = env.step(state.pipeline_state, action)
            return state.replace(
                pipeline_state=ours,
                obs=ours.obs,
                reward=ours.reward,
                done=ours.done,
                metrics={**state.metrics, **ours.metrics},
            )

        @property
        def observation_size(self):
            return env.observation_shape[0]

        @property
        def action_size(self):
            return env.action_size

        @property
        def backend(self):
            return "mjx"

    return Adapter()


def run_ours(config):
    from iap_mjx.es import train

    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as run_dir:
        result = train(config, run_dir=run_dir, progress=False)
    wall = time.perf_counter() - start
    return result.history, wall


def run_brax(env, config, num_timesteps: int):
    import functools

    import flax.linen as linen
    from brax.training.agents.es import networks as es_networks
    from brax.training.agents.es import train as brax_es

    es = config.es
    hidden = tuple(dict(config.policy.options).get("hidden_sizes", ()))
    if config.policy.kind == "mlp" and not hidden:
        hidden = (32, 32)
    curve = []
    start = time.perf_counter()

    def progress(steps, metrics):
        curve.append(
            {
                "env_steps": int(steps),
                "wall_s": time.perf_counter() - start,
                "eval_return": float(metrics["eval/episode_reward"]),
                "sps": float(metrics.get("training/sps", float("nan"))),
            }
        )

    brax_es.train(
        environment=brax_adapter(env),
        num_timesteps=num_timesteps,
        episode_length=env.episode_length,
        population_size=es.population_size // 2,  # brax adds the mirrored half itself
        learning_rate=es.learning_rate,
        perturbation_std=es.sigma,
        l2coeff=es.weight_decay,
        fitness_shaping=brax_es.FitnessShaping.CENTERED_RANK,
        normalize_observations=es.normalize_observations,
        num_evals=11,
        num_eval_envs=max(2, config.run.eval_episodes),
        deterministic_eval=True,
        seed=config.run.seed,
        network_factory=functools.partial(
            es_networks.make_es_networks, hidden_layer_sizes=hidden, activation=linen.tanh
        ),
        progress_fn=progress,
    )
    return curve, time.perf_counter() - start


def first_reaching(rows, threshold):
    for row in rows:
        if row.get("eval_return", float("-inf")) >= threshold:
            return row
    return None


def plot(ours, brax, path: Path, title: str):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.6), dpi=120)
    ax.plot([r["wall_s"] / 60 for r in ours], [r["eval_return"] for r in ours], label="iap_mjx.es (centre, eval seeds)")
    if brax:
        ax.plot(
            [r["wall_s"] / 60 for r in brax],
            [r["eval_return"] for r in brax],
            "o-",
            label="brax ES (deterministic eval)",
        )
    ax.axhline(400, color="grey", lw=0.8, ls="--")
    ax.set_xlabel("wall-clock minutes (compile included)")
    ax.set_ylabel("evaluation return")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="cheetah-run-state")
    parser.add_argument("--minutes", type=float, default=15.0)
    parser.add_argument("--skip-brax", action="store_true")
    parser.add_argument("--no-write", action="store_true", help="print only")
    parser.add_argument("overrides", nargs="*", metavar="key=value")
    args = parser.parse_args()

    from iap_mjx import runtime

    runtime.set_host_device_count()
    cache = tempfile.mkdtemp(prefix="iap_mjx_es_bench_cache_")
    runtime.enable_compilation_cache(cache)  # cold: compile time is measured honestly

    import jax

    from iap_mjx import configs, envs

    config = configs.apply_overrides(configs.get(args.preset), args.overrides)
    config = dataclasses.replace(
        config,
        run=dataclasses.replace(
            config.run, iterations=10**6, max_minutes=args.minutes, checkpoint_every=0, tensorboard=False
        ),
    )
    load_before = os.getloadavg()[0]
    ours, ours_wall = run_ours(config)
    steps = ours[-1]["env_steps"]
    steady = [r["env_steps_per_s"] for r in ours[1:]] or [ours[0]["env_steps_per_s"]]
    summary = {
        "preset": args.preset,
        "overrides": args.overrides,
        "devices": len(jax.devices()),
        "load_average_1min_before_after": [load_before, os.getloadavg()[0]],
        "ours": {
            "iterations": ours[-1]["iteration"],
            "env_steps": steps,
            "wall_s": ours_wall,
            "compile_s": ours[-1]["compile_s"],
            "steady_env_steps_per_s": float(sorted(steady)[len(steady) // 2]),
            "final_eval_return": ours[-1]["eval_return"],
            "best_eval_return": max(r["eval_return"] for r in ours),
        },
    }
    reached = first_reaching(ours, 400)
    summary["ours"]["minutes_to_400"] = reached["wall_s"] / 60 if reached else None
    brax = []
    history_path = ROOT / "benchmarks" / f"es_{args.preset}_history.json"
    history_path.write_text(json.dumps({"summary": summary, "ours": ours}, indent=0))
    if not args.no_write:  # record ours now, in case the comparison is cut short
        write_outputs(args, config, summary, ours, brax)
    if not args.skip_brax:
        env = envs.make_spec(config.env)
        brax, brax_wall = run_brax(env, config, steps)
        summary["brax"] = {
            "env_steps": brax[-1]["env_steps"],
            "wall_s": brax_wall,
            "steady_env_steps_per_s": brax[-1]["sps"],
            "final_eval_return": brax[-1]["eval_return"],
            "best_eval_return": max(r["eval_return"] for r in brax),
        }
    print(json.dumps(summary, indent=1))
    history_path.write_text(json.dumps({"summary": summary, "ours": ours, "brax": brax}, indent=0))
    if not args.no_write:
        write_outputs(args, config, summary, ours, brax)
    return 0


def write_outputs(args, config, summary, ours, brax) -> None:
    """The curve PNG and the ``es`` sections of BENCHMARKS.md and RESULTS.md."""

    png = ROOT / "benchmarks" / f"es_{args.preset}.png"
    plot(ours, brax, png, f"{args.preset} {' '.join(args.overrides)} ({args.minutes:g} min)")
    command = (
        f"python benchmarks/es.py --minutes {args.minutes:g} --preset {args.preset} {' '.join(args.overrides)}"
    ).rstrip()
    o = summary["ours"]
    reached = f"after {o['minutes_to_400']:.1f} min" if o["minutes_to_400"] else "no"
    lines = [
        "## ES: state-based cheetah-run, iap_mjx.es vs brax ES",
        "",
        f"Command: `{command}` ({summary['devices']} XLA CPU devices, cold compilation cache, "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; 1-min load average before/"
        f"after our run: {summary['load_average_1min_before_after'][0]:.1f}/"
        f"{summary['load_average_1min_before_after'][1]:.1f} on 2 cores: the machine is "
        "shared, so steps/s are lower bounds).",
        "",
        "| trainer | env steps | wall-clock s | compile s | steady env-steps/s | "
        "final eval return | best eval return |",
        "|---|---|---|---|---|---|---|",
        f"| iap_mjx.es | {o['env_steps']:,} | {o['wall_s']:.0f} | {o['compile_s']:.0f} | "
        f"{o['steady_env_steps_per_s']:,.0f} | {o['final_eval_return']:.1f} | "
        f"{o['best_eval_return']:.1f} |",
    ]
    if brax:
        b = summary["brax"]
        lines.append(
            f"| brax ES | {b['env_steps']:,} | {b['wall_s']:.0f} | (in wall) | "
            f"{b['steady_env_steps_per_s']:,.0f} | {b['final_eval_return']:.1f} | "
            f"{b['best_eval_return']:.1f} |"
        )
    lines += [
        "",
        "Both trainers get the same env (our MJX cheetah-run; brax's through an "
        "adapter), the same env-step budget, population, sigma, learning rate, weight "
        "decay, centred ranks and observation normalisation; brax ES samples "
        "stochastic actions during training (its design), evaluated deterministically. "
        "brax's steps/s is its own `training/sps` of the last epoch. Our eval return is "
        f"the centre params on {config.run.eval_episodes} episodes of separate seeds, "
        "every iteration.",
        "",
        f"Reached 400: {reached}. Curve: `benchmarks/{png.name}`.",
        "",
    ]
    report.write_section(ROOT / "BENCHMARKS.md", "es", "\n".join(lines))
    report.write_section(ROOT / "RESULTS.md", "es", results_section(ours, brax, summary, command, png))


def results_section(ours, brax, summary, command: str, png: Path) -> str:
    """The learning curve as a table: the last row of every wall-clock minute."""
    by_minute = {}
    for row in ours:
        by_minute[int(row["wall_s"] // 60)] = row
    lines = [
        "## ES sanity bar: state-based cheetah-run within 15 minutes",
        "",
        f"Command: `{command}`. Bar: mean evaluation return >= 400 within 15 min of "
        "wall-clock on this 2-core machine (compile included, cold cache).",
        "",
        f"![curve](benchmarks/{png.name})",
        "",
        "| minute | iteration | env steps | eval return (mean +- std over episodes) | population mean return |",
        "|---|---|---|---|---|",
    ]
    for minute, row in sorted(by_minute.items()):
        lines.append(
            f"| {row['wall_s'] / 60:.1f} | {row['iteration']} | {row['env_steps']:,} | "
            f"{row['eval_return']:.1f} +- {row['eval_return_std']:.1f} | "
            f"{row['return_mean']:.1f} |"
        )
    o = summary["ours"]
    verdict = f"reached after {o['minutes_to_400']:.1f} min" if o["minutes_to_400"] else "not reached"
    lines += ["", f"Bar: {verdict}; final eval return {o['final_eval_return']:.1f}, best {o['best_eval_return']:.1f}."]
    if brax:
        b = summary["brax"]
        lines.append(
            f"brax ES with the same env, env steps and hyperparameters: final eval return "
            f"{b['final_eval_return']:.1f} (best {b['best_eval_return']:.1f}) after "
            f"{b['wall_s'] / 60:.1f} min. Details in BENCHMARKS.md."
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
