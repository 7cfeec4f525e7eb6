"""lightemma's exceptions: the Rust core's errors arrive as lightemma's classes (still ValueErrors), and the CLI prints
one line for a user error but a traceback for a bug."""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import lightemma
from lightemma import _core, errors
from lightemma.errors import InputError, NonFiniteError, ShapeError, UnknownNameError, UserError

ROOT = Path(__file__).resolve().parents[3]


@pytest.mark.parametrize(
    ("call", "cls", "words"),
    [
        (lambda: _core.integrate(np.zeros((2, 3))), ShapeError, "actions must have shape (N, T, 2)"),
        (lambda: _core.integrate(np.zeros((1, 3, 2)), 0.5, "rk4"), UnknownNameError, "unknown integration method"),
        (lambda: _core.integrate(np.zeros((1, 3, 2)), -1.0), InputError, "dt must be a positive finite number"),
        (lambda: _core.evaluate(np.full((1, 6, 2), np.nan), np.zeros((1, 6, 2))), NonFiniteError, "non-finite"),
        # the binding's own refusals go through the same mapping
        (lambda: _core.integrate(np.zeros((1, 3, 4))[..., ::2]), ShapeError, "C-contiguous"),
        (lambda: _core.parse_actions(["ok", 3]), InputError, "texts must be str: item 1 is int"),
        (lambda: _core.planning_first_bad_box(np.zeros((1, 1, 1, 8)), 5), InputError, "out of range"),
    ],
)
def test_a_rust_kernel_error_arrives_as_lightemmas_class(call, cls, words):
    with pytest.raises(cls) as caught:
        call()
    assert type(caught.value) is cls  # exactly its variant's class, not a parent
    assert words in str(caught.value)
    # still a ValueError (``except ValueError`` keeps working) and a user error (the CLI prints one line)
    assert isinstance(caught.value, ValueError) and isinstance(caught.value, UserError)


def test_the_public_api_raises_the_same_classes():
    with pytest.raises(ShapeError):
        lightemma.evaluate(np.zeros((2, 6, 2)), np.zeros((3, 6, 2)))
    with pytest.raises(UnknownNameError, match="expected one of: lightemma, stp3, uniad"):
        lightemma.evaluate(np.zeros((2, 6, 2)), np.zeros((2, 6, 2)), convention="nope")
    with pytest.raises(InputError, match="n must be a positive integer"):
        lightemma.parse_actions("[(1, 0)]", n=0)


def test_the_classes_are_exported_from_lightemma():
    for name in (
        "UserError",
        "InputError",
        "ShapeError",
        "NonFiniteError",
        "UnknownNameError",
        "DatasetError",
        "RunStoreError",
        "RunFatalError",
        "RunStopped",
    ):
        assert name in lightemma.__all__
        assert getattr(lightemma, name) is getattr(errors, name)
    for cls in (InputError, ShapeError, NonFiniteError, UnknownNameError, errors.DatasetError, errors.RunStoreError):
        assert issubclass(cls, ValueError) and issubclass(cls, UserError)


def test_no_binding_raises_a_python_class_of_its_own():
    """One mapping (rust/python/errors.rs): no binding file builds a Python exception but through it."""
    sources = [ROOT / "rust" / "python.rs", *sorted((ROOT / "rust" / "python").glob("*.rs"))]
    offenders = [
        f"{p.name}:{i}"
        for p in sources
        for i, line in enumerate(p.read_text().splitlines(), 1)
        if re.search(r"\bPy[A-Z]\w*(Error|Exception)\b", line) and p.name != "errors.rs"
    ]
    assert offenders == []


# ---- the CLI ----------------------------------------------------------------------------------------------------


def _cli_with(monkeypatch, func):
    """lightemma's main() with one subcommand, ``boom``, that runs ``func``."""
    import lightemma.cli as cli

    def build_parser() -> argparse.ArgumentParser:
        parser = cli._Parser(prog="lightemma")
        sub = parser.add_subparsers(dest="command", parser_class=cli._SubParser)
        sub.add_parser("boom").set_defaults(func=lambda args: func())
        return parser

    monkeypatch.setattr(cli, "build_parser", build_parser)
    monkeypatch.delenv("LIGHTEMMA_DEBUG", raising=False)
    return cli.main


def test_the_cli_prints_one_line_for_a_kernel_error(monkeypatch, capsys):
    main = _cli_with(monkeypatch, lambda: _core.integrate(np.zeros((2, 3))))
    assert main(["boom"]) == 2
    err = capsys.readouterr().err
    assert err == "lightemma boom: error: actions must have shape (N, T, 2), got [2, 3]\n"


def test_the_cli_prints_one_line_for_an_os_error(monkeypatch, capsys, tmp_path):
    main = _cli_with(monkeypatch, lambda: (tmp_path / "missing" / "x").read_text())
    assert main(["boom"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("lightemma boom: error: cannot read or write")


@pytest.mark.parametrize("bug", [ValueError("an internal slip"), TypeError("an internal slip")])
def test_the_cli_lets_a_bug_through(monkeypatch, capsys, bug):
    def raise_bug():
        raise bug

    main = _cli_with(monkeypatch, raise_bug)
    with pytest.raises(type(bug), match="an internal slip"):
        main(["boom"])
    assert "error:" not in capsys.readouterr().err


@pytest.mark.slow
def test_a_bug_prints_a_traceback_from_the_command(tmp_path):
    """End to end: the ``lightemma`` process shows the traceback of a plain ValueError and exits non-zero."""
    script = (
        "import argparse, sys\n"
        "import lightemma.cli as cli\n"
        "def build_parser():\n"
        "    p = cli._Parser(prog='lightemma')\n"
        "    s = p.add_subparsers(dest='command', parser_class=cli._SubParser)\n"
        "    s.add_parser('boom').set_defaults(func=lambda a: int('not a number'))\n"
        "    return p\n"
        "cli.build_parser = build_parser\n"
        "sys.exit(cli.main(['boom']))\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "LIGHTEMMA_DEBUG"}
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 1
    assert "Traceback (most recent call last)" in done.stderr
    assert "ValueError: invalid literal for int()" in done.stderr
    assert "lightemma boom: error:" not in done.stderr
