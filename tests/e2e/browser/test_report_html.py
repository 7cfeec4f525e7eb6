"""`index.html` in a real browser (Debian's headless Chromium through selenium and the system chromedriver).

The page is opened from file:// (no server): a table is sorted, frames are filtered, a frame view is
opened; the DOM is checked, the console must have logged no error, and a screenshot is kept in the
test's tmp folder.
"""

from __future__ import annotations

import json
import os
import shutil

os.environ.setdefault("MPLBACKEND", "Agg")

import numpy as np
import pytest

from lightemma.evaluation.synthetic import write_synthetic_run
from lightemma.report import write_report

CHROMEDRIVER = "/usr/bin/chromedriver"


def _chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture(scope="module")
def browser():
    if not (os.path.exists(CHROMEDRIVER) and _chromium()):
        pytest.fail(
            "chromium and chromium-driver are needed (apt-get install -y chromium chromium-driver; .ci/run installs them)"
        )
    os.environ["SE_AVOID_STATS"] = "true"  # Selenium Manager would phone home otherwise
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = _chromium()
    for arg in (
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-dev-shm-usage",
        "--window-size=1400,1000",
        "--allow-file-access-from-files",
    ):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    driver.set_page_load_timeout(60)
    yield driver
    driver.quit()


@pytest.fixture(scope="module")
def html_report(tmp_path_factory):
    runs = tmp_path_factory.mktemp("runs")
    write_synthetic_run(runs, "openai/gpt-4o", 90, seed=1, noise=0.3)
    write_synthetic_run(runs, "gemini/gemini-2.0-flash", 90, seed=2, noise=0.9)
    write_synthetic_run(runs, "baseline:cv", 90, seed=3, noise=1.5)
    out = tmp_path_factory.mktemp("report") / "rep"
    write_report([runs], out, top=1, common=True, case_tags=())
    return out, runs


def _tagged(runs, tag):
    """Frame ids carrying ``tag`` by lightemma.evaluation.scenarios.tag_frames (all synthetic runs share one truth)."""
    from lightemma.evaluation import load_run
    from lightemma.evaluation.scenarios import tag_frames

    run = load_run(next(p.parent for p in sorted(runs.rglob("manifest.json"))), details=True)
    mask = tag_frames(run.gt_positions, run.history_actions)[tag]
    return [fid for fid, m in zip(run.frame_ids, mask) if m]


def _wait(driver, predicate, timeout=15):
    """Until ``predicate`` holds; an element the page re-renders between the look-up and the read is looked up again."""
    from selenium.common.exceptions import StaleElementReferenceException
    from selenium.webdriver.support.ui import WebDriverWait

    return WebDriverWait(driver, timeout, ignored_exceptions=(StaleElementReferenceException,)).until(
        lambda d: predicate(d)
    )


def _errors(driver):
    return [e for e in driver.get_log("browser") if e["level"] in ("SEVERE", "ERROR")]


def test_html_report_is_self_contained(html_report):
    html_report, _ = html_report
    page = (html_report / "index.html").read_text()
    assert "http://" not in page.replace("http://www.w3.org/2000/svg", "") and "https://" not in page
    assert (html_report / "index.md").read_text().count("(index.html)") == 1
    data = (html_report / "html" / "data.js").read_text()
    assert data.startswith("LE.data(") and data.rstrip().endswith(");")
    payload = json.loads(data[len("LE.data(") : data.rindex(")")])
    assert sorted(m["label"] for m in payload["models"]) == ["GPT-4o", "Gemini-2.0-Flash", "baseline:cv"]
    assert len(payload["ids"]) == 90 and len(payload["gt"]) == 90 * 12 and len(payload["pred"]) == 3
    assert all(len(a) == 90 for a in payload["ade"])


