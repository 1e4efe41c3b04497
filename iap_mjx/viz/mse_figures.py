"""The paper's Figures 3 and 4: mean squared errors of the trig, exp and hybrid estimators.

Both figures draw the closed forms of :func:`iap_mjx.attention.features.closed_form_mse`
(``m = 10``, ``r = 5``, iid draws) and put Monte Carlo estimates of the same MSEs on top, so a
reader sees the formulas and the estimators agree.

- Figure 3: MSE over the angle ``theta in [0, pi]`` and the common input length ``R``, one
  panel per estimator, with the slice at ``R = 1`` drawn in grey and its Monte Carlo points.
- Figure 4: slices at ``R = 1`` over an extended angle axis ``theta in [-3 pi, 3 pi]``.
"""

from __future__ import annotations

import logging
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from iap_mjx.attention import features as ft
from iap_mjx.viz.curves import save_png, subplots

logger = logging.getLogger(__name__)

M, R_SIGNS, D = 10, 5, 4
ESTIMATORS = ("trig", "exp", "hybrid")
SLICE_LENGTH = 1.0


def inputs_at(length: np.ndarray, theta: np.ndarray) -> tuple[jax.Array, jax.Array]:
    """``x, y (..., D)`` of norm ``length`` at angle ``theta`` (in the first two coordinates)."""
    length, theta = np.broadcast_arrays(np.asarray(length, np.float32), np.asarray(theta, np.float32))
    x = np.zeros(length.shape + (D,), np.float32)
    y = np.zeros_like(x)
    x[..., 0] = length
    y[..., 0], y[..., 1] = length * np.cos(theta), length * np.sin(theta)
    return jnp.asarray(x), jnp.asarray(y)


def closed_forms(length: np.ndarray, theta: np.ndarray) -> dict[str, np.ndarray]:
    """Closed-form MSE per estimator on a broadcast grid of lengths and angles."""
    x, y = inputs_at(length, theta)
    return {kind: np.asarray(ft.closed_form_mse(kind, x, y, m=M, r=R_SIGNS)) for kind in ESTIMATORS}


def monte_carlo(
    length: float, theta: np.ndarray, *, draws: int, seed: int = 0
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Empirical MSE per estimator at ``theta (P,)`` from ``draws`` iid projection draws.

    Returns ``{kind: (mse (P,), standard_error (P,))}``.
    """
    x, y = inputs_at(np.full_like(theta, length), theta)
    truth = ft.softmax_kernel(x, y)
    out = {}
    for kind in ESTIMATORS:

        @jax.jit
        def squared_errors(keys, kind=kind):
            def one(key):
                proj = ft.draw_projections(key, kind, m=M, d=D, r=R_SIGNS, orthogonal=False)
                estimate = jnp.sum(
                    ft.feature_map(kind, x, proj, role="query") * ft.feature_map(kind, y, proj, role="key"), axis=-1
                )
                return (estimate - truth) ** 2

            errors = jax.vmap(one)(keys)
            return jnp.mean(errors, axis=0), jnp.std(errors, axis=0) / np.sqrt(draws)

        mse, stderr = squared_errors(jax.random.split(jax.random.PRNGKey(seed), draws))
        out[kind] = (np.asarray(mse), np.asarray(stderr))
    return out


def figure3(path: Path, *, draws: int) -> Path:
    """MSE surfaces over ``(theta, R)`` with the ``R = 1`` slice and its Monte Carlo points."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    theta = np.linspace(0.0, np.pi, 121)
    lengths = np.linspace(-1.5, 1.5, 121)  # symmetrised along the length axis, as in the paper
    grid_theta, grid_length = np.meshgrid(theta, lengths)
    surfaces = closed_forms(np.abs(grid_length), grid_theta)
    slice_curves = closed_forms(np.full_like(theta, SLICE_LENGTH), theta)
    mc_theta = np.linspace(0.0, np.pi, 9)
    mc = monte_carlo(SLICE_LENGTH, mc_theta, draws=draws)
    fig = plt.figure(figsize=(15, 4.8))
    names = {"trig": "trigonometric", "exp": "positive (FAVOR+)", "hybrid": "hybrid"}
    for index, kind in enumerate(ESTIMATORS):
        ax = fig.add_subplot(1, 3, index + 1, projection="3d")
        ax.plot_surface(grid_theta, grid_length, surfaces[kind], cmap="viridis", alpha=0.75, linewidth=0)
        ax.plot(
            theta,
            np.full_like(theta, SLICE_LENGTH),
            slice_curves[kind],
            color="grey",
            linewidth=3,
            label=f"closed form, R = {SLICE_LENGTH:g}",
        )
        ax.scatter(
            mc_theta,
            np.full_like(mc_theta, SLICE_LENGTH),
            mc[kind][0],
            color="red",
            s=18,
            depthshade=False,
            label=f"Monte Carlo ({draws} draws)",
        )
        ax.set_xlabel("angle θ")
        ax.set_ylabel("length R")
        ax.set_zlabel("MSE")
        ax.set_title(f"{names[kind]}, m = {M}" + (f", r = {R_SIGNS}" if kind == "hybrid" else ""))
        ax.legend(loc="upper left", fontsize=7)
    fig.suptitle("Figure 3: MSE of the softmax-kernel estimators (iid features)")
    return save_png(fig, path, dpi=110)


def figure4(path: Path, *, draws: int) -> Path:
    """Slices at ``R = 1`` over ``theta in [-3 pi, 3 pi]``, closed forms and Monte Carlo points."""
    theta = np.linspace(-3 * np.pi, 3 * np.pi, 1201)
    curves = closed_forms(np.full_like(theta, SLICE_LENGTH), theta)
    mc_theta = np.linspace(-3 * np.pi, 3 * np.pi, 25)
    mc = monte_carlo(SLICE_LENGTH, mc_theta, draws=draws, seed=1)
    fig, ax = subplots(figsize=(9, 4.5))
    colours = {"trig": "tab:blue", "exp": "tab:orange", "hybrid": "tab:green"}
    for kind in ESTIMATORS:
        ax.plot(theta, curves[kind], color=colours[kind], label=f"{kind} (closed form)")
        ax.scatter(
            mc_theta, mc[kind][0], color=colours[kind], marker="x", s=30, label=f"{kind} (Monte Carlo, {draws} draws)"
        )
    ax.set_xticks(
        np.arange(-3, 4) * np.pi,
        [f"{k}π" if k not in (0, 1, -1) else {0: "0", 1: "π", -1: "-π"}[k] for k in range(-3, 4)],
    )
    ax.set_xlabel("angle θ (extended axis)")
    ax.set_ylabel("MSE")
    ax.set_yscale("symlog", linthresh=1e-2)
    ax.set_ylim(bottom=0)
    ax.set_title(f"Figure 4: slices at R = {SLICE_LENGTH:g}, m = {M}, r = {R_SIGNS}")
    ax.legend(fontsize=7, ncol=2)
    return save_png(fig, path, dpi=110)


def write_mse_figures(out_dir: str | Path, *, draws: int = 100_000) -> list[Path]:
    """Writes ``figure3_mse.png`` and ``figure4_mse_slices.png`` into ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [
        figure3(out_dir / "figure3_mse.png", draws=draws),
        figure4(out_dir / "figure4_mse_slices.png", draws=draws),
    ]
    for path in paths:
        logger.info("wrote %s", path)
    return paths
