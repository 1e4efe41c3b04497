"""Does the course need vision? A walker that goes straight, on many ``quadruped-walls`` (or
``quadruped-gates``) episodes.

The walker is the PMTG low level with a constant latent (it sees the IMU and joint angles, never
the walls): by default the policy's initial params (the TG's trot at ``initial_tg``, zero
weights and residuals: about 0.8 m/s on the flat), or with ``--low-level RUN_DIR`` a trained
``quadruped-flat-pmtg`` run's centre params and observation statistics. It runs ``--episodes``
episodes of the course (each with its own wall placement), through the ES's own rollout
(``iap_mjx.es.rollout``), and reports per-episode course statistics (the env's
``episode_metrics``): the fraction that pass every wall, touch a wall, fall off the platform,
and the mean walls passed and distance. If the straight walker passes most episodes, the
course does not need eyes. ``--env quadruped-gates`` runs the gates corridor instead and
reports its statistics (gates passed, obstacle contacts, leaving the corridor, falls).

    python benchmarks/course_check.py --episodes 64
    python benchmarks/course_check.py --episodes 64 --low-level runs/flat0 --section course-check
    python benchmarks/course_check.py --env quadruped-gates --episodes 32 --section course-check-gates
    python benchmarks/course_check.py --low-level runs/flat0 --export-low-level low.npz
        # the run's weights with its observation normalisation folded in, for
        # policy.low_level_init=low.npz of the quadruped-walls-* presets; a quadruped-turn-pmtg
        # run's command becomes the latent's first entry (hierarchical.low_level_weights)

``key=value`` arguments set the env's settings (e.g. ``n_walls=3``, ``n_gates=3``).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

from iap_mjx import runtime  # noqa: E402

runtime.set_host_device_count()
runtime.enable_compilation_cache()

import jax  # noqa: E402
import numpy as np  # noqa: E402
from jax.flatten_util import ravel_pytree  # noqa: E402

from iap_mjx import configs, es  # noqa: E402
from iap_mjx.configs.overrides import parse_value  # noqa: E402
from iap_mjx.policies.hierarchical import low_level_weights  # noqa: E402

COURSES = ("quadruped-walls", "quadruped-gates")


def walker(
    low_level: str | None, env_overrides: tuple, env_name: str = "quadruped-walls"
) -> tuple[configs.TrainConfig, object, object]:
    """``(config, params, obs_stats)`` of the straight walker on the course ``env_name``."""
    if low_level is None:
        config = configs.TrainConfig(
            env=configs.EnvSpec(env_name, env_overrides),
            policy=configs.PolicySpec("pmtg"),
            es=configs.ESConfig(population_size=2, normalize_observations=False),
            run=configs.RunConfig(eval_episodes=0),
        )
        parts = es.build(config)
        return config, parts.template_params, None
    trained = es.load_run(low_level)
    if trained.config.policy.kind != "pmtg":
        raise SystemExit(f"{low_level} trained a {trained.config.policy.kind!r} policy; a pmtg one is needed")
    config = dataclasses.replace(
        trained.config,
        env=configs.EnvSpec(env_name, env_overrides),
        run=dataclasses.replace(trained.config.run, eval_episodes=0),
    )
    return config, trained.params, trained.obs_stats


def run(config: configs.TrainConfig, params, obs_stats, episodes: int, seed: int) -> dict[str, np.ndarray]:
    """Per-episode ``{"return", "steps", "saturated"}`` and the env's ``episode_metrics`` (e.g.
    ``walls_passed``, ``fell_off``, ``wall_contacts``, ``distance``), and the env."""
    chunk = min(32, episodes)
    config = dataclasses.replace(config, run=dataclasses.replace(config.run, chunk_size=chunk))
    parts = es.build(config)
    flat, _ = ravel_pytree(params)
    population = np.broadcast_to(np.asarray(flat), (episodes, flat.shape[0]))
    keys = jax.random.split(jax.random.PRNGKey(seed), episodes)
    result = jax.jit(parts.rollout)(population, keys, obs_stats)
    host = jax.tree_util.tree_map(np.asarray, result)
    return {"return": host.ret, "steps": host.steps, "saturated": host.saturated, **host.metrics}, parts.env


def summary(results: dict[str, np.ndarray], env) -> dict[str, float]:
    """Fractions of episodes by outcome, and means (the walls course's or the gates corridor's)."""
    if env.name == "quadruped-gates":
        return gates_summary(results, env)
    passed, contacts = results["walls_passed"], results["wall_contacts"]
    fell = results["fell_off"] > 0
    ended = results["steps"] < env.episode_length
    finished = results["distance"] > env.PLATFORM[1]
    return {
        "episodes": len(passed),
        "passed every wall": float(np.mean(passed >= env.config.n_walls)),
        "passed no wall": float(np.mean(passed == 0)),
        "touched a wall": float(np.mean(contacts > 0)),
        "fell off the platform": float(np.mean(fell)),
        "fell over on it (trunk down)": float(np.mean(ended & ~fell & ~finished)),
        "touched a wall or fell off": float(np.mean((contacts > 0) | fell)),
        "reached the far end": float(np.mean(finished)),
        "walls passed (mean)": float(np.mean(passed)),
        "distance m (mean)": float(np.mean(results["distance"])),
        "return (mean)": float(np.mean(results["return"])),
    }


def gates_summary(results: dict[str, np.ndarray], env) -> dict[str, float]:
    """The gates corridor's outcomes: fractions of episodes, and means."""
    passed, touched = results["gates_passed"], results["collisions"] > 0
    left, fell = results["left_corridor"] > 0, results["fell_over"] > 0
    return {
        "episodes": len(passed),
        "passed every gate": float(np.mean(passed >= env.config.n_gates)),
        "passed no gate": float(np.mean(passed == 0)),
        "touched a gate or clutter": float(np.mean(touched)),
        "left the corridor": float(np.mean(left)),
        "fell over (trunk down)": float(np.mean(fell)),
        "reached the far end": float(np.mean(results["distance"] > env.x_end)),
        "contact slots saturated": float(np.mean(results["saturated"] > 0)),
        "gates passed (mean)": float(np.mean(passed)),
        "distance m (mean)": float(np.mean(results["distance"])),
        "return (mean)": float(np.mean(results["return"])),
    }


