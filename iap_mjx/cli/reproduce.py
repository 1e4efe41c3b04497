"""``iap-mjx reproduce FIGURE``: the paper's figures and tables, one subcommand each.

Each figure's subcommand takes only its own options: another figure's (``reproduce fig7
--tasks ...``) is refused by the parser, not ignored, and no option is taken for an
abbreviation of another (``--seed``, fig7's and table2's one training seed, is never ``--seeds``). Its function hands them to
the module that trains, evaluates and reports the figure. Every figure is resumable: finished
runs are skipped, the others continue from their last checkpoint.

Per figure, ``_add_<figure>`` builds its parser and sits next to ``_<figure>``, which hands the
parsed options to the figure's module; :func:`add_commands` calls the builders in turn.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from iap_mjx.cli import arguments
from iap_mjx.cli.arguments import usage_error


def cmd_reproduce(args: argparse.Namespace) -> int:
    """Runs the figure's function (``args.run_figure``) and prints its markdown; a bad setting
    exits 2 before anything trains, Ctrl-C exits 130 with a hint that the command resumes."""
    try:
        markdown = args.run_figure(args)
    except ValueError as error:
        return usage_error(error)
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


def _figure(
    figures: Any, name: str, summary: str, description: str, function: Any, *, overrides: bool = True
) -> argparse.ArgumentParser:
    """Adds figure ``name``'s parser to ``figures`` (the ``reproduce`` subparsers), with the
    options every figure takes (``key=value`` overrides unless ``overrides=False``, ``--out``);
    running it calls ``function(args)``."""
    parser = figures.add_parser(name, help=summary, description=f"{summary}: {description}", allow_abbrev=False)
    if overrides:
        parser.add_argument(
            "overrides", nargs="*", metavar="key=value", help="applied to every preset, e.g. run.iterations=100"
        )
    parser.add_argument("--out", default="results", help="output directory (default: results)")
    parser.set_defaults(func=cmd_reproduce, run_figure=function, command_parser=parser)
    return parser


# the options that several figures share
def _add_seeds(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seeds", type=arguments.count, default=3, help="training seeds per preset (default 3)")


def _add_episodes(parser: argparse.ArgumentParser, what: str) -> None:
    parser.add_argument("--episodes", type=arguments.count, default=20, help=f"evaluation episodes {what} (default 20)")


def _add_results(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--results", default=None, metavar="RESULTS.md", help="rewrite this markdown file's section")


def _add_report_only(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--report-only",
        action="store_true",
        help="train nothing: report the runs already in --out, however far they got",
    )


def _add_section(parser: argparse.ArgumentParser, default: str, what: str, example: str) -> None:
    parser.add_argument(
        "--section",
        default=default,
        help=f"names the --results section and the experiments/ folder{what} (default {default}; e.g. "
        f"{example} for a second setting beside the first)",
    )


def _add_export(parser: argparse.ArgumentParser, example: str) -> None:
    parser.add_argument(
        "--export",
        default=None,
        metavar="DIR",
        help=f"copy each run's newest checkpoint, config and metrics to {example}, tracked by git",
    )


def _fig1_fig6(args: argparse.Namespace) -> str:
    from iap_mjx.paper import fig1_fig6

    return fig1_fig6.reproduce_fig1_fig6(
        args.figure,
        args.out,
        seeds=args.seeds,
        overrides=tuple(args.overrides),
        passes=args.passes,
        train=not args.report_only,
    )


def _add_fig1_fig6(figures: Any) -> None:
    for name in ("fig1", "fig6"):
        parser = _figure(
            figures,
            name,
            "inference time per pass next to return",
            "times one forward pass of every attention variant and trains each preset on --seeds seeds",
            _fig1_fig6,
        )
        _add_seeds(parser)
        parser.add_argument("--passes", type=arguments.count, default=100, help="timed forward passes (default 100)")
        _add_report_only(parser)


def _fig7(args: argparse.Namespace) -> str:
    from iap_mjx.paper import fig7

    return fig7.reproduce_fig7(
        args.out,
        seed=args.seed,
        overrides=tuple(args.overrides),
        episodes=args.episodes,
        train=not args.report_only,
        results=args.results,
    )


def _add_fig7(figures: Any) -> None:
    parser = _figure(
        figures,
        "fig7",
        "the patch sweep",
        "on dcs-cartpole-swingup, one seed per cell of patch size {2, 4, 8} x selected patches "
        "{5, 10, 20}, then d_qk {2, 4, 8} at the best cell",
        _fig7,
    )
    parser.add_argument("--seed", type=arguments.index, default=0, help="the training seed of every cell (default 0)")
    _add_episodes(parser, "per run, in the training condition")
    _add_results(parser)
    _add_report_only(parser)


def _fig8(args: argparse.Namespace) -> str:
    from iap_mjx.paper import fig8

    return fig8.reproduce_fig8(
        args.out, overrides=tuple(args.overrides), train=not args.report_only, results=args.results
    )


def _add_fig8(figures: Any) -> None:
    parser = _figure(
        figures,
        "fig8",
        "return against wall-clock",
        "brute force, IAP ReLU and hybrid on dcs-cartpole-swingup, each method's seconds per "
        "iteration measured first (leave the machine alone)",
        _fig8,
    )
    _add_results(parser)
    _add_report_only(parser)


def _table1(args: argparse.Namespace) -> str:
    from iap_mjx.paper import table1

    return table1.reproduce_table1(
        args.out,
        seeds=args.seeds,
        overrides=tuple(args.overrides),
        episodes=args.episodes,
        train=not args.report_only,
        tasks=args.tasks or table1.TASKS,
        results=args.results,
        export=args.export,
        policy=args.policy,
        section=args.section,
    )


def _add_table1(figures: Any) -> None:
    parser = _figure(
        figures,
        "table1",
        "the Distracting Control Suite, static medium",
        "trains dcs-<task> for every task and seed, then evaluates each finished run in four "
        "conditions (training backgrounds, held-out backgrounds, dynamic, no distraction); "
        "--policy cnn does the same for the convolutional baseline",
        _table1,
    )
    _add_seeds(parser)
    _add_episodes(parser, "per run and condition")
    parser.add_argument(
        "--tasks", type=arguments.names, default=None, help="comma-separated suite tasks (default: all six)"
    )
    parser.add_argument(
        "--policy",
        default="iap",
        choices=["iap", "cnn"],
        help="iap (dcs-<task>) or cnn, the same-budget convolutional baseline (dcs-<task>-cnn), "
        "reported beside the IAP runs in --out",
    )
    _add_results(parser)
    _add_export(parser, "DIR/<task>-seed<k>, with --policy cnn DIR/<task>-cnn-seed<k> (e.g. pretrained/dcs)")
    _add_section(parser, "table1", ", and table1.json (with --policy cnn: <section>-cnn)", "table1-fs2")
    _add_report_only(parser)


def _fig11(args: argparse.Namespace) -> str:
    from iap_mjx.paper import fig11

    return fig11.reproduce_fig11(
        args.out,
        seeds=args.seeds,
        overrides=tuple(args.overrides),
        episodes=args.episodes,
        train=not args.report_only,
        results=args.results,
        export=args.export,
        section=args.section,
        courses_of=args.courses_of,
    )


def _add_fig11(figures: Any) -> None:
    parser = _figure(
        figures,
        "fig11",
        "the quadruped's high levels on the walls course",
        "trains quadruped-walls-iap, -cnn and -blind on --seeds seeds, then evaluates each finished "
        "run on --episodes courses not seen in training (walls passed, falls, wall contacts, distance)",
        _fig11,
    )
    _add_seeds(parser)
    _add_episodes(parser, "per run, each on a course not seen in training")
    _add_results(parser)
    _add_export(parser, "DIR/<preset>-seed<k> (e.g. pretrained/quadruped)")
    _add_section(parser, "fig11", "", "fig11-turn")
    _add_report_only(parser)
    parser.add_argument(
        "--courses-of",
        type=arguments.index,
        default=None,
        metavar="ITERATION",
        help="evaluate on the courses of an ITERATION-iteration checkpoint (e.g. 200: another budget's report), "
        "not each checkpoint's own; writes fig11-courses-of-ITERATION.json/.png",
    )


def _table2(args: argparse.Namespace) -> str:
    from iap_mjx.paper import table2

    return table2.reproduce_table2(
        args.out,
        settings=args.settings or table2.SETTINGS,
        seed=args.seed,
        overrides=tuple(args.overrides),
        episodes=args.episodes,
        train=not args.report_only,
        results=args.results,
        export=args.export,
    )


def _add_table2(figures: Any) -> None:
    parser = _figure(
        figures,
        "table2",
        "the quadruped's patch sizes and strides",
        "quadruped-walls-iap at each --settings patch size and stride, one --seed, reporting the "
        "maximum episode return and the walls passed on unseen courses",
        _table2,
    )
    parser.add_argument(
        "--settings",
        type=arguments.settings,
        default=None,
        metavar="PxS,...",
        help="comma-separated patch size x stride (default 1x1,2x2,4x4,4x2)",
    )
    parser.add_argument("--seed", type=arguments.index, default=0, help="the training seed (default 0)")
    _add_episodes(parser, "per finished run, each on a course not seen in training")
    _add_results(parser)
    _add_export(
        parser,
        "DIR/table2-p<p>-s<s>-seed<k>, the preset's own setting DIR/quadruped-walls-iap-seed<k> (e.g. pretrained/quadruped)",
    )
    _add_report_only(parser)


def _fig10(args: argparse.Namespace) -> str:
    from iap_mjx.paper import fig10

    return fig10.reproduce_fig10(args.out, run_dirs=args.run_dirs, frames=args.frames, results=args.results)


def _add_fig10(figures: Any) -> None:
    parser = _figure(
        figures,
        "fig10",
        "the quadruped's camera with the selected patches",
        "a PNG strip along one episode of each of --run-dirs, drawn from the trained runs as they are",
        _fig10,
        overrides=False,
    )
    parser.add_argument(
        "--run-dirs",
        type=arguments.names,
        default=None,
        metavar="DIR,...",
        help="comma-separated trained quadruped-walls-iap runs (default: "
        "OUT/table2-p1-s1-seed0,OUT/quadruped-walls-iap-seed0)",
    )
    parser.add_argument("--frames", type=arguments.count, default=6, help="frames per strip (default 6)")
    _add_results(parser)


def _gates(args: argparse.Namespace) -> str:
    from iap_mjx.paper import gates

    return gates.reproduce_gates(
        args.out,
        seeds=args.seeds,
        overrides=tuple(args.overrides),
        episodes=args.episodes,
        frames=args.frames,
        train=not args.report_only,
        results=args.results,
        export=args.export,
    )


def _add_gates(figures: Any) -> None:
    parser = _figure(
        figures,
        "gates",
        "beyond the paper: the quadruped's gates corridor seen through depth",
        "trains quadruped-gates-iap and -blind on --seeds seeds, evaluates each finished run on "
        "--episodes corridors not seen in training (gates passed, contacts, falls, distance; IAP "
        "also with its eyes closed), and draws IAP seed 0's depth patches along one corridor",
        _gates,
    )
    parser.add_argument("--seeds", type=arguments.count, default=1, help="training seeds per preset (default 1)")
    _add_episodes(parser, "per run, each on a corridor not seen in training")
    parser.add_argument("--frames", type=arguments.count, default=6, help="frames of the strip (default 6)")
    _add_results(parser)
    _add_export(parser, "DIR/<preset>-seed<k> (e.g. pretrained/quadruped-gates)")
    _add_report_only(parser)


def add_commands(commands: Any) -> None:
    """Adds ``reproduce`` and its one subcommand per figure to the ``iap-mjx`` subparsers."""
    repro = commands.add_parser(
        "reproduce",
        help="the paper's Figure 1, 6 (inference time vs return), 7 (patch sweep), 8 (wall-clock), "
        "Table 1, the quadruped's Figures 10, 11 and Table 2, or its gates corridor (beyond the paper)",
        description="Trains, evaluates and reports one of the paper's figures or tables; "
        "`iap-mjx reproduce FIGURE -h` lists that figure's options. Rerunning a command resumes "
        "it: finished runs are skipped, the others continue from their last checkpoint.",
    )
    figures = repro.add_subparsers(dest="figure", required=True, metavar="FIGURE")
    _add_fig1_fig6(figures)
    _add_fig7(figures)
    _add_fig8(figures)
    _add_table1(figures)
    _add_fig11(figures)
    _add_table2(figures)
    _add_fig10(figures)
    _add_gates(figures)
