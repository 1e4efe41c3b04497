"""How far the latent command of each Figure 11 run steers its trained low level.

The hierarchy trains both levels together from the same trot, so how the robot answers a command
(turn left, turn right, go straight) is learned alongside what the high level asks for. This
probe holds each of 32 latent commands constant (zero, +-1 on each of the 4 entries, and 23 drawn
uniformly from [-1, 1]^4 with a fixed key: the high level's outputs lie in [-1, 1]) and walks the
run's low level alone on ``quadruped-flat`` for 250 control steps (5 s), 2 episodes per command,
and prints per run the heading reached after 5 s (degrees, unwrapped: the yaw turned since the
start, + is left, toward +y, and a turn past 180 degrees keeps its sign): its minimum,
median and maximum over the commands (each the mean of its 2 episodes), and how many commands
turn the robot left or right by more than 15 degrees. A low level that turns both ways is one
the high level can steer around a wall on either side. A ``quadruped-turn-pmtg`` run is probed
as the hierarchy would hold it (its command as the latent's first entry).

    python experiments/fig11_steering.py pretrained/quadruped/quadruped-walls-*-seed*
    python experiments/fig11_steering.py results/turn/quadruped-turn-pmtg-seed0
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from iap_mjx import envs, es
from iap_mjx.policies.hierarchical import low_level_weights
from iap_mjx.policies.pmtg import PMTGPolicy, PMTGState

STEPS = 250  # 5 s of 0.02 s control steps
EPISODES = 2
TURN = 15.0  # degrees: a command that turns the robot more than this counts as a turn
LATENT_SEED = 0


def commands(latent_size: int, count: int = 32) -> np.ndarray:
    """``(count, latent_size)``: zero, +-1 on each entry, then uniform draws from [-1, 1]."""
    axes = [sign * np.eye(latent_size)[i] for i in range(latent_size) for sign in (1.0, -1.0)]
    fixed = np.array([np.zeros(latent_size), *axes])
    drawn = np.random.default_rng(LATENT_SEED).uniform(-1.0, 1.0, (count - len(fixed), latent_size))
    return np.concatenate([fixed, drawn]).astype(np.float32)


def heading(quat: jax.Array) -> jax.Array:
    """Yaw (degrees) of a ``(w, x, y, z)`` unit quaternion."""
    w, x, y, z = quat[0], quat[1], quat[2], quat[3]
    return jnp.degrees(jnp.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


def low_level(run_dir: Path) -> tuple[PMTGPolicy, dict]:
    """The run's low level and its params as the hierarchy holds them: a hierarchical run's own;
    a ``quadruped-turn-pmtg`` run's with its normalisation folded in and its command as the
    latent's first entry (what ``policy.low_level_init`` would start the hierarchy from)."""
    result = es.load_run(run_dir)
    if result.config.env.name != "quadruped-turn":
        return result.policy.low, result.params["low"]
    turn = result.policy
    w, b = low_level_weights(turn, result.params, result.obs_stats, result.config.env.name)
    return dataclasses.replace(turn, obs_size=turn.obs_size - 1), {"w": jnp.asarray(w), "b": jnp.asarray(b)}


def probe(run_dir: Path) -> np.ndarray:
    """``(commands,)`` the heading after ``STEPS`` control steps per command, mean over episodes."""
    low, params = low_level(run_dir)
    env = envs.make("quadruped-flat", episode_length=STEPS)

    def episode(params, latent, key):
        def step(carry, _):
            state, policy_state, turned = carry
            action, policy_state = low.apply(params, state.obs, policy_state)
            after = env.step(state, action)
            # summed per-step yaw changes, each wrapped to (-180, 180]: a turn past 180 degrees
            # stays a turn that way instead of wrapping to the other sign
            change = heading(after.data.qpos[3:7]) - heading(state.data.qpos[3:7])
            return (after, policy_state, turned + (change + 180.0) % 360.0 - 180.0), None

        start = env.reset(key)
        first = (start, PMTGState(latent=latent, phase=jnp.zeros(())), jnp.zeros(()))
        (_, _, turned), _ = jax.lax.scan(step, first, None, length=STEPS)
        return turned

    run = jax.jit(jax.vmap(jax.vmap(episode, (None, None, 0)), (None, 0, None)))
    keys = jax.random.split(jax.random.PRNGKey(0), EPISODES)
    return np.asarray(run(params, jnp.asarray(commands(len(low.latent))), keys)).mean(1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dirs", nargs="+", type=Path, help="trained quadruped-walls hierarchical runs")
    args = parser.parse_args()
    print(f"| run | heading after 5 s: min / median / max (deg) | commands turning left / right (> {TURN:.0f} deg) |")
    print("|---|---|---|")
    for run_dir in args.run_dirs:
        yaw = probe(run_dir)
        print(
            f"| `{run_dir.name}` | {yaw.min():.0f} / {np.median(yaw):.0f} / {yaw.max():.0f} | "
            f"{int((yaw > TURN).sum())} / {int((yaw < -TURN).sum())} of {len(yaw)} |"
        )


if __name__ == "__main__":
    main()
