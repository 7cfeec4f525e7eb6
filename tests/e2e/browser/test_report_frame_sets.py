"""``lightemma report`` never ranks runs on different frame sets in one column: every table that lists runs is split
into one labelled group per frame set (fingerprint id and frame count shown), in ``index.md``, ``tables/`` and
``index.html`` — the last checked in a real headless browser (as tests/e2e/browser/test_report_html.py)."""

from __future__ import annotations

import contextlib
import io
import os

os.environ.setdefault("MPLBACKEND", "Agg")

import pytest

from lightemma.evaluation.stats import Resampling
from lightemma.report import write_report
from tests.e2e.browser.test_report_html import _errors, browser  # noqa: F401 - the module's headless Chromium fixture

#: the model cells of a table's run rows (not the paper's row, not the difference row beside it)
RUN_CELLS = "tbody tr:not(.paper):not(.diff) td:first-child"


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """Two runs on different frame sets (40 and 20 synthetic frames), reported together."""
    from lightemma.evaluation import load_run
    from lightemma.evaluation.core import unique_labels
    from lightemma.evaluation.synthetic import write_synthetic_run
    from lightemma.frames.fingerprint import run_fingerprint

    base = tmp_path_factory.mktemp("report_frame_sets")
    dirs = [
        write_synthetic_run(base / "runs", "openai/gpt-4o", 40, seed=1, noise=0.3),
        write_synthetic_run(base / "runs", "gemini/gemini-2.0-flash", 20, seed=2, noise=0.9),
    ]
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        write_report(
            [base / "runs"],
            base / "rep",
            top=0,
            pictures=False,
            case_tags=(),
            pairwise=False,
            resampling=Resampling(n_resamples=20),
        )
    runs = [load_run(d) for d in dirs]
    fps = {
        label: run_fingerprint(run.info.run_dir, run.info.manifest or {}, run.frame_ids)
        for label, run in zip(unique_labels(runs), runs, strict=True)
    }
    return base / "rep", fps


def test_every_run_table_is_split_by_frame_set_in_the_files(report):
    out, fps = report
    assert {fp["id"] for fp in fps.values()} and len({fp["id"] for fp in fps.values()}) == 2
    index = (out / "index.md").read_text(encoding="utf-8")
    assert "**Runs on 2 frame sets**" in index
    for label, fp in fps.items():
        part = out / "tables" / f"accuracy_lightemma_{fp['id'].replace(':', '-')}.md"
        text = part.read_text(encoding="utf-8")
        assert f"frame set {fp['id']}" in text and f"{fp['n_frames']} frames" in text
        other = next(lab for lab in fps if lab != label)
        assert f"| {label} " in text and f"| {other} " not in text  # never ranked together
        footer = text.split("#### Provenance", 1)[1]  # every table file says where its numbers come from
        assert all(f"Frame set {f['id']}" in footer for f in fps.values()) and "Metrics: " in footer
        csv = part.with_suffix(".csv").read_text(encoding="utf-8")
        assert f"# Frame set {fp['id']}" in csv
    assert not (out / "tables" / "accuracy_lightemma.md").exists()  # no table holds both
    for stem in ("efficiency", "accuracy_stp3", "accuracy_uniad"):
        assert len(list((out / "tables").glob(f"{stem}_frames-*.md"))) == 2, stem