@pytest.mark.slow
def test_html_report_in_a_browser(browser, html_report, tmp_path):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    html_report, runs = html_report
    d = browser
    d.get((html_report / "index.html").as_uri())
    _wait(d, lambda d: d.execute_script("return window.LE && window.LE.ready === true"))

    # sort the accuracy table by ADE avg, both ways: the numbers come out ordered
    table = d.find_element(By.CSS_SELECTOR, "#table-accuracy_lightemma table")
    headers = table.find_elements(By.TAG_NAME, "th")
    col = next(i for i, h in enumerate(headers) if h.text.startswith("ADE avg"))

    def column():
        cells = [r.find_elements(By.TAG_NAME, "td")[col] for r in table.find_elements(By.CSS_SELECTOR, "tbody tr")]
        return [float(c.get_attribute("data-sort")) for c in cells if c.get_attribute("data-sort") is not None]

    headers[col].click()
    up = column()
    assert len(up) >= 3 and up == sorted(up) and headers[col].get_attribute("aria-sort") == "ascending"
    headers[col].click()
    assert column() == sorted(up, reverse=True)

    # a model's name links to its frames, worst first
    link = table.find_element(By.CSS_SELECTOR, "tbody tr a.frames-link")
    model_label = link.text
    link.click()
    _wait(d, lambda d: d.find_element(By.ID, "frames-view").is_displayed())
    assert Select(d.find_element(By.ID, "f-sort")).first_selected_option.get_attribute("value") == "worst"
    cards = d.find_elements(By.CSS_SELECTOR, "#grid .card")
    assert len(cards) >= 10
    ades = [float(c.text.split("ADE ")[1].split(" m")[0]) for c in cards if "ADE " in c.text]
    assert ades == sorted(ades, reverse=True) and model_label.startswith(
        Select(d.find_element(By.ID, "f-model")).first_selected_option.text
    )

    # filter: a scenario tag and an error band; every card shown matches, the count says how many
    d.get((html_report / "index.html").as_uri() + "#frames")
    _wait(
        d,
        lambda d: (
            d.find_element(By.ID, "frames-view").is_displayed() and d.find_elements(By.CSS_SELECTOR, "#grid .card")
        ),
    )
    total = len(d.find_elements(By.CSS_SELECTOR, "#grid .card"))
    Select(d.find_element(By.ID, "f-tag")).select_by_value("braking")
    _wait(d, lambda d: d.execute_script("return LE.lastList.query") == "tag=braking")
    braking = d.execute_script("return LE.lastList.list")
    shown_ids = d.execute_script("return LE.lastList.list.map((j) => LE.frameId(j))")
    assert 0 < len(braking) < 90 and shown_ids == _tagged(runs, "braking")
    count = d.find_element(By.ID, "frame-count").text
    assert count.startswith(f"{len(braking)} of 90 frames")
    Select(d.find_element(By.ID, "f-dis")).select_by_value("1")
    _wait(d, lambda d: d.execute_script("return LE.lastList.query") == "tag=braking&dis=1")
    narrowed = d.execute_script("return LE.lastList.list")
    assert set(narrowed) <= set(braking)
    assert len(d.find_elements(By.CSS_SELECTOR, "#grid .card")) == min(len(narrowed), 60) <= total
    # an error band of one model, and a failure kind: the lists are exactly the frames data.js says
    payload = json.loads((html_report / "html" / "data.js").read_text()[len("LE.data(") : -3])
    d.get((html_report / "index.html").as_uri() + "#frames?model=0&band=0")
    _wait(
        d,
        lambda d: d.execute_script(
            "return window.LE && LE.ready && LE.lastList && LE.lastList.query === 'model=0&band=0'"
        ),
    )
    banded = d.execute_script("return LE.lastList.list")
    assert banded == [j for j, a in enumerate(payload["ade"][0]) if a is not None and a < 1.0] and banded
    failed = [j for j in range(90) if any(f[j] == payload["failures"].index("format") for f in payload["fail"])]
    d.get((html_report / "index.html").as_uri() + "#frames?fail=format")
    _wait(
        d,
        lambda d: d.execute_script(
            "return window.LE && LE.ready && LE.lastList && LE.lastList.query === 'fail=format'"
        ),
    )
    assert d.execute_script("return LE.lastList.list") == failed
    d.get((html_report / "index.html").as_uri() + "#frames?tag=braking&dis=1")
    _wait(
        d,
        lambda d: d.execute_script(
            "return window.LE && LE.ready && LE.lastList && LE.lastList.query === 'tag=braking&dis=1'"
        ),
    )
    # thumbnails are drawn as they scroll into view: the first ones hold a bird's-eye plot
    _wait(d, lambda d: d.find_elements(By.CSS_SELECTOR, "#grid .card .thumb svg polyline.gt"))

    # open a frame view: camera panel, BEV with ground truth and every scored model, metrics and stage texts
    first = d.find_element(By.CSS_SELECTOR, "#grid .card")
    fid = first.find_element(By.CSS_SELECTOR, ".id").text
    first.click()
    _wait(d, lambda d: d.find_element(By.ID, "frame-view").is_displayed())
    _wait(d, lambda d: d.find_elements(By.CSS_SELECTOR, "#texts .model-texts"))
    assert d.find_element(By.ID, "frame-title").text == fid
    assert len(d.find_elements(By.CSS_SELECTOR, "#frame-view .bev svg polyline.gt")) == 1
    assert len(d.find_elements(By.CSS_SELECTOR, "#frame-view .bev svg polyline.pred")) >= 2
    rows = d.find_elements(By.CSS_SELECTOR, "#frame-metrics tbody tr")
    assert len(rows) == 3
    texts = d.find_elements(By.CSS_SELECTOR, "#texts .model-texts")
    assert len(texts) == 3 and "the road ahead is clear" in texts[0].text and "3 · Answer" in texts[0].text
    # the stage-3 answer of the first model is the one in its record
    answer = texts[0].find_elements(By.TAG_NAME, "dd")[2].text
    assert answer.startswith("[(") and answer.endswith(")]")
    # next/previous walk the filtered list
    if len(narrowed) > 1:
        d.find_element(By.ID, "next").click()
        _wait(d, lambda d: d.find_element(By.ID, "frame-title").text != fid)

    shot = tmp_path / "frame_view.png"
    d.save_screenshot(str(shot))
    assert shot.stat().st_size > 10_000
    assert _errors(d) == []


