"""The README's commands are the ones CI runs, and both install from the lock file."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _fenced_after(heading: str) -> list[str]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    start = text.index(heading)
    block = re.search(r"```bash\n(.*?)```", text[start:], re.S)
    assert block, f"no ```bash block after {heading!r} in README.md"
    return [line.strip() for line in block.group(1).splitlines() if line.strip()]


def test_readme_test_command_is_what_ci_runs() -> None:
    (command,) = _fenced_after("## Test\n")
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()
    assert command in [line.strip() for line in ci], f"README's test command {command!r} is not a line of .ci/run"
    assert "-c constraints.txt" in command


def test_readme_install_commands_use_the_lock() -> None:
    lines = [line for line in _fenced_after("## Install\n") if line.startswith("pip install")]
    for line in lines:
        if "vllm" not in line:
            assert "-c constraints.txt" in line, line
            # the main installs include the devkit (maps, rendering; the lock's numpy<2)
            assert re.search(r"\[[^]]*nuscenes", line), line
        else:
            # vLLM needs numpy 2: no devkit, no lock (whose numpy is < 2)
            assert "nuscenes" not in line and "constraints.txt" not in line, line
    test_command = _fenced_after("## Test\n")[0]
    assert "nuscenes" in test_command  # CI runs the tests against the devkit's reading


def test_lock_pins_exactly_and_excludes_known_broken_releases() -> None:
    pins = {}
    for line in (ROOT / "constraints.txt").read_text(encoding="utf-8").splitlines():
        m = re.match(r"^([A-Za-z0-9][A-Za-z0-9._-]*)==(\S+)", line)
        if m:
            pins[m.group(1).lower()] = m.group(2)
        else:
            assert not re.match(r"^[A-Za-z0-9]", line), f"constraints.txt line is not an exact pin: {line!r}"
    for name in ("torch", "transformers", "litellm", "numpy", "nuscenes-devkit"):
        assert name in pins, f"{name} is not pinned in constraints.txt"
    assert pins["transformers"] != "5.24.0"
    assert pins["litellm"] not in ("1.82.7", "1.82.8")
    major, minor, patch = (int(x) for x in pins["litellm"].split(".")[:3])
    assert (major, minor, patch) <= (1, 106, 2)
    pyproject = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    assert "!=5.24.0" in pyproject and "!=1.82.7" in pyproject and "!=1.82.8" in pyproject


def _python_block(heading: str) -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    start = text.index(heading)
    block = re.search(r"```python\n(.*?)```", text[start:], re.S)
    assert block, f"no ```python block after {heading!r} in README.md"
    return block.group(1)


def test_readme_api_example_runs_as_written_with_a_failed_answer(capsys) -> None:
    code = _python_block("## API in ten lines\n")
    assert "mask=parsed.ok" in code
    exec(compile(code, "README.md", "exec"), {"__name__": "readme"})  # noqa: S102 - the README's own example
    out = capsys.readouterr().out
    # one of the three answers fails to parse; the mask keeps it out of the metrics
    assert out.startswith("['ok' 'corrected' 'failed'] 2 1.860 m {"), out
    assert "'n_frames': 2" in out


def test_readme_first_hour_commands_parse_with_the_cli() -> None:
    import shlex

    from lightemma.cli import build_parser

    text = (ROOT / "README.md").read_text(encoding="utf-8")
    start = text.index("## The first hour\n")
    section = text[start : text.index("\n## ", start + 1)]
    blocks = re.findall(r"```bash\n(.*?)```", section, re.S)
    lines = [line.strip() for block in blocks for line in block.splitlines() if line.strip().startswith("lightemma ")]
    assert len(lines) == 9, lines
    parser = build_parser()
    for line in lines:
        argv = shlex.split(line.split("#", 1)[0])[1:]
        parser.parse_args(argv)  # argparse exits (SystemExit) on an unknown flag or a bad choice
