"""Reproducing the paper's Figure 7: how the attention's shape matters on the Distracting
Control Suite.

On ``dcs-cartpole-swingup`` (the suite's cheapest task: 8 control steps per frame), one seed
per cell at a budget the caller states in iterations (``run.iterations=...``):

- the grid patch size ``{2, 4, 8}`` x selected patches ``l`` in ``{5, 10, 20}`` at
  ``d_qk = 4`` (the preset's);
- then query/key dimension ``d_qk`` in ``{2, 4, 8}`` at the grid's best cell, chosen once all
  nine cells are finished (its ``d_qk = 4`` run is the grid cell itself).

Each cell trains in ``<out>/fig7-p<p>-l<l>-d<d>-seed<k>`` (resumed, skipped once finished; the
training loop is :func:`iap_mjx.paper.report_runs.trained_curve`'s). A cell's return is its final
centre's mean over ``episodes`` evaluation episodes in the training condition, stored in the
run's ``eval.json`` (:func:`iap_mjx.paper.evaluations.evaluate_conditions`). Writes ``fig7.json`` and
``fig7.png`` and returns the markdown table.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from iap_mjx import configs
from iap_mjx.checks import require_int
from iap_mjx.files import write_json
from iap_mjx.paper.report_runs import (
    built_policies,
    check_evaluated,
    check_not_swept,
    check_seed_not_set,
    reported_run,
    train_command,
)
from iap_mjx.sections import mean_std, reproduce_command, tracked_copy, write_results_section

logger = logging.getLogger(__name__)

PRESET = "dcs-cartpole-swingup"
PATCH_SIZES = (2, 4, 8)
TOP_LS = (5, 10, 20)
D_QKS = (2, 4, 8)
GRID_D_QK = 4
TRAIN_CONDITION: dict[str, tuple[str, ...]] = {"train": ()}


def cell_overrides(patch_size: int, top_l: int, d_qk: int) -> tuple[str, ...]:
    return (f"policy.patch_size={patch_size}", f"policy.top_l={top_l}", f"policy.d_qk={d_qk}")


def run_name(patch_size: int, top_l: int, d_qk: int, seed: int) -> str:
    return f"fig7-p{patch_size}-l{top_l}-d{d_qk}-seed{seed}"


def check(overrides: tuple[str, ...]) -> dict[tuple[int, int, int], configs.TrainConfig]:
    """Every cell's config (grid and every possible ``d_qk`` row), validated before anything
    compiles; ``overrides`` may not set what the sweep varies."""
    from iap_mjx import envs

    check_seed_not_set("fig7", overrides)
    check_not_swept(
        "fig7",
        overrides,
        ("policy.patch_size", "policy.top_l", "policy.d_qk"),
        "the patch size, top_l and d_qk per cell",
    )
    cells = {}
    for p in PATCH_SIZES:
        for top_l in TOP_LS:
            for d in D_QKS:
                cells[p, top_l, d] = configs.apply_overrides(
                    configs.get(PRESET), (*overrides, *cell_overrides(p, top_l, d))
                )
    check_evaluated("fig7", cells.values())
    first = next(iter(cells.values()))
    envs.check_spec(first.env)  # the cells share one env
    return cells


def cell_row(
    cell: tuple[int, int, int], config: configs.TrainConfig, seed: int, out_dir: Path, *, train: bool, episodes: int
) -> dict[str, Any] | None:
    """One cell: its curve and (finished) its final centre's evaluation returns."""
    from iap_mjx.paper.evaluations import evaluate_conditions

    def evaluate(run_dir: Path, step: int) -> dict[str, Any]:
        returns = evaluate_conditions(run_dir, step, episodes=episodes, conditions=TRAIN_CONDITION)["train"]
        return {"returns": returns, "return": float(np.mean(returns))}

    run_dir = out_dir / run_name(*cell, seed)
    reported = reported_run(config, seed, run_dir, train=train, evaluate=evaluate)
    if reported is None:
        return None
    return {"patch_size": cell[0], "top_l": cell[1], "d_qk": cell[2], **reported[0], "run": run_dir.name}


def best_cell(rows: list[dict[str, Any]]) -> tuple[int, int] | None:
    """The grid's ``(patch_size, top_l)`` of highest return, once all nine are finished."""
    grid = {(row["patch_size"], row["top_l"]): row for row in rows if row["d_qk"] == GRID_D_QK and row["finished"]}
    if len(grid) < len(PATCH_SIZES) * len(TOP_LS):
        return None
    return max(grid, key=lambda cell: grid[cell]["return"])