def course_size(env) -> str:
    """``"3 walls"`` or ``"3 gates"``: what the course has."""
    if env.name == "quadruped-gates":
        return f"{env.config.n_gates} gates"
    return f"{env.config.n_walls} walls"


def markdown(label: str, stats: dict[str, float], command: str, course: str) -> str:
    when = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    load = os.getloadavg()[0]
    rows = "\n".join(
        f"| {name} | {value:.2f} |" if isinstance(value, float) else f"| {name} | {value} |"
        for name, value in stats.items()
    )
    return (
        f"### {label}\n\nCommand: `{command}` ({when}; 1-min load average {load:.1f}; "
        f"{course})\n\n| statistic | value |\n|---|---:|\n{rows}\n"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("overrides", nargs="*", metavar="key=value", help="the env's settings")
    parser.add_argument("--env", choices=COURSES, default="quadruped-walls", help="the course")
    parser.add_argument("--episodes", type=int, default=64)
    parser.add_argument("--seed", type=int, default=2024, help="course draws (not a training seed)")
    parser.add_argument(
        "--low-level",
        metavar="RUN_DIR",
        help="a trained quadruped-flat-pmtg or quadruped-turn-pmtg run (default: the PMTG policy's "
        "initial params, the TG's trot)",
    )
    parser.add_argument(
        "--export-low-level",
        metavar="OUT.npz",
        help="with --low-level: write its w and b with the normalisation folded in, and stop",
    )
    parser.add_argument("--section", help="also write this section of RESULTS.md")
    args = parser.parse_args(argv)
    env_overrides = tuple(sorted((k, parse_value(v)) for k, v in (o.split("=", 1) for o in args.overrides)))
    config, params, obs_stats = walker(args.low_level, env_overrides, args.env)
    if args.export_low_level:
        if args.low_level is None or obs_stats is None:
            raise SystemExit("--export-low-level needs --low-level RUN_DIR of a run with observation statistics")
        trained = es.load_run(args.low_level)
        w, b = low_level_weights(trained.policy, trained.params, trained.obs_stats, trained.config.env.name)
        np.savez(args.export_low_level, w=w, b=b)
        print(f"wrote {args.export_low_level}: w {w.shape}, b {b.shape}")
        return 0
    results, env = run(config, params, obs_stats, args.episodes, args.seed)
    stats = summary(results, env)
    label = (
        f"Trained flat low level `{args.low_level}`, constant latent"
        if args.low_level
        else "The TG's trot (`PMTGPolicy.initial_tg`, zero weights and residuals)"
    )
    command = "python benchmarks/course_check.py " + " ".join(argv if argv is not None else sys.argv[1:])
    text = markdown(label, stats, command.strip(), course_size(env))
    print(text)
    if args.section:
        import report

        report.write_section(ROOT / "RESULTS.md", args.section, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
