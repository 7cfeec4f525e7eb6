"""``lightemma evaluate RUN_DIR...``: the paper's Tables I and II from runs."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lightemma.report.tables import FORMATS


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "evaluate",
        help="score runs: FE, ADE/FDE per convention, time, cost, tokens (Tables I and II)",
        description="Score run directories (or folders holding runs) and print the paper's Tables I and II.",
    )
    parser.add_argument("run_dirs", nargs="*", metavar="RUN_DIR", help="run directory, or a folder holding runs")
    parser.add_argument(
        "--merge",
        nargs="+",
        metavar="JSON",
        help="join tables written by earlier `evaluate --format json` calls (same metric ids, versions and frame set; "
        "docs/evaluate.md#merging-evaluations); --format json or md",
    )
    parser.add_argument(
        "--convention",
        default="lightemma",
        choices=["lightemma", "stp3", "uniad", "all"],
        help="ADE convention (default: lightemma, the paper's; docs/definitions.md#metrics)",
    )
    parser.add_argument("--common", action="store_true", help="score every model on the frames valid for all of them")
    parser.add_argument("--format", choices=FORMATS, help="output format (default: md; with --merge json)")
    parser.add_argument(
        "--with-paper",
        action="store_true",
        help="put each run beside the paper's row of its model, with the difference",
    )
    parser.add_argument(
        "--parse",
        choices=["lenient", "strict", "paper", "json"],
        help="re-score every run's stored answers under this definition (default: each run's own; paper for imported runs)",
    )
    parser.add_argument(
        "--speed-range",
        type=float,
        nargs=2,
        metavar=("LO", "HI"),
        help="with --parse lenient|strict|json: plausible speeds, m/s",
    )
    parser.add_argument(
        "--max-curvature",
        type=float,
        metavar="K",
        help="with --parse lenient|strict|json: largest plausible |curvature|, 1/m",
    )
    parser.add_argument(
        "--keep-implausible",
        action="store_true",
        help="average implausible actions too (every answer the parse definition reads, as the paper's evaluation did; one can dominate a mean)",
    )
    parser.add_argument(
        "--miss-threshold",
        type=float,
        default=2.0,
        metavar="M",
        help="miss if any error exceeds M metres (default: 2.0)",
    )
    add_safety_arguments(parser)
    parser.add_argument(
        "--no-planning",
        dest="planning",
        action="store_false",
        help="skip the planning score (NAVSIM's PDMS / EPDMS and sub-scores; docs/definitions.md#planning-score)",
    )
    parser.add_argument(
        "--no-explanations",
        dest="explanations",
        action="store_false",
        help="skip the explanation audit (stated intent against plan and ground truth; docs/definitions.md#explanation-audit)",
    )
    add_statistics_arguments(parser, pairwise_default=False)
    parser.add_argument(
        "-o",
        "--output",
        type=Path,
        metavar="FILE",
        help="write the tables to FILE instead of stdout (its folder must exist)",
    )
    parser.set_defaults(func=run)
    return parser


def _parse_definition(args: argparse.Namespace):  # -> ParseDefinition | None
    from lightemma.errors import UserError
    from lightemma.evaluation.rescore import ParseDefinition

    if args.parse is None:
        if args.speed_range is not None or args.max_curvature is not None:
            raise UserError("--speed-range and --max-curvature need --parse lenient, strict or json")
        return None
    return ParseDefinition(args.parse, tuple(args.speed_range) if args.speed_range else None, args.max_curvature)


def add_safety_arguments(parser: argparse.ArgumentParser) -> None:
    """--dataroot / --version / --no-safety (shared with ``lightemma report``; docs/definitions.md#safety)."""
    parser.add_argument(
        "--dataroot",
        metavar="DIR",
        help="nuScenes folder for the off-road and collision columns (maps, annotations, poses; default: each run's own, as its manifest records)",
    )
    parser.add_argument(
        "--version",
        dest="dataset_version",
        metavar="V",
        help="with --dataroot: the nuScenes version (v1.0-test, v1.0-trainval, v1.0-mini, …)",
    )
    parser.add_argument(
        "--no-safety", dest="safety", action="store_false", help="skip the off-road and collision columns"
    )


def safety_options(args: argparse.Namespace) -> dict:
    """evaluate_runs keywords from the safety arguments: a --version without --dataroot (or the reverse), a --dataroot
    that is not a folder, or one without the --version folder is refused (UserError)."""
    from lightemma.errors import UserError

    if args.dataset_version and not args.dataroot:
        raise UserError("--version needs --dataroot")
    if args.dataroot and not args.dataset_version:
        raise UserError("--dataroot needs --version (the nuScenes version folder under it, e.g. v1.0-trainval)")
    if args.dataroot:
        root = Path(args.dataroot).expanduser()
        if not root.is_dir():
            raise UserError(f"--dataroot {args.dataroot} {'is not a folder' if root.exists() else 'does not exist'}")
        if not (root / args.dataset_version).is_dir():
            raise UserError(
                f"--version {args.dataset_version}: --dataroot {args.dataroot} has no folder {args.dataset_version}"
            )
    return {"safety": args.safety, "dataroot": args.dataroot, "version": args.dataset_version}


def add_statistics_arguments(parser: argparse.ArgumentParser, *, pairwise_default: bool) -> None:
    """--pairwise / --no-pairwise, --resamples, --seed (shared with ``lightemma report``)."""
    if pairwise_default:
        parser.add_argument(
            "--no-pairwise", dest="pairwise", action="store_false", help="skip the paired comparisons between runs"
        )
    else:
        parser.add_argument(
            "--pairwise",
            action="store_true",
            help="compare every pair of runs on their common frames (difference, interval, Holm-adjusted p)",
        )
    parser.add_argument(
        "--resamples",
        type=int,
        default=10_000,
        metavar="N",
        help="scene-bootstrap resamples and sign-flip permutations (default: 10000; 0: no intervals)",
    )
    parser.add_argument("--seed", type=int, default=0, metavar="S", help="seed of the resampling (default: 0)")


def resampling_of(args: argparse.Namespace):  # noqa: ANN201 - Resampling, imported lazily
    from lightemma.errors import UserError
    from lightemma.evaluation.stats import Resampling

    try:
        return Resampling(n_resamples=args.resamples, seed=args.seed)
    except ValueError as exc:
        raise UserError(str(exc).replace("n_resamples", "--resamples").replace("seed", "--seed")) from None


def _check_output(args: argparse.Namespace) -> None:
    """-o's folder must exist and -o must not be a folder (UserError), checked before any work."""
    from lightemma._text import printable
    from lightemma.errors import UserError

    if args.output is not None:  # before any work; a missing folder is a typo more often than a wish
        folder = args.output.parent
        if not folder.is_dir():
            raise UserError(
                f"-o {printable(args.output)}: the folder {printable(folder)} {'is not a folder' if folder.exists() else 'does not exist'} "
                "(create it first)"
            )
        if args.output.is_dir():
            raise UserError(f"-o {printable(args.output)} is a folder, not a file")


def _merge(args: argparse.Namespace) -> int:
    """``evaluate --merge``: the merged JSON (or Markdown with --format md); nothing written on a refusal."""
    import json

    from lightemma.errors import UserError
    from lightemma.evaluation.merge import merge_documents
    from lightemma.report.merged import merged_markdown

    if args.run_dirs:
        raise UserError(
            f"lightemma evaluate --merge joins JSON files only; {args.run_dirs[0]} is a RUN_DIR (evaluate the runs first)"
        )
    given = [
        flag
        for flag, on in (
            ("--common", args.common),
            ("--pairwise", args.pairwise),
            ("--with-paper", args.with_paper),
            ("--parse", args.parse is not None),
            ("--keep-implausible", args.keep_implausible),
        )
        if on
    ]
    if given:
        raise UserError(f"lightemma evaluate --merge joins tables as written; {given[0]} belongs to evaluating runs")
    if args.format is None:
        args.format = "json"
    if args.format not in ("json", "md"):
        raise UserError(f"lightemma evaluate --merge writes --format json or md, not {args.format}")
    _check_output(args)
    doc = merge_documents(args.merge)
    text = json.dumps(doc, indent=2) + "\n" if args.format == "json" else merged_markdown(doc)
    if args.output:
        args.output.write_text(text, encoding="utf-8")
        print(f"wrote {args.output}", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return 0


def refuse_disjoint_pairs(evaluation) -> None:  # noqa: ANN001 - Evaluation, imported lazily
    """``--pairwise`` between two runs without a frame scored in both is refused (UserError), in one line naming both
    runs and their frame-set fingerprints (docs/evaluate.md#runs-on-different-frame-sets)."""
    from lightemma.errors import UserError

    fps = {m.label: (m.fingerprint or {}).get("id", "an unrecorded frame set") for m in evaluation.models}
    for row in evaluation.pairwise or []:
        if row.get("frames") == 0:
            a, b = row["model_a"], row["model_b"]
            raise UserError(
                f"--pairwise: {a} (frame set {fps.get(a)}) and {b} (frame set {fps.get(b)}) "
                "have no frame scored in both; evaluate them apart, or without --pairwise"
            )


def run(args: argparse.Namespace) -> int:
    from lightemma._text import printable
    from lightemma.errors import UserError
    from lightemma.evaluation import evaluate_runs
    from lightemma.report.evaluation_tables import (
        evaluation_tables,
        frame_set_groups,
        frame_set_tables,
        json_frame_set_rows,
    )
    from lightemma.report.tables import render

    if args.merge:
        return _merge(args)
    if args.format is None:
        args.format = "md"
    if not args.run_dirs:
        raise UserError("lightemma evaluate: give a RUN_DIR (or --merge A.json B.json …)")
    parse = _parse_definition(args)
    _check_output(args)
    evaluation = evaluate_runs(
        args.run_dirs,
        convention=args.convention,
        common=args.common,
        miss_threshold=args.miss_threshold,
        parse=parse,
        keep_implausible=args.keep_implausible,
        resampling=resampling_of(args),
        pairwise=args.pairwise,
        planning=args.planning,
        explanations=args.explanations,
        **safety_options(args),
    )
    for warning in evaluation.warnings:
        print(f"lightemma evaluate: warning: {printable(warning)}", file=sys.stderr)  # names from outside: one line
    held = [
        m.label for m in evaluation.models if m.parse.get("mode") != "paper"
    ]  # their parser holds answers to the limits
    if args.keep_implausible and held:
        print(
            f"lightemma evaluate: note: --keep-implausible changes nothing for {printable(', '.join(held))}: parsed with "
            "plausibility limits, an implausible answer failed when read (Failed, not Implausible); --parse paper reads them "
            "by the paper's rules, without limits",
            file=sys.stderr,
        )
    if args.pairwise:
        refuse_disjoint_pairs(evaluation)
    tables = evaluation_tables(evaluation, with_paper=args.with_paper)
    if args.format != "json":  # JSON keeps one table per name, its rows say their frame set (below)
        tables = frame_set_tables(tables, evaluation)
    extra = {
        "common": evaluation.common,
        "n_common": evaluation.n_common,
        "parse": parse.to_dict() if parse else "each run's own",
        "keep_implausible": args.keep_implausible,
        "resampling": evaluation.resampling.to_dict(),
        "warnings": evaluation.warnings,
    }
    groups = frame_set_groups(evaluation)
    if args.format == "json" and groups is not None:  # each run row says its frame set; the top lists the groups
        tables = json_frame_set_rows(tables, evaluation)
        extra["frame_set_groups"] = groups
    from lightemma.evaluation.descriptors import evaluation_document, footer_lines
    from lightemma.report.evaluation_tables import provenance_footer

    if args.format == "json":  # every column's descriptor, the frame sets and the software (docs/evaluate.md)
        extra = {
            **evaluation_document(
                tables, evaluation, with_paper=args.with_paper, dataroot=args.dataroot, version=args.dataset_version
            ),
            **extra,
        }
        if evaluation.robustness is not None:  # a sweep: each variant against its clean run, with metric ids
            extra["robustness"] = evaluation.robustness.to_dict()
    text = render(tables, args.format, extra=extra)
    if args.format == "json":  # a value its descriptor does not allow (a rate above 1) is a bug: said, never printed
        import json

        from lightemma.evaluation.descriptors import check_evaluation_json

        check_evaluation_json(json.loads(text), "lightemma evaluate --format json")
    else:
        text += provenance_footer(footer_lines(evaluation), args.format)
    if args.output:
        args.output.write_text(text, encoding="utf-8")
        print(f"wrote {args.output}", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return 0