@pytest.mark.slow
def test_html_frame_view_draws_the_camera_image_with_projected_paths(browser, tmp_path):
    """Runs on a synthetic nuScenes dataset: thumbnails are camera images, the frame view projects every path."""
    from selenium.webdriver.common.by import By

    import lightemma
    from lightemma.backends.baseline import baseline_actions
    from lightemma.evaluation.synthetic import make_record
    from lightemma.runs.store import RunWriter, create_run_dir
    from lightemma.synth import write_dataset

    root = write_dataset(tmp_path / "data", scenes=3, keyframes=15, image_size=(320, 180), sweeps=False)
    frames = lightemma.load_frames(root, "v1.0-mini", split="all")
    run_dirs = []
    for kind in ("constant", "cv"):
        run_dir = create_run_dir(
            tmp_path / "runs",
            f"baseline:{kind}",
            {"model": f"baseline:{kind}", "dataset": frames.describe(), "finished_at": "t"},
        )
        with RunWriter(run_dir) as w:
            for frame in frames:
                actions = baseline_actions(kind, frame)
                w.append(
                    make_record(
                        frame.frame_id,
                        frame.gt_positions,
                        lightemma.integrate(actions),
                        actions=actions,
                        history_actions=frame.history_actions,
                    )
                )
        run_dirs.append(run_dir)
    out = tmp_path / "report"
    write_report(run_dirs, out, top=1, convention="lightemma", case_tags=())
    images = sorted((out / "html" / "images").glob("*.jpg"))
    assert len(images) == len(frames)
    d = browser
    d.get(out.joinpath("index.html").as_uri() + "#frames")
    _wait(d, lambda d: d.find_elements(By.CSS_SELECTOR, "#grid .card .thumb img"))
    d.find_elements(By.CSS_SELECTOR, "#grid .card")[-1].click()
    _wait(d, lambda d: d.find_elements(By.CSS_SELECTOR, "#camera svg#projection polyline.gt"))
    assert d.execute_script("return document.querySelector('#camera img').naturalWidth") == 320
    assert len(d.find_elements(By.CSS_SELECTOR, "#camera svg#projection polyline.pred")) == 2
    points = d.find_element(By.CSS_SELECTOR, "#camera svg#projection polyline.gt").get_attribute("points").split()
    uv = np.array([[float(v) for v in p.split(",")] for p in points])
    assert len(uv) >= 3 and (uv[:, 0] >= -50).all() and (uv[:, 1] > 180 / 2).all()  # on the ground: below the horizon
    d.save_screenshot(str(tmp_path / "camera_view.png"))
    assert _errors(d) == []


