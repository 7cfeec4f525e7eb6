"""``lightemma demo``: synthetic data → baseline runs → evaluation → report, with no dataset and no keys."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lightemma.errors import InputError


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "demo",
        help="run the whole benchmark offline on synthetic data and write a report (start here)",
        description="Write a small synthetic nuScenes-format dataset, run the baselines (and, for each API key "
        "set, one of the paper's models on a few frames), evaluate, and write the report into ./lightemma-demo/.",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=Path("lightemma-demo"),
        metavar="DIR",
        help="output folder (default: ./lightemma-demo)",
    )
    parser.add_argument(
        "--scenes", type=int, default=None, metavar="N", help="synthetic scenes (default: one per scenario kind)"
    )
    parser.add_argument(
        "--keyframes",
        type=int,
        default=24,
        metavar="N",
        help="keyframes per scene (default: 24, i.e. 10 frames per scene)",
    )
    parser.add_argument("--no-api", action="store_true", help="run no API model even when a key is set")
    parser.add_argument(
        "--api-limit",
        type=int,
        default=12,
        metavar="N",
        help="frames per API model (default: 12; they cost money); when one runs, every model is "
        "scored on the frames scored in every run",
    )
    parser.add_argument("--api-base", metavar="URL", help="send the API models to this OpenAI-compatible server")
    parser.set_defaults(func=run)
    return parser


def _progress(message: str) -> None:
    """Progress lines go to stderr, so that stdout holds only where the results are."""
    print(message, file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    from lightemma.offline_demo import run_demo

    if args.keyframes < 15:
        raise InputError(
            f"--keyframes must be at least 15 (the reference window needs 15 keyframes for one frame), got {args.keyframes}"
        )
    result = run_demo(
        args.out,
        scenes=args.scenes,
        keyframes=args.keyframes,
        use_api=not args.no_api,
        api_limit=args.api_limit,
        api_base=args.api_base,
        log=_progress,
    )
    print(f"demo report: {result.index}")
    print(f"runs: {result.out / 'runs'}   dataset: {result.dataroot}")
    return 0
