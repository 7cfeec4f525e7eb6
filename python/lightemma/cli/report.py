"""``lightemma report RUN_DIR... --out DIR``: tables, figures and scenario analysis in one folder."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "report",
        help="write tables, figures and the scenario analysis of runs into one folder",
        description="Evaluate runs and write Tables I/II with scene-bootstrap intervals, the paired comparisons, the bubble "
        "chart, scenario tables, the history-bias figure and pictures of the frames where models disagree most into DIR, with an index.md.",
    )
    parser.add_argument("run_dirs", nargs="+", metavar="RUN_DIR", help="run directory, or a folder holding runs")
    parser.add_argument(
        "--out",
        required=True,
        type=Path,
        metavar="DIR",
        help="report folder (written whole, then swapped in; an existing folder must be a lightemma report)",
    )
    parser.add_argument(
        "--convention",
        default="all",
        choices=["lightemma", "stp3", "uniad", "all"],
        help="ADE convention(s) (default: all; docs/definitions.md#metrics)",
    )
    parser.add_argument("--common", action="store_true", help="score every model on the frames valid for all of them")
    parser.add_argument("--no-paper", action="store_true", help="leave the paper's rows out of the tables and chart")
    parser.add_argument(
        "--top",
        type=int,
        default=5,
        metavar="N",
        help="pictures of the N frames where models disagree most (default: 5)",
    )
    parser.add_argument(
        "--dataroot", metavar="DIR", help="dataset location for camera images, if not where the runs were made"
    )
    parser.add_argument(
        "--version",
        dest="dataset_version",
        metavar="V",
        help="with --dataroot: its nuScenes version, for the off-road and collision columns (default: each run's own)",
    )
    parser.add_argument(
        "--no-safety", dest="safety", action="store_false", help="skip the off-road and collision columns and views"
    )
    parser.add_argument(
        "--frame", action="append", default=[], metavar="FRAME_ID", help="also draw this frame (repeatable)"
    )
    parser.add_argument(
        "--no-pictures",
        action="store_true",
        help="skip per-frame pictures and camera thumbnails (the HTML frame browser still draws bird's-eye views)",
    )
    parser.add_argument("--svg", action="store_true", help="also write every figure as SVG (PNG only by default)")
    parser.add_argument(
        "--force", action="store_true", help="replace DIR even when it holds something other than a lightemma report"
    )
    from lightemma.cli.evaluate import add_statistics_arguments

    add_statistics_arguments(parser, pairwise_default=True)
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    from lightemma.cli.evaluate import resampling_of
    from lightemma.report import write_report

    index = write_report(
        args.run_dirs,
        args.out,
        convention=args.convention,
        common=args.common,
        with_paper=not args.no_paper,
        top=args.top,
        dataroot=args.dataroot,
        pictures=not args.no_pictures,
        frames=args.frame,
        pairwise=args.pairwise,
        resampling=resampling_of(args),
        svg=args.svg,
        force=args.force,
        progress=sys.stderr.isatty(),  # no bar (its \r redraws) in a log file or a pipe, as import and synth
        version=args.dataset_version,
        safety=args.safety,
    )
    print(f"report written to {index} (browse {index.with_name('index.html')})")
    return 0
