"""``lightemma import SRC...``: the LightEMMA reference scripts' result folders become runs."""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "import",
        help="turn the reference scripts' result folders (<model>/output/*.json) into runs",
        description=(
            "Import result folders written by the LightEMMA reference scripts: one run per model folder, "
            "in the normal run format, scored by default as the paper scored it (its FE / FE corr rules, "
            "Euler integration). Importing the same folder again writes nothing. See docs/import.md."
        ),
    )
    parser.add_argument(
        "sources",
        nargs="+",
        metavar="SRC",
        type=Path,
        help="a model folder (holding output/*.json) or a folder holding several",
    )
    parser.add_argument(
        "--output", type=Path, default=Path("runs"), metavar="DIR", help="where the runs go (default: runs)"
    )
    parser.add_argument(
        "--dataset-kind",
        default="nuscenes",
        choices=["nuscenes", "synthetic"],
        help="what the reference scripts ran on (default: nuscenes; recorded, shown by evaluate --with-paper)",
    )
    parser.add_argument(
        "--jobs",
        type=int,
        metavar="N",
        help="model folders imported at once, each in its own process (default: one per folder, at most 4 and the CPUs)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    from lightemma._text import printable
    from lightemma.runs.importer import default_jobs, import_reference
    from lightemma.runs.reference import find_model_folders

    def warn(line: str) -> None:
        print(
            f"lightemma import: warning: {printable(line)}", file=sys.stderr, flush=True
        )  # one line, whatever the names

    jobs = args.jobs if args.jobs is not None else default_jobs(sum(len(find_model_folders(s)) for s in args.sources))
    try:
        results = import_reference(
            args.sources,
            args.output,
            dataset_kind=args.dataset_kind,
            warn=warn,
            progress=not args.quiet and sys.stderr.isatty(),
            jobs=jobs,
        )
    except KeyboardInterrupt as exc:  # SIGINT, SIGTERM or SIGHUP: the workers are stopped, no partial folder is left
        if not hasattr(exc, "runs_total") or not hasattr(exc, "runs_done"):  # the importer sets both together
            raise
        name, signum = getattr(exc, "name", "SIGINT"), getattr(exc, "signum", signal.SIGINT)
        print(
            f"lightemma import: interrupted by {name}; {exc.runs_done} of {exc.runs_total} model folder(s) imported, "
            "run the same command again to import the rest",
            file=sys.stderr,
            flush=True,
        )
        return 128 + int(signum)
    for result in results:
        print(printable(result.describe()))
    return 1 if any(r.outcome == "nothing to import" for r in results) else 0
