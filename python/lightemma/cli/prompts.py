"""``lightemma prompts check PROMPT_SET RUN_DIR``: does a prompt set say what an imported run's prompts said?"""

from __future__ import annotations

import argparse


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "prompts",
        help="prompt sets: check one against the prompts an imported run stored",
        description="Prompt-set tools. See docs/import.md for writing a prompt set that reproduces reference prompts.",
    )
    sub = parser.add_subparsers(dest="prompts_command", metavar="ACTION", required=True)
    check = sub.add_parser(
        "check",
        help="compare a prompt set, rendered per frame, with an imported run's stored prompts",
        description=(
            "Render PROMPT_SET for every frame of RUN_DIR (a run made by `lightemma import`) with that frame's own "
            "stage texts and history, fold whitespace as the reference stored its prompts, and compare per stage. "
            "Prints, per stage, how many frames match and the first differing character. Exit status 1 when any differs."
        ),
    )
    check.add_argument("prompt_set", metavar="PROMPT_SET", help="a shipped prompt set's name or a prompt-set JSON file")
    check.add_argument("run_dir", metavar="RUN_DIR", help="a run directory made by lightemma import")
    check.add_argument("--limit", type=int, metavar="N", help="check the first N frames only")
    check.set_defaults(func=run_check)
    return parser


def run_check(args: argparse.Namespace) -> int:
    from lightemma.errors import UserError
    from lightemma.prompts import load_prompt_set
    from lightemma.prompts.check import check_prompts, format_checks

    if args.limit is not None and args.limit < 1:
        raise UserError(f"--limit must be at least 1, got {args.limit}")
    prompts = load_prompt_set(args.prompt_set)
    checks = check_prompts(prompts, args.run_dir, limit=args.limit)
    print(format_checks(checks, prompts, args.run_dir))
    if not any(c.compared for c in checks):
        raise UserError(f"{args.run_dir} has no frame with stored prompts")
    return 0 if all(c.ok or (c.compared == 0) for c in checks) else 1
