"""The ``lightemma`` command line.

Each subcommand lives in its own module under ``lightemma.cli`` and exposes
``add_parser(subparsers) -> argparse.ArgumentParser`` which registers the
subcommand and sets ``func`` (a callable taking the parsed namespace and
returning an exit code) via ``parser.set_defaults(func=...)``.

Errors meant for the user are raised as :class:`lightemma.errors.UserError` (its subclasses
``InputError``, ``ShapeError``, ``DatasetError``, … — the Rust core's errors included) or ``OSError``, and
printed as one clear line (a ``UserError``'s command-line wording when it has one), never as a traceback
(set ``LIGHTEMMA_DEBUG=1`` to see the traceback). Any other exception — a plain ``ValueError`` or
``TypeError`` included — is a bug in lightemma and prints its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import warnings
from collections.abc import Sequence

# subcommand modules, in the order `lightemma --help` lists them
SUBCOMMANDS: list[str] = ["demo", "synth", "run", "sweep", "import", "evaluate", "report", "prompts", "models"]


MODULES: dict[str, str] = {"import": "import_"}  # subcommand -> module where the name is a Python keyword


class _Parser(argparse.ArgumentParser):
    """argparse, with a usage error as one line (the flag and what was wrong) instead of the whole usage block.

    Subcommand parsers are of this class too (``add_subparsers`` makes them of the parent's class).
    """

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())} (see {self.prog} --help)\n")


class _SubParser(_Parser):
    """A subcommand's parser: it names the arguments it does not know itself (with its own --help), rather
    than leaving them to the top-level parser, which would blame ``lightemma`` (``add_subparsers`` of a
    subcommand makes its own subcommands of this class too)."""

    def parse_known_args(self, args=None, namespace=None):
        namespace, extras = super().parse_known_args(args, namespace)
        if extras:
            self.error(f"unrecognized arguments: {' '.join(extras)}")
        return namespace, extras


def build_parser() -> argparse.ArgumentParser:
    from lightemma import __version__

    parser = _Parser(
        prog="lightemma",
        description="Benchmark how well vision-language models drive (nuScenes, LightEMMA protocol).",
    )
    parser.add_argument("--version", action="version", version=f"lightemma {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_SubParser)
    for name in SUBCOMMANDS:
        importlib.import_module(f"lightemma.cli.{MODULES.get(name, name)}").add_parser(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    from lightemma._text import printable
    from lightemma.errors import UserError

    # litellm's clients leave coroutines of calls a stop cancelled unawaited; Python warns of each as it collects them,
    # three lines under the stop's one line. They are litellm's (its class names), said of calls already cancelled.
    warnings.filterwarnings(
        "ignore",
        category=RuntimeWarning,
        message=r"coroutine '(OpenAI|Anthropic|Gemini|Vertex|BaseLLM|LiteLLM|AsyncHTTPHandler)\w*\.\w+' was never awaited",
    )
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "func", None) is None:
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM / SIGHUP during a run (handled alike)
        signum = getattr(exc, "signum", 2)
        if not getattr(exc, "reported", False):  # a run says it in its own line, with the resume command
            print(f"lightemma: interrupted{' by ' + exc.name if hasattr(exc, 'name') else ''}", file=sys.stderr)
        return 128 + signum
    except UserError as exc:
        if os.environ.get("LIGHTEMMA_DEBUG"):
            raise
        message = exc.for_cli()
        print(f"lightemma {args.command}: error: {printable(' '.join(message.split()))}", file=sys.stderr)
        return 2
    except OSError as exc:  # disk full, permissions, … met where no caller gave it context
        if os.environ.get("LIGHTEMMA_DEBUG"):
            raise
        from lightemma.errors import os_error_line

        message = os_error_line(exc, "read or write") if exc.errno else str(exc)
        print(f"lightemma {args.command}: error: {printable(' '.join(message.split()))}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
