"""Do an IAP policy's patch scores follow colour contrast? A measurement for Table 1's analysis.

RESULTS.md's Distracting Control tuning notes guessed that the hybrid kernel's scores grow with
a key's norm, so that the patches most unlike the rest of the frame in colour win the top 10
whatever they show. This probe measures it. Per run, it records episodes of the run's latest
checkpoint (and of its initial parameters, the ES centre before iteration 0) on training
backgrounds, and for every ``--every``-th frame the policy saw it computes each of the L patches'
score (the layer's own), its key's norm ``|k|`` and its colour contrast (the distance of the
patch's mean RGB from the frame's mean RGB). It prints, as medians over those frames:

- ``rho(score, contrast)``, ``rho(score, |k|)`` and ``rho(score, q.k)``: Spearman rank
  correlations over the L patches, ``q`` the frame's mean query. The last is 1 when the score
  orders patches as one linear function of their pixels does (``k = W_K^T patch``, so ``q.k``
  is the patch's pixels projected on ``W_K q``): a fixed colour filter, not a comparison of
  each patch with the rest;
- the selected patches' contrast percentile: where the ``l`` selected patches' contrast ranks among
  all L patches of their frame (50: no preference; 100: the most contrasting patches);
- the scores' spread, ``(max - median) / max |score|``: how much the patches' scores differ at all.

The patches the episode selected are checked to hold the top ``l`` of the scores recomputed here
(up to float32 rounding), so the frames are the ones the policy saw; frames whose scores spread
too little for that check are measured, not verified, and counted.

    python experiments/score_contrast.py pretrained/dcs/cartpole-swingup-seed{0,1,2} --episodes 3
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from iap_mjx import es
from iap_mjx.attention.patches import extract_patches
from iap_mjx.es.components import build
from iap_mjx.viz import recording


def ranks(x: jax.Array) -> jax.Array:
    """Ranks ``0..n-1`` of ``x (n,)``, tied values sharing their mean rank (a picture's
    saturated highlights tie in contrast)."""
    ordered = jnp.sort(x)
    first = jnp.searchsorted(ordered, x, side="left")
    past = jnp.searchsorted(ordered, x, side="right")
    return (first + past - 1).astype(jnp.float32) / 2.0


def spearman(a: jax.Array, b: jax.Array) -> jax.Array:
    """Spearman's rank correlation of ``a, b (n,)``."""
    ra, rb = ranks(a), ranks(b)
    ra, rb = ra - ra.mean(), rb - rb.mean()
    return jnp.sum(ra * rb) / jnp.sqrt(jnp.sum(ra**2) * jnp.sum(rb**2))


def frame_measures(
    layer, attention_params, frame: jax.Array, scores: jax.Array, selected: jax.Array
) -> dict[str, jax.Array]:
    """For one frame ``(H, W, 3)``, its patches' ``scores (L,)`` and the patches the episode
    selected, ``selected (l,)``: the three rank correlations and the selected patches' mean
    contrast percentile."""
    p = layer.config.patch_size
    queries, keys = layer.queries_keys(attention_params, frame)
    patches, _ = extract_patches(frame, p, layer.config.effective_stride)  # (L, p * p * C)
    colour = patches.reshape(patches.shape[0], p * p, -1).mean(axis=1)  # (L, C)
    contrast = jnp.linalg.norm(colour - frame.reshape(-1, frame.shape[-1]).mean(axis=0), axis=1)
    percentile = 100.0 * ranks(contrast)[selected].mean() / (contrast.shape[0] - 1)
    return {
        "rho_contrast": spearman(scores, contrast),
        "rho_key_norm": spearman(scores, jnp.linalg.norm(keys, axis=1)),
        "rho_mean_query": spearman(scores, keys @ queries.mean(axis=0)),
        "percentile": percentile,
    }


ROW_NAMES = ("rho_contrast", "rho_key_norm", "rho_mean_query", "percentile", "spread")


def measure(result, params, *, episodes: int, every: int, seed: int) -> dict[str, float]:
    """Medians over the sampled frames of ``episodes`` episodes of ``params`` (and of the
    scores' spread, ``(max - median) / max |score|``), the number of ``frames`` and of those
    ``verified`` (below)."""
    env, policy = result.env, result.policy
    program = recording.episode_program(env, policy, steps=env.episode_length, scene=False)
    score_frame = jax.jit(lambda layer, a, pr, frame: layer.scores(a, pr, frame), static_argnums=0)
    measure_frame = jax.jit(frame_measures, static_argnums=0)
    rows, verified = [], 0
    for key in jax.random.split(jax.random.PRNGKey(seed), episodes):
        record = recording.record_episode(
            env, policy, params, key, steps=env.episode_length, obs_stats=result.obs_stats, program=program
        )
        frames = np.flatnonzero(record["alive"])[::every]
        projections, _ = policy.initial_state(jax.random.split(key)[1])  # the episode's policy key
        images = [jnp.asarray(record["frames"][t]) for t in frames]
        scores = np.stack([np.asarray(score_frame(policy.layer, params["attention"], projections, i)) for i in images])
        selected = record["indices"][frames]
        # The episode's selected patches must hold the top l scores recomputed here, up to float32
        # rounding (this program and the episode's round the scores differently in their last
        # bits, so patches at the top l's edge may swap), which a different frame would not. A
        # frame whose scores spread less than 100 times that rounding cannot tell: it is measured
        # but not verified (the frames come from the same record as the verified ones).
        rounding = 1e-5 * np.abs(scores).max(axis=1)
        spread = scores.max(axis=1) - np.median(scores, axis=1)
        kept = spread > 100 * rounding
        chosen = np.take_along_axis(scores, selected, axis=1)
        edge = np.sort(scores, axis=1)[:, -selected.shape[1]]
        if np.any((chosen < (edge - rounding)[:, None])[kept]):
            raise RuntimeError("the episode's selected patches are not the top scores here: not the frames it saw")
        verified += int(np.sum(kept))
        for t in range(len(frames)):
            row = measure_frame(policy.layer, params["attention"], images[t], jnp.asarray(scores[t]), selected[t])
            relative_spread = spread[t] / np.abs(scores[t]).max()
            rows.append({name: float(value) for name, value in row.items()} | {"spread": float(relative_spread)})
    medians = {name: float(np.median([row[name] for row in rows])) for name in ROW_NAMES}
    return medians | {"frames": len(rows), "verified": verified}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dirs", nargs="+", type=Path)
    parser.add_argument("--episodes", type=int, default=3)
    parser.add_argument("--every", type=int, default=10, help="measure every n-th frame the policy saw")
    parser.add_argument("--seed", type=int, default=2021, help="episode keys: split(PRNGKey(seed), episodes)")
    args = parser.parse_args(argv)
    print(
        "| run | parameters | frames (verified) | score spread | rho(score, contrast) | rho(score, abs k) "
        "| rho(score, q.k) | selected patches' contrast percentile |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for run_dir in args.run_dirs:
        result = es.load_run(run_dir)
        initial = build(result.config, env=result.env, policy=result.policy).template_params
        for name, params in (("initial", initial), ("trained", result.params)):
            m = measure(result, params, episodes=args.episodes, every=args.every, seed=args.seed)
            print(
                f"| {run_dir} | {name} | {m['frames']} ({m['verified']}) | {m['spread']:.1e} | {m['rho_contrast']:.2f} | {m['rho_key_norm']:.2f} "
                f"| {m['rho_mean_query']:.2f} | {m['percentile']:.1f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
