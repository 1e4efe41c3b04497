"""What the PMTG trajectory generator walks on its own: fixed TG settings, no residuals.

For each setting of the TG's four inputs ``(f, I, h, k)`` (the policy's outputs in ``[-1, 1]``,
held for the whole episode; the 12 residuals zero) it runs ``--episodes`` episodes of
``quadruped-flat`` in MJX and prints the mean forward speed (capped return / episode seconds,
a fall counting as standing still from then on) and how many episodes fell. A grid over
``--frequency``, ``--intensity``, ``--height`` (in Hz, 1, m: the TG's own units) and the
zero-output setting, so one can see whether the TG's centre (what a zero policy walks) is a
good place for ES to start and what the TG alone can reach.

    python benchmarks/quadruped_tg.py --episodes 8
"""

from __future__ import annotations

import argparse
import itertools
import math

from iap_mjx import runtime

runtime.set_host_device_count(2)

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from iap_mjx import envs  # noqa: E402
from iap_mjx.policies import pmtg  # noqa: E402
from iap_mjx.robots import a1  # noqa: E402


def to_unit(value: float, bounds: tuple[float, float], log: bool = False) -> float:
    """A TG parameter in its units -> the policy output in [-1, 1] that gives it."""
    lo, hi = bounds
    if log:
        value, lo, hi = math.log(value), math.log(lo), math.log(hi)
    return 2.0 * (value - lo) / (hi - lo) - 1.0


def episode_speed(env, tg: pmtg.TGConfig, u_tg: jax.Array, key: jax.Array):
    """Mean forward speed (m/s) and whether the episode ended early, for one TG setting."""
    u = jnp.concatenate([jnp.zeros(12), u_tg])

    def body(carry, _):
        state, phase = carry
        step = pmtg.tg_step(tg, phase, u)
        state = env.step(state, a1.targets_to_action(step.targets))
        return (state, step.phase), (state.reward, state.done)

    state = env.reset(key)
    _, (rewards, done) = jax.lax.scan(body, (state, jnp.zeros(())), None, length=env.episode_length)
    seconds = env.episode_length * env.control_timestep
    fell = done[-2] > 0  # ended before the time limit
    return jnp.sum(rewards) / seconds, fell


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frequency", nargs="+", type=float, default=[1.0, 1.5, 2.0, 2.5, 3.0])
    parser.add_argument("--intensity", nargs="+", type=float, default=[0.2, 0.4, 0.6, 0.8])
    parser.add_argument("--height", nargs="+", type=float, default=[0.0, 0.1, 0.225, 0.35])
    parser.add_argument("--ratio", nargs="+", type=float, default=[1.0])
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--gait", default="trot")
    parser.add_argument("--top", type=int, default=15)
    args = parser.parse_args(argv)
    env = envs.make("quadruped-flat")
    tg = pmtg.TGConfig(gait=args.gait)
    grid = list(itertools.product(args.frequency, args.intensity, args.height, args.ratio))
    centre = tg.parameters(jnp.zeros(4))
    grid.insert(0, tuple(float(centre[k]) for k in pmtg.TG_PARAMETERS))
    units = np.array(
        [
            [
                to_unit(f, tg.frequency_range),
                to_unit(i, tg.intensity_range),
                to_unit(h, tg.height_range),
                to_unit(k, tg.ratio_range, log=True),
            ]
            for f, i, h, k in grid
        ],
        np.float32,
    )
    n = len(grid) * args.episodes
    chunk = 64  # <= env.max_chunk_size: larger vmapped batches can deadlock XLA:CPU (jaxlib 0.10)
    pad = (-n) % chunk
    u = np.repeat(units, args.episodes, axis=0)
    u = np.concatenate([u, np.zeros((pad, 4), np.float32)])
    keys = jax.random.split(jax.random.key(0), n + pad)
    run = jax.jit(jax.vmap(lambda uu, kk: episode_speed(env, tg, uu, kk)))
    out = [jax.device_get(run(jnp.asarray(u[i : i + chunk]), keys[i : i + chunk])) for i in range(0, n + pad, chunk)]
    speed, fell = (np.concatenate([o[j] for o in out]) for j in (0, 1))
    speed, fell = speed[:n].reshape(len(grid), -1), fell[:n].reshape(len(grid), -1)
    rows = sorted(range(len(grid)), key=lambda g: -speed[g].mean())
    print(
        f"TG alone on quadruped-flat ({args.gait}, residuals 0, {args.episodes} episodes each, "
        f"{env.episode_length} control steps): mean speed m/s, falls"
    )
    print(
        f"centre (zero policy): f={grid[0][0]:.2f} I={grid[0][1]:.2f} h={grid[0][2]:.3f} k={grid[0][3]:.2f}: "
        f"{speed[0].mean():.3f} m/s, falls {int(fell[0].sum())}/{args.episodes}"
    )
    for g in rows[: args.top]:
        f, i, h, k = grid[g]
        print(
            f"f={f:.2f} I={i:.2f} h={h:.3f} k={k:.2f} u={np.round(units[g], 2).tolist()}: "
            f"{speed[g].mean():.3f} +- {speed[g].std():.3f} m/s, falls {int(fell[g].sum())}/{args.episodes}"
        )


if __name__ == "__main__":
    main()