def test_a_new_column_needs_no_html_change():
    """Tables are drawn from Table.columns: a column another part adds (e.g. a safety metric) appears, sortable."""
    from lightemma.report.html import table_html
    from lightemma.report.tables import Column, Table, fixed

    table = Table(
        "Safety",
        [Column("model", "Model"), Column("collision_pct", "Collision (%)", fixed(2))],
        [{"model": "GPT-4o", "collision_pct": 0.512}, {"model": "CV", "collision_pct": None}],
        name="safety",
    )
    page = table_html(table, {"model:GPT-4o": "#frames?model=0&sort=worst"})
    assert '<section class="table" id="table-safety">' in page and ">Collision (%)</th>" in page
    assert '<td data-sort="0.512" class="num">0.51</td>' in page and '<td class="num">-</td>' in page
    assert '<a href="#frames?model=0&amp;sort=worst" class="frames-link">GPT-4o</a>' in page


@pytest.mark.slow
def test_the_frame_browser_shows_hostile_names_as_visible_text(browser, tmp_path):
    """Issue 32.7: a right-to-left override or an ESC in a frame id, scene or model name is shown as an escape, never
    obeyed; markup in them is text. The answer's lines stay lines."""
    from selenium.webdriver.common.by import By

    runs = tmp_path / "runs"
    run_dir = write_synthetic_run(runs, "openai/gpt-4o", 30, seed=1, noise=0.3)
    records = [json.loads(line) for line in (run_dir / "frames.jsonl").read_text().splitlines()]
    for r in records:
        r["frame_id"] = r["frame_id"].replace("scene-", "sc\u202eene-<b>")
        r["scene_name"] = "scene \u202eevil\x1b[2J"
        r["attempts"][-1]["answer"] = "line one\u202e\nline two"
        r["answer"] = "line one\u202e\nline two"
    (run_dir / "frames.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    from lightemma.runs.store import update_manifest

    update_manifest(run_dir, display_name="GPT <i>x</i>\u202e")
    out = tmp_path / "rep"
    write_report([runs], out, top=0, case_tags=(), pictures=False, with_paper=False)
    d = browser
    d.get((out / "index.html").as_uri() + "#frame/0")
    _wait(d, lambda d: d.execute_script("return window.LE && window.LE.ready === true"))
    _wait(
        d,
        lambda d: (
            d.find_element(By.ID, "frame-view").is_displayed()
            and d.find_elements(By.CSS_SELECTOR, "#texts .model-texts")
        ),
    )
    title = d.find_element(By.ID, "frame-title").text
    assert title.startswith("sc\\u202eene-<b>0000/") and "\u202e" not in title
    page = d.find_element(By.ID, "frame-view").text
    assert "scene \\u202eevil\\x1b[2J" in page and "GPT <i>x</i>\\u202e" in page and "\u202e" not in page
    assert not d.find_elements(By.CSS_SELECTOR, "#frame-view b, #frame-view i:not([style])")  # markup stayed text
    answer = d.find_elements(By.CSS_SELECTOR, "#texts .model-texts dd")[2].text
    assert answer == "line one\\u202e\nline two"
    assert _errors(d) == []


@pytest.fixture(scope="module")
def safety_report(tmp_path_factory):
    """A synthetic dataset, an oracle run changed on two frames — one swerves 1.5 m right into the parked car of the
    accelerate scene (collides), one veers 8 m/step left (off road) — and an untouched constant-velocity run."""
    from lightemma.cli import main
    from lightemma.evaluation import safety as S
    from lightemma.runs.columns import SIDECAR_FILE
    from lightemma.runs.store import find_run_dirs
    from lightemma.synth import write_dataset

    base = tmp_path_factory.mktemp("safety_html")
    root = write_dataset(base / "data", scenes=2, keyframes=20, image_size=(64, 36), sweeps=False)
    for kind in ("oracle", "cv"):
        assert (
            main(
                [
                    "run",
                    "--model",
                    f"baseline:{kind}",
                    "--dataroot",
                    str(root),
                    "--version",
                    "v1.0-mini",
                    "--split",
                    "all",
                    "--out",
                    str(base / "runs" / kind),
                ]
            )
            == 0
        )
    run_dir = find_run_dirs(base / "runs" / "oracle")[0]
    data = S.load_safety_data(root, "v1.0-mini")
    records = [json.loads(line) for line in (run_dir / "frames.jsonl").read_text().splitlines()]
    swerve = np.array([[4.0 * k, -1.5] for k in range(1, 7)])
    veer = np.array([[2.0 * k, 8.0 * k] for k in range(1, 7)])
    hit = off = None
    for r in records:
        tok = S.sample_token_of(r["frame_id"])
        if hit is None and r["frame_id"].startswith("synth-0001-accelerate/"):
            fs = S.frame_safety(swerve[None], [tok], data)
            if fs.collide[0].any():
                hit, r["trajectory"] = r["frame_id"], swerve.tolist()
                continue
        if off is None and r["frame_id"].startswith("synth-0000-cruise/"):
            fs = S.frame_safety(veer[None], [tok], data)
            if fs.off_steps[0].any() and not fs.collide[0].any():
                off, r["trajectory"] = r["frame_id"], veer.tolist()
    assert hit and off
    (run_dir / "frames.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    (run_dir / SIDECAR_FILE).unlink(missing_ok=True)
    out = base / "rep"
    write_report(
        [base / "runs"], out, top=0, case_tags=(), dataroot=str(root), version="v1.0-mini", convention="lightemma"
    )
    return out, hit, off


@pytest.mark.slow
def test_safety_filter_and_per_model_flags_in_the_frame_browser(browser, safety_report, tmp_path):
    """Issue 32.12: the frame browser filters on collides / off road (any model, or the chosen one), and the frame
    view says per model whether it collides and whether it leaves the road."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    out, hit, off = safety_report
    d = browser
    d.get((out / "index.html").as_uri() + "#frames")
    _wait(d, lambda d: d.execute_script("return window.LE && LE.ready && LE.lastList") is not None)
    labels = [o.text for o in Select(d.find_element(By.ID, "f-model")).options][1:]
    oracle = next(i for i, lab in enumerate(labels) if "oracle" in lab)
    Select(d.find_element(By.ID, "f-safe")).select_by_value("collides")
    _wait(d, lambda d: d.execute_script("return LE.lastList.query") == "safe=collides")
    assert d.execute_script("return LE.lastList.list.map((j) => LE.frameId(j))") == [hit]
    Select(d.find_element(By.ID, "f-safe")).select_by_value("off_road")
    _wait(d, lambda d: d.execute_script("return LE.lastList.query") == "safe=off_road")
    assert sorted(d.execute_script("return LE.lastList.list.map((j) => LE.frameId(j))")) == sorted(
        [hit, off]
    )  # the swerve leaves the lane too
    Select(d.find_element(By.ID, "f-safe")).select_by_value("unsafe")
    _wait(d, lambda d: d.execute_script("return LE.lastList.query") == "safe=unsafe")
    assert sorted(d.execute_script("return LE.lastList.list.map((j) => LE.frameId(j))")) == sorted([hit, off])
    assert len(d.find_elements(By.CSS_SELECTOR, "#grid .card")) == 2
    # the other model has neither: filtered on it, nothing is left
    d.get((out / "index.html").as_uri() + f"#frames?model={1 - oracle}&safe=unsafe")
    _wait(
        d,
        lambda d: (
            d.execute_script("return window.LE && LE.ready && LE.lastList && LE.lastList.query")
            == f"model={1 - oracle}&safe=unsafe"
        ),
    )
    assert d.execute_script("return LE.lastList.list") == []
    # the frame view: each model's row says yes / no
    j = d.execute_script(f"return [...Array(1000).keys()].find((k) => LE.frameId(k) === {json.dumps(hit)})")
    d.get((out / "index.html").as_uri() + f"#frame/{j}")
    _wait(
        d,
        lambda d: (
            d.find_element(By.ID, "frame-view").is_displayed()
            and d.find_elements(By.CSS_SELECTOR, "#frame-metrics tbody tr")
        ),
    )
    heads = [th.text for th in d.find_elements(By.CSS_SELECTOR, "#frame-metrics thead th")]
    c, o = heads.index("Collides"), heads.index("Off-road")

    def flags(model):
        row = d.find_element(By.CSS_SELECTOR, f'#frame-metrics tbody tr[data-model="{model}"]')
        cells = row.find_elements(By.TAG_NAME, "td")
        return cells[c].text, cells[o].text

    assert flags(oracle) == ("yes", "yes") and flags(1 - oracle) == ("no", "no")
    red = d.find_element(By.CSS_SELECTOR, f'#frame-metrics tbody tr[data-model="{oracle}"] td.unsafe')
    assert red.value_of_css_property("color") == "rgba(176, 0, 0, 1)"
    d.save_screenshot(str(tmp_path / "safety_frame.png"))
    assert _errors(d) == []


@pytest.mark.slow
def test_without_safety_values_the_filter_says_why_once(browser, html_report):
    """Runs without a dataroot: the safety filter is off and says why, instead of an empty list on every choice."""
    from selenium.webdriver.common.by import By

    html_report, _ = html_report
    d = browser
    d.get((html_report / "index.html").as_uri() + "#frames")
    _wait(d, lambda d: d.execute_script("return window.LE && LE.ready === true"))
    select = d.find_element(By.ID, "f-safe")
    assert not select.is_enabled() and "pass --dataroot" in select.text


@pytest.mark.slow
def test_the_model_column_stays_in_view_when_a_wide_table_scrolls(browser, safety_report):
    """Issue 32.14: the first (model) column of a table wider than the window is frozen while the rest scrolls."""
    from selenium.webdriver.common.by import By

    out, _, _ = safety_report
    d = browser
    d.set_window_size(700, 900)
    try:
        d.get((out / "index.html").as_uri())
        _wait(d, lambda d: d.execute_script("return window.LE && LE.ready === true"))
        box = d.find_element(By.CSS_SELECTOR, "#table-accuracy_lightemma .scroll")
        assert d.execute_script(
            "return arguments[0].scrollWidth > arguments[0].clientWidth + 300", box
        )  # wide: it scrolls
        d.execute_script("arguments[0].scrollIntoView({block: 'center'})", box)
        first = box.find_element(By.CSS_SELECTOR, "tbody tr td:first-child")
        second = box.find_element(By.CSS_SELECTOR, "tbody tr td:nth-child(2)")
        left = lambda e: d.execute_script("return arguments[0].getBoundingClientRect().left", e)  # noqa: E731
        before, second_before = left(first), left(second)
        d.execute_script("arguments[0].scrollLeft = 300", box)
        _wait(d, lambda d: left(second) < second_before - 250)
        assert abs(left(first) - before) < 1.0
        # and it is on top: the point at its middle is the model cell, not a scrolled cell under it
        hit = d.execute_script(
            "const r = arguments[0].getBoundingClientRect(); const e = document.elementFromPoint(r.left + r.width / 2, r.top + r.height / 2);"
            " return arguments[0].contains(e)",
            first,
        )
        assert hit
    finally:
        d.set_window_size(1400, 1000)
