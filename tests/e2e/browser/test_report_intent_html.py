"""The explanation audit in the HTML frame browser (issue 36 item 5; python/lightemma/report/html.py ``intent_flags`` /
``intent_entries``, report.js): a loopback model whose stated intent contradicts its plan at known frames, its report
opened in headless Chromium — the filter "contradicts its plan" shows exactly those frames, each flagged, and the
frame view shows the read intent beside the stage-2 text, the contradiction highlighted."""

from __future__ import annotations

import json
import os

os.environ.setdefault("MPLBACKEND", "Agg")

import pytest

from tests.e2e.browser.test_report_html import _errors, _wait, browser  # noqa: F401  (the browser fixture)
from tests.unit.explanations.test_explanations_evaluate import LIE, _model, _records


@pytest.fixture(scope="module")
def intent_report(tmp_path_factory, synth_root):
    from lightemma.pipeline import run
    from lightemma.report import write_report
    from tests.support.fake_openai import FakeOpenAIServer

    out = tmp_path_factory.mktemp("intent-html") / "runs"
    with FakeOpenAIServer(_model(3)) as server:
        run_dir = run(
            "openai/gpt-4o",
            api_base=server.url,
            dataroot=synth_root,
            version="v1.0-mini",
            output=out,
            backoff_base=0.01,
            backoff_cap=0.05,
            timeout=10.0,
            progress=False,
        ).run_dir
    report = tmp_path_factory.mktemp("intent-html-report") / "rep"
    write_report([run_dir], report, top=1, case_tags=())
    records = _records(run_dir)
    lied = sorted(fid for fid, r in records.items() if r["intent_text"] == LIE)
    assert 0 < len(lied) < len(records)
    return report, lied, sorted(records)


def test_the_data_carries_the_contradictions(intent_report):
    report, lied, frames = intent_report
    data = (report / "html" / "data.js").read_text(encoding="utf-8")
    payload = json.loads(data[data.index("(") + 1 : data.rindex(")")])
    flagged = sorted(fid for fid, v in zip(payload["ids"], payload["contra"][0], strict=True) if v == 1)
    assert flagged == lied
    assert all(v in (0, 1) for v in payload["contra"][0])


@pytest.mark.slow
def test_the_frame_browser_filters_flags_and_highlights(browser, intent_report, tmp_path):  # noqa: F811
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    report, lied, frames = intent_report
    d = browser
    d.get((report / "index.html").as_uri() + "#frames")
    _wait(d, lambda d: d.execute_script("return window.LE && window.LE.ready === true"))
    _wait(d, lambda d: len(d.find_elements(By.CSS_SELECTOR, "#grid .card")) > 0)
    # every frame, the lied ones flagged
    cards = d.find_elements(By.CSS_SELECTOR, "#grid .card")
    shown = {
        c.find_element(By.CSS_SELECTOR, ".id").text: bool(c.find_elements(By.CSS_SELECTOR, ".intent-flag"))
        for c in cards
    }
    assert sorted(shown) == frames
    assert sorted(fid for fid, flag in shown.items() if flag) == lied
    # the filter: only the contradicting frames
    Select(d.find_element(By.ID, "f-intent")).select_by_value("contra")
    _wait(d, lambda d: "intent=contra" in d.current_url)
    _wait(d, lambda d: len(d.find_elements(By.CSS_SELECTOR, "#grid .card")) == len(lied))
    ids = sorted(c.text for c in d.find_elements(By.CSS_SELECTOR, "#grid .card .id"))
    assert ids == lied
    assert d.find_element(By.ID, "frame-count").text.startswith(f"{len(lied)} of {len(frames)}")
    # a lied frame: the read intent says stop, highlighted as a contradiction with the reason
    d.find_element(By.CSS_SELECTOR, "#grid .card").click()
    _wait(d, lambda d: d.find_elements(By.CSS_SELECTOR, "#texts .read-intent"))
    read = d.find_element(By.CSS_SELECTOR, "#texts .read-intent")
    assert "contradicts" in read.get_attribute("class").split() and read.get_attribute("data-verdict") == "contradicts"
    assert "Read intent: stop" in read.text and "says stop" in read.text
    assert read.value_of_css_property("color") in ("rgba(176, 0, 0, 1)", "rgb(176, 0, 0)")
    d.save_screenshot(str(tmp_path / "contradiction.png"))
    # an honest frame: the read intent is shown, not highlighted
    ids = [d.execute_script(f"return LE.frameId({j})") for j in range(len(frames))]
    honest = next(j for j, fid in enumerate(ids) if fid not in lied)
    d.get((report / "index.html").as_uri() + f"#frame/{honest}")
    _wait(d, lambda d: d.find_elements(By.CSS_SELECTOR, "#texts .read-intent"))
    read = d.find_element(By.CSS_SELECTOR, "#texts .read-intent")
    assert read.get_attribute("data-verdict") == "consistent"
    assert "contradicts" not in read.get_attribute("class").split()
    assert "keep speed / follow lane" in read.text
    assert not _errors(d)