@pytest.mark.slow
def test_the_html_page_shows_two_separated_labelled_groups(report, browser):  # noqa: F811
    from selenium.webdriver.common.by import By

    out, fps = report
    browser.get((out / "index.html").as_uri())
    block = browser.find_element(By.CSS_SELECTOR, '.frame-set-groups[data-table="accuracy_lightemma"]')
    groups = block.find_elements(By.CSS_SELECTOR, "section[data-frame-set]")
    runs = {g.get_attribute("data-frame-set"): g for g in groups if g.get_attribute("data-frame-set") != "reference"}
    assert set(runs) == {fp["id"] for fp in fps.values()}
    for label, fp in fps.items():
        group = runs[fp["id"]]
        text = group.find_element(By.CSS_SELECTOR, ".frame-set-label").text
        assert fp["id"] in text and f"{fp['n_frames']} frames" in text, text
        models = [td.text for td in group.find_elements(By.CSS_SELECTOR, RUN_CELLS)]
        assert len(models) == 1 and models[0].startswith(label), models  # one run per group: nothing ranked across sets
        assert group.is_displayed() and group.find_element(By.CSS_SELECTOR, "table.sortable")
        # --with-paper (the report's default): the paper's row of the model and the difference stay beside the run
        assert len(group.find_elements(By.CSS_SELECTOR, "tbody tr.paper")) == 1
        assert len(group.find_elements(By.CSS_SELECTOR, "tbody tr.diff")) == 1
    (one, first_fp), (other, second_fp) = fps.items()
    first, second = runs[first_fp["id"]], runs[second_fp["id"]]
    assert (
        first.rect["y"] + first.rect["height"] <= second.rect["y"]
        or second.rect["y"] + second.rect["height"] <= first.rect["y"]
    )  # separated, not overlapping
    header = first.find_element(By.CSS_SELECTOR, "thead th:nth-child(2)")
    header.click()  # sorting one group leaves the other as it was
    after = [td.text for td in second.find_elements(By.CSS_SELECTOR, RUN_CELLS)]
    assert len(after) == 1 and after[0].startswith(other), after
    runs_table = browser.find_element(By.ID, "table-runs").text
    assert all(fp["id"] in runs_table for fp in fps.values())
    assert _errors(browser) == []
    browser.save_screenshot(str(out.parent / "frame_sets.png"))


def test_one_frame_set_keeps_one_table(tmp_path):
    from lightemma.evaluation.synthetic import write_synthetic_run

    write_synthetic_run(tmp_path / "runs", "openai/gpt-4o", 20, seed=1)
    write_synthetic_run(tmp_path / "runs", "gemini/gemini-2.0-flash", 20, seed=2)
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        write_report(
            [tmp_path / "runs"],
            tmp_path / "rep",
            top=0,
            pictures=False,
            case_tags=(),
            pairwise=False,
            resampling=Resampling(n_resamples=0),
        )
    assert (tmp_path / "rep" / "tables" / "accuracy_lightemma.md").is_file()
    assert not list((tmp_path / "rep" / "tables").glob("*_frames-*"))
    assert '<div class="frame-set-groups"' not in (tmp_path / "rep" / "index.html").read_text(encoding="utf-8")


def test_disjoint_frame_sets_split_the_scenario_and_history_bias_tables(tmp_path):
    """No frame in common: the scenario table (a column per run) and the history-bias table come once per frame set."""
    from lightemma.evaluation.synthetic import write_synthetic_run

    write_synthetic_run(tmp_path / "runs", "openai/gpt-4o", 30, seed=1)
    other = write_synthetic_run(tmp_path / "runs", "gemini/gemini-2.0-flash", 24, seed=2)
    frames = other / "frames.jsonl"  # the synthetic ids in scenes of their own: no frame in common
    frames.write_text(frames.read_text(encoding="utf-8").replace('"scene-', '"other-'), encoding="utf-8")
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        write_report(
            [tmp_path / "runs"],
            tmp_path / "rep",
            top=0,
            pictures=False,
            case_tags=(),
            pairwise=False,
            resampling=Resampling(n_resamples=0),
        )
    tables = tmp_path / "rep" / "tables"
    assert not (tables / "scenarios.md").exists() and not (tables / "history_bias.md").exists()
    parts = sorted(tables.glob("scenarios_frames-*.md"))
    assert len(parts) == 2 and len(list(tables.glob("history_bias_frames-*.md"))) == 2
    lines = [p.read_text(encoding="utf-8").splitlines() for p in parts]
    headers = [next(line for line in part if line.startswith("| Tag")) for part in lines]
    assert sorted(h.count("GPT-4o") + 2 * h.count("Gemini") for h in headers) == [1, 2], headers  # one run each
