"""The README's commands are the ones CI runs, and both install from the lock file."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]


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


def test_readme_is_at_most_12_kb() -> None:
    """The README is the front page (pitch, install, demo, API, first hour, links); the rest lives in docs/."""
    size = len((ROOT / "README.md").read_bytes())
    assert size <= 12 * 1024, f"README.md is {size} bytes: move reference material into docs/ or benches/README.md"


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    text = re.sub(r"```.*?```", "", path.read_text(encoding="utf-8"), flags=re.S)
    anchors: set[str] = set()
    seen: dict[str, int] = {}
    for heading in re.findall(r"^#+\s+(.*)$", text, re.M):
        slug = _slug(heading)
        if slug in seen:
            seen[slug] += 1
            anchors.add(f"{slug}-{seen[slug]}")
        else:
            seen[slug] = 0
            anchors.add(slug)
    return anchors


# the README, every page it links to, and the pages made from it
DOC_PAGES = [
    "README.md",
    "CHANGELOG.md",
    "benches/README.md",
    *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md")),
]


@pytest.mark.parametrize("page", DOC_PAGES)
def test_every_relative_link_resolves_to_a_file_and_heading(page: str) -> None:
    path = ROOT / page
    text = re.sub(r"```.*?```", "", path.read_text(encoding="utf-8"), flags=re.S)
    links = re.findall(r"\]\(([^)\s]+)\)", text)
    assert links or page == "CHANGELOG.md", f"{page} links nowhere"
    broken = []
    for link in links:
        if re.match(r"[a-z]+:", link):  # https:, mailto:
            continue
        target, _, anchor = link.partition("#")
        resolved = (path.parent / target).resolve() if target else path
        if not resolved.exists():
            broken.append(f"{link} (no file {resolved.relative_to(ROOT) if ROOT in resolved.parents else resolved})")
        elif anchor and resolved.suffix == ".md" and anchor not in _anchors(resolved):
            broken.append(f"{link} (no heading #{anchor} in {resolved.relative_to(ROOT)})")
    assert not broken, f"{page}: " + "; ".join(broken)


def test_readme_links_every_doc_page_and_the_project_files() -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    linked = set(re.findall(r"\]\(([^)#\s]+)", text))
    pages = {f"docs/{p.name}" for p in (ROOT / "docs").glob("*.md")}
    missing = sorted(pages - linked) + [f for f in ("benches/README.md", "CHANGELOG.md", "LICENSE") if f not in linked]
    assert not missing, f"README.md does not link {missing}"
    assert (ROOT / "LICENSE").read_text(encoding="utf-8").startswith("MIT License")
    assert 'license = { text = "MIT" }' in (ROOT / "pyproject.toml").read_text(encoding="utf-8")


def test_cli_reference_names_every_subcommand() -> None:
    """docs/cli.md's command block has a line for every subcommand the parser knows."""
    import argparse

    from lightemma.cli import build_parser

    text = (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
    block = re.search(r"## Commands\n\n```bash\n(.*?)```", text, re.S)
    assert block, "no ```bash block under '## Commands' in docs/cli.md"
    documented = {line.split()[1] for line in block.group(1).splitlines() if line.startswith("lightemma ")}
    (sub,) = [a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)]
    assert documented == set(sub.choices), (sorted(documented), sorted(sub.choices))


def test_every_bench_script_has_its_figures_in_benches_readme() -> None:
    text = (ROOT / "benches" / "README.md").read_text(encoding="utf-8")
    headings = re.findall(r"^## (.*)$", text, re.M)
    for script in sorted((ROOT / "benches").glob("bench_*.py")):
        assert any(script.name in h for h in headings), f"benches/README.md has no section for {script.name}"
    # the README's figures moved here whole, with their commands
    for figure in ("**11.9×** (≥ 3×)", "**0.917**", "**6.8 s** (goal < 30 s)", "**1.41×**", "**121×** (target ≥ 20×)"):
        assert figure in text, figure