def reproduce_fig7(
    out_dir: str | Path,
    *,
    seed: int = 0,
    overrides: tuple[str, ...] = (),
    episodes: int = 20,
    train: bool = True,
    results: str | Path | None = None,
) -> str:
    """Trains (``train=False``: only reads) the grid, then the ``d_qk`` row at its best cell;
    writes ``fig7.json`` / ``fig7.png`` in ``out_dir`` and returns the markdown table;
    ``results``: a markdown file whose ``fig7`` section is rewritten with it."""
    require_int("episodes", episodes)
    require_int("seed", seed, 0)
    cells = check(tuple(overrides))
    patches = {cell: policy.layer.num_patches for cell, policy in built_policies(cells).items()}
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    grid = [(p, top_l, GRID_D_QK) for p in PATCH_SIZES for top_l in TOP_LS]
    rows = [row for cell in grid if (row := cell_row(cell, cells[cell], seed, out_dir, train=train, episodes=episodes))]
    best = best_cell(rows)
    if best is not None:  # the d_qk row at the grid's best cell, once the grid is finished
        row_cells = [(*best, d) for d in D_QKS if d != GRID_D_QK]
        rows += [
            row
            for cell in row_cells
            if (row := cell_row(cell, cells[cell], seed, out_dir, train=train, episodes=episodes))
        ]
    if not rows:
        raise ValueError(f"no fig7 runs in {out_dir} to report")
    for row in rows:
        row["patches"] = patches[row["patch_size"], row["top_l"], row["d_qk"]]
    write_json(out_dir / "fig7.json", {"best": best, "rows": rows})
    png = plot(rows, best, out_dir / "fig7.png")
    markdown = table(rows, best, overrides=tuple(overrides), seed=seed)
    if results is not None:
        write_results(Path(results), markdown, png, overrides=tuple(overrides), episodes=episodes, seed=seed)
    return markdown


def cell_command(overrides: tuple[str, ...], row: dict[str, Any], seed: int) -> str:
    """The ``iap-mjx train`` command of one cell."""
    cell = cell_overrides(row["patch_size"], row["top_l"], row["d_qk"])
    return train_command(PRESET, (*overrides, *cell), seed)


def table(rows: list[dict[str, Any]], best: tuple[int, int] | None, *, overrides: tuple[str, ...], seed: int) -> str:
    """Markdown: one line per cell with its command, its return and how far it got."""
    lines = [
        "| patch size | l | d_qk | patches L | return (mean ± std, episodes) | best eval return on the way | "
        "iterations | wall-clock (s) | command |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for row in rows:
        final = f"{mean_std(row['returns'])} ({len(row['returns'])})" if row["finished"] else "running"
        lines.append(
            f"| {row['patch_size']} | {row['top_l']} | {row['d_qk']} | {row['patches']:,} | {final} | "
            f"{max(row['curve']):.1f} | {row['iterations']} | {row['seconds']:.0f} | "
            f"`{cell_command(overrides, row, seed)}` |"
        )
    lines.append("")
    lines.append(
        "Best grid cell (patch size, l): "
        + (f"{best}" if best is not None else "not chosen yet (the grid is not finished)")
        + "."
    )
    return "\n".join(lines)


def plot(rows: list[dict[str, Any]], best: tuple[int, int] | None, path: Path) -> Path:
    """Left: the grid's returns as an annotated heat map (patch size x l). Right: return
    against ``d_qk`` at the best cell."""
    from iap_mjx.viz.curves import save_png, subplots

    grid = np.full((len(PATCH_SIZES), len(TOP_LS)), np.nan)
    for row in rows:
        if row["d_qk"] == GRID_D_QK and row["finished"]:
            grid[PATCH_SIZES.index(row["patch_size"]), TOP_LS.index(row["top_l"])] = row["return"]
    fig, (ax, bars) = subplots(1, 2, figsize=(10, 4))
    image = ax.imshow(grid, cmap="viridis", origin="lower")
    for i in range(len(PATCH_SIZES)):
        for j in range(len(TOP_LS)):
            ax.text(j, i, "-" if np.isnan(grid[i, j]) else f"{grid[i, j]:.0f}", ha="center", va="center", color="white")
    ax.set_xticks(range(len(TOP_LS)), [str(l) for l in TOP_LS])
    ax.set_yticks(range(len(PATCH_SIZES)), [str(p) for p in PATCH_SIZES])
    ax.set_xlabel("selected patches l")
    ax.set_ylabel("patch size")
    ax.set_title(f"cartpole-swingup (static medium), d_qk = {GRID_D_QK}")
    fig.colorbar(image, ax=ax, label="return")
    if best is not None:
        done = sorted(
            (row["d_qk"], row["return"])
            for row in rows
            if (row["patch_size"], row["top_l"]) == best and row["finished"]
        )
        bars.bar([str(d) for d, _ in done], [r for _, r in done], color="tab:blue")
        bars.set_title(f"d_qk at patch size {best[0]}, l = {best[1]}")
    else:
        bars.set_title("d_qk row: after the grid")
    bars.set_xlabel("query/key dimension d_qk")
    bars.set_ylabel("return")
    return save_png(fig, path)


def write_results(
    path: Path, markdown: str, png: Path, *, overrides: tuple[str, ...], episodes: int, seed: int
) -> None:
    """The ``fig7`` section of ``path``: the command, the figure and the table."""
    command_line = reproduce_command(
        "fig7", [*overrides, f"--seed {seed}", f"--episodes {episodes}"], out=png.parent, results=path
    )
    image = tracked_copy(png, path, "fig7")
    body = (
        f"## Figure 7: patch size, selected patches and d_qk on cartpole-swingup (static medium)\n\n"
        f"Command: `{command_line}`. One seed per cell (seed {seed}). Return: the final centre's mean over {episodes} "
        f"evaluation episodes in the training condition.\n\n![fig7]({image})\n\n{markdown}\n"
    )
    write_results_section(path, "fig7", body)
