"""Names from outside (models, runs, scenes, frames) are inert text in every file of a report (issue 32.7).

``index.md`` and ``tables/*.md`` are rendered with markdown-it-py (CommonMark, raw HTML on, as MkDocs' renderers
pass it through): no name may become an element, an attribute or a link; each must show as the text it is. The
frame browser's data shows control and bidirectional characters as visible escapes, and every SVG figure parses.
"""

from __future__ import annotations

import json
import os
import xml.etree.ElementTree as ET
from html.parser import HTMLParser

os.environ.setdefault("MPLBACKEND", "Agg")

import pytest

from lightemma.evaluation.synthetic import write_synthetic_run
from lightemma.report import write_report
from lightemma.runs.store import update_manifest

PAYLOAD = "<img src=x onerror=alert(1)>"
SCENE = "scene-<b onmouseover=alert(2)>&amp;\u202eevil"
RUNS = "runs-<i>x</i>"


class _Elements(HTMLParser):
    """Every start tag with its attributes, and the text, of rendered HTML."""

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.tags: list[tuple[str, dict[str, str | None]]] = []
        self.text: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))

    def handle_data(self, data):
        self.text.append(data)


def _render(markdown: str) -> _Elements:
    from markdown_it import MarkdownIt

    parser = _Elements()
    parser.feed(MarkdownIt("commonmark").enable("table").render(markdown))
    return parser


def _hostile_run(runs, model, seed, **manifest):
    run_dir = write_synthetic_run(runs, model, 30, seed=seed, noise=0.5)
    lines = (run_dir / "frames.jsonl").read_text().splitlines()
    records = [json.loads(line) for line in lines]
    for r in records:  # every frame of scene 0 gets a hostile scene name and frame id
        if r["scene_name"] == "scene-0000":
            r["scene_name"] = SCENE
            r["frame_id"] = r["frame_id"].replace("scene-0000", SCENE) + "\x1b[31m"
    (run_dir / "frames.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    update_manifest(run_dir, **manifest)
    return run_dir


@pytest.fixture(scope="module")
def hostile_report(tmp_path_factory):
    runs = tmp_path_factory.mktemp("hostile") / RUNS
    _hostile_run(runs, "openai/gpt-4o", 1, display_name=f"GPT {PAYLOAD}\x1b[31m", name="<script>alert(3)</script>")
    _hostile_run(runs, "baseline:cv", 2, display_name="[cv](javascript:alert(4)) <http://evil.example> \u202eright")
    out = tmp_path_factory.mktemp("report") / "rep"
    write_report([runs], out, top=2, frames=[f"{SCENE}/7\x1b[31m"], with_paper=False, svg=True)
    return out


def test_no_name_becomes_html_or_a_link_in_any_markdown_file(hostile_report):
    files = [hostile_report / "index.md", *sorted((hostile_report / "tables").glob("*.md"))]
    assert len(files) >= 6
    for path in files:
        source = path.read_text(encoding="utf-8")
        rendered = _render(source)
        # h4: the "#### Provenance" footer of every table file (lightemma.report.evaluation_tables.provenance_footer)
        allowed = {
            "h1",
            "h2",
            "h3",
            "h4",
            "p",
            "table",
            "thead",
            "tbody",
            "tr",
            "th",
            "td",
            "em",
            "strong",
            "ul",
            "li",
            "code",
            "blockquote",
            "img",
            "a",
        }
        assert {tag for tag, _ in rendered.tags} <= allowed, (path.name, rendered.tags)
        for tag, attrs in rendered.tags:
            assert not any(name.startswith("on") for name in attrs), (path.name, tag, attrs)
            if tag == "a":  # only the report's own links: relative files, never a script or another host
                assert not attrs["href"].startswith(("javascript:", "http")), (path.name, attrs)
            if tag == "img":
                assert attrs["src"].startswith("figures/"), (path.name, attrs)
        assert "\x1b" not in source and "\u202e" not in source, path.name
    index = _render((hostile_report / "index.md").read_text(encoding="utf-8"))
    text = "".join(index.text)
    # each name shows as the text it is (control and bidirectional characters as visible escapes)
    assert f"GPT {PAYLOAD}\\x1b[31m" in text
    assert "<script>alert(3)</script>" in text
    assert "[cv](javascript:alert(4)) <http://evil.example> \\u202eright" in text
    assert f"{RUNS}" in text
    scenarios = "".join(_render((hostile_report / "tables" / "accuracy_lightemma.md").read_text(encoding="utf-8")).text)
    assert f"GPT {PAYLOAD}" in scenarios


def test_every_svg_figure_parses(hostile_report):
    svgs = sorted((hostile_report / "figures").rglob("*.svg"))
    assert len(svgs) >= 5
    for path in svgs:
        ET.parse(path)  # an ESC in a name is no XML character: the figure would not open


def test_the_frame_browser_shows_control_and_bidi_characters_as_escapes(hostile_report):
    data = (hostile_report / "html" / "data.js").read_text(encoding="utf-8")
    payload = json.loads(data[len("LE.data(") : -len(");\n")])
    scene = SCENE.replace("\u202e", "\\u202e")
    assert scene + "/7\\x1b[31m" in payload["ids"] and scene in payload["scene"]
    assert any(m["label"].startswith(f"GPT {PAYLOAD}\\x1b[31m") for m in payload["models"])
    for path in [hostile_report / "index.html", *(hostile_report / "html").rglob("*.js")]:
        text = path.read_text(encoding="utf-8")
        assert "\x1b" not in text and "\u202e" not in text, path.name
