"""Imported runs scored as the paper scored them, and any run re-scored under another parse definition."""

import ast
import json
import math
import re

import numpy as np
import pytest

import lightemma
from lightemma.cli import main
from lightemma.errors import UserError
from lightemma.evaluation import evaluate_runs
from lightemma.evaluation.rescore import ParseDefinition
from lightemma.evaluation.synthetic import make_record
from lightemma.models.catalog import lookup
from lightemma.models.paper import paper_accuracy_rows, paper_efficiency_rows
from lightemma.models.prices import price_per_token
from lightemma.report.evaluation_tables import evaluation_tables
from lightemma.runs.importer import import_reference
from lightemma.runs.store import RunWriter, create_run_dir, read_run, update_manifest
from tests.support.reference_fixtures import euler, write_results

# ---------------------------------------------------------------- the paper's rules, restated in plain Python


def paper_read(text):
    """(FE, FE corr, actions): FE unless the answer is, as a Python literal, a list of exactly 6 tuples of 2 numbers;
    then FE corr unless 12 numbers can be read from maximal runs of digits, '-' and '.' of the form -?digits(.digits)?"""
    try:
        value = ast.literal_eval(text)
    except (ValueError, SyntaxError, TypeError, MemoryError, RecursionError):
        value = None
    if (
        isinstance(value, list)
        and len(value) == 6
        and all(isinstance(p, tuple) and len(p) == 2 and all(type(x) in (int, float) for x in p) for p in value)
    ):
        return False, False, [[float(v), float(c)] for v, c in value]
    numbers = [float(run) for run in re.findall(r"[0-9.\-]+", text) if re.fullmatch(r"-?\d+(\.\d+)?", run)]
    if len(numbers) < 12:
        return True, True, None
    return True, False, [numbers[i : i + 2] for i in range(0, 12, 2)]


def usable(frame):
    """The frames a correct import keeps: 6 ground-truth points, 6 history pairs, all finite."""
    ego = frame.get("ego_info", {})
    pairs = lambda value, n: (  # noqa: E731
        isinstance(value, list)
        and len(value) == n
        and all(len(p) == 2 and all(isinstance(x, (int, float)) and math.isfinite(x) for x in p) for p in value)
    )
    return pairs(ego.get("gt_positions"), 6) and pairs(ego.get("obs_actions"), 6)


def implausible(actions):
    """Outside lightemma's default plausibility limits: a speed outside [-10, 50] m/s or |curvature| > 1 /m."""
    return any(not -10.0 <= v <= 50.0 or abs(c) > 1.0 for v, c in actions)


def paper_tables(folder, prices=None, *, gate=False):
    """Table I and II values of one model folder, the way the paper computes them (lightemma convention).

    ``gate=True``: as lightemma evaluates by default, implausible actions are counted, not averaged
    (time and tokens still over every frame the paper's rules could read)."""
    fe = fe_corr = received = n_implausible = n_read = 0
    errors, seconds, inputs, outputs, costs = [], [], [], [], []
    for path in sorted((folder / "output").glob("*.json")):
        try:
            scene = json.loads(path.read_text())
        except json.JSONDecodeError:
            continue
        for frame in scene["frames"]:
            if not usable(frame):
                continue
            received += 1
            is_fe, is_fe_corr, actions = paper_read(frame["inference"]["pred_actions_str"])
            fe += is_fe
            fe_corr += is_fe_corr
            if actions is None:
                continue
            n_read += 1
            if "time_usage" in frame:
                seconds.append(sum(frame["time_usage"].values()))
                inputs.append(sum(u["input"] for u in frame["token_usage"].values()))
                outputs.append(sum(u["output"] for u in frame["token_usage"].values()))
                if prices:
                    costs.append(
                        100
                        * sum(u["input"] * prices[0] + u["output"] * prices[1] for u in frame["token_usage"].values())
                    )
            if gate and implausible(actions):
                n_implausible += 1
                continue
            pred, gt = euler(actions), frame["ego_info"]["gt_positions"]
            errors.append([math.hypot(p[0] - g[0], p[1] - g[1]) for p, g in zip(pred, gt)])
    e = np.array(errors)
    mean = lambda xs: sum(xs) / len(xs) if xs else None  # noqa: E731
    return {
        "frames": len(errors),
        "implausible": n_implausible,
        "fe_pct": 100 * fe / received,
        "fe_corr_pct": 100 * fe_corr / received,
        "ade_1s": e[:, 0:2].mean(),
        "ade_2s": e[:, 2:4].mean(),
        "ade_3s": e[:, 4:6].mean(),
        "ade_avg": e.mean(),
        "fde": e[:, 5].mean(),
        "miss_rate": (e.max(axis=1) > 2.0).mean(),
    }, {
        "seconds_per_frame": mean(seconds),
        "input_tokens": mean(inputs),
        "output_tokens": mean(outputs),
        "cost_cents_per_frame": mean(costs),
        "frames": n_read,
    }  # means over readable frames whose counts are known


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    root = tmp_path_factory.mktemp("imported")
    results = write_results(root / "results")
    runs = {r.model: r.run_dir for r in import_reference([root / "results"], root / "runs")}
    return results, runs


@pytest.mark.parametrize("model", ["gpt-4o", "claude-3.7-sonnet", "qwen-2.5-vl-7b", "my-finetune"])
def test_import_then_evaluate_gives_exactly_the_papers_rules(imported, model):
    results, runs = imported
    info = lookup(model)
    prices = price_per_token(info) if info is not None and info.backend == "api" else None
    # exactly the paper's rules: every answer they read is averaged, implausible or not
    accuracy, efficiency = paper_tables(results["models"][model], prices)
    ev = evaluate_runs([runs[model]], keep_implausible=True)
    (row,) = ev.accuracy_rows("lightemma")
    assert row["parse"] == "paper" and row["frames"] == accuracy["frames"] and row["implausible"] == 0
    for key, expected in accuracy.items():
        assert row[key] == pytest.approx(expected, rel=1e-12, abs=1e-12), key
    (eff,) = ev.efficiency_rows()
    for key, expected in efficiency.items():
        assert eff[key] == (None if expected is None else pytest.approx(expected, rel=1e-12)), key
    # by default the paper's FE columns stand, but implausible actions are counted and never averaged
    gated, gated_efficiency = paper_tables(results["models"][model], prices, gate=True)
    ev = evaluate_runs([runs[model]])
    (row,) = ev.accuracy_rows("lightemma")
    assert row["frames"] == gated["frames"] and row["implausible"] == gated["implausible"]
    for key, expected in gated.items():
        assert row[key] == pytest.approx(expected, rel=1e-12, abs=1e-12), key
    (eff,) = ev.efficiency_rows()
    assert eff["seconds_per_frame"] == pytest.approx(gated_efficiency["seconds_per_frame"], rel=1e-12)


def test_the_fixtures_exercise_every_rule(imported):
    """FE without FE corr (list of lists, prose, lost decimals, a '-0' ending), FE corr, and plain answers all occur."""
    results, runs = imported
    statuses = {}
    for run_dir in runs.values():
        for rec in read_run(run_dir).records.values():
            statuses.setdefault(rec["status"], []).append(rec["answer"])
    assert {"ok", "corrected", "failed"} == set(statuses)
    assert any(a.startswith("[[") for a in statuses["corrected"]) and any(
        a.startswith("Sure") for a in statuses["corrected"]
    )
    assert any("5254" in a for a in statuses["corrected"])  # the paper's rule reads lost decimals as 5254 m/s
    assert any(a.startswith("I am unable") for a in statuses["failed"]) and any(
        a.count("(") == 5 for a in statuses["failed"]
    )


def test_parse_rescores_stored_answers_and_says_so(imported, capsys):
    results, runs = imported
    run_dir = runs["qwen-2.5-vl-7b"]
    records = list(read_run(run_dir).records.values())
    answers = [r["answer"] for r in records]
    for mode in ("lenient", "strict"):
        ev = evaluate_runs([run_dir], parse=ParseDefinition(mode))
        (row,) = ev.accuracy_rows()
        parsed = lightemma.parse_actions(answers, mode=mode)
        ok = parsed.status != "failed"
        assert row["parse"] == mode and row["frames"] == int(ok.sum())
        assert row["fe_pct"] == pytest.approx(100 * (parsed.status != "ok").mean())
        assert row["fe_corr_pct"] == pytest.approx(100 * (~ok).mean())
        gt = np.array([r["gt_positions"] for r in records])[ok]
        expected = lightemma.evaluate(lightemma.integrate(parsed.actions[ok]), gt)
        assert row["ade_avg"] == pytest.approx(expected.ade_avg) and row["fde"] == pytest.approx(expected.fde)
    assert main(["evaluate", str(run_dir), "--parse", "strict", "--format", "json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["parse"] == {"mode": "strict", "speed_range": [-10.0, 50.0], "max_abs_curvature": 1.0}
    assert doc["tables"][1]["rows"][0]["parse"] == "strict"
    assert main(["evaluate", str(run_dir)]) == 0 and "| paper |" in capsys.readouterr().out  # an imported run's own


def test_plausibility_limits_reach_the_parser(imported):
    results, runs = imported
    run_dir = runs["qwen-2.5-vl-7b"]
    tight = evaluate_runs([run_dir], parse=ParseDefinition("lenient", speed_range=(0.0, 3.0)))
    loose = evaluate_runs([run_dir], parse=ParseDefinition("lenient"))
    assert tight.accuracy_rows()[0]["frames"] < loose.accuracy_rows()[0]["frames"]
    assert tight.accuracy_rows()[0]["parse"] == "lenient v∈[0, 3]"


def test_rescoring_takes_the_first_attempt_that_passes_and_integrates_with_the_runs_integrator(tmp_path):
    good = "[(4.0, 0.01), (4.2, 0.01), (4.4, 0.0), (4.6, 0.0), (4.8, 0.0), (5.0, 0.0)]"
    prose = "Answer: [(9.0, 0.1), (9.0, 0.1), (9.0, 0.1), (9.0, 0.1), (9.0, 0.1), (9.0, 0.1)]"
    gt = lightemma.integrate(np.array([[4.0, 0.0]] * 6))
    run_dir = create_run_dir(
        tmp_path, "openai/test", {"model": "openai/test", "params": {"integrate_method": "midpoint"}}
    )
    with RunWriter(run_dir) as writer:
        rec = make_record("s/1", gt, None, status="corrected", first_status="corrected")
        rec["attempts"] = [
            {"answer": prose, "status": "corrected", "reason": ""},
            {"answer": None, "status": "failed", "error": "Timeout"},
            {"answer": good, "status": "ok", "reason": ""},
        ]
        writer.append(rec)
    update_manifest(run_dir, finished_at="t")
    lenient = evaluate_runs([run_dir], parse=ParseDefinition("lenient"))
    strict = evaluate_runs([run_dir], parse=ParseDefinition("strict"))
    (row_l,), (row_s,) = lenient.accuracy_rows(), strict.accuracy_rows()
    assert (
        row_l["fe_pct"] == 100.0 and row_s["fe_pct"] == 100.0 and row_s["fe_corr_pct"] == 100.0
    )  # first received answer
    assert row_s["frames"] == row_l["frames"] == 1
    from lightemma.evaluation import load_run

    strict_run = load_run(run_dir, parse=ParseDefinition("strict"))
    expected = lightemma.integrate(np.array(ast.literal_eval(good), dtype=float), method="midpoint")
    assert np.allclose(strict_run.trajectory[0], expected) and strict_run.rescored
    lenient_run = load_run(run_dir, parse=ParseDefinition("lenient"))
    assert np.allclose(lenient_run.trajectory[0], lightemma.integrate(np.array([[9.0, 0.1]] * 6), method="midpoint"))
    assert not load_run(run_dir).rescored  # by default the recorded statuses stand


def test_bad_parse_options_are_one_line_errors(imported, capsys):
    results, runs = imported
    assert main(["evaluate", str(runs["gpt-4o"]), "--parse", "paper", "--max-curvature", "0.5"]) == 2
    assert "no plausibility limits" in capsys.readouterr().err
    assert main(["evaluate", str(runs["gpt-4o"]), "--speed-range", "0", "30"]) == 2
    assert "need --parse lenient, strict or json" in capsys.readouterr().err
    with pytest.raises(UserError, match="LO < HI"):
        ParseDefinition("strict", speed_range=(5.0, 1.0))


def test_with_paper_puts_each_run_beside_its_papers_row(imported):
    results, runs = imported
    ev = evaluate_runs([runs["gpt-4o"], runs["my-finetune"]])
    accuracy = evaluation_tables(ev, with_paper=True)[1].rows
    mine, paper, diff = accuracy[0], accuracy[1], accuracy[2]
    assert (mine["model"], paper["model"], paper["source"], diff["source"]) == ("GPT-4o", "GPT-4o", "paper", "diff")
    reference = next(r for r in paper_accuracy_rows() if r["model"] == "GPT-4o")
    for key in ("fe_pct", "fe_corr_pct", "ade_1s", "ade_2s", "ade_3s", "ade_avg", "fde"):
        assert diff[key] == pytest.approx(mine[key] - reference[key])
    assert (
        accuracy[3]["model"] == "my-finetune" and accuracy[4]["source"] == "paper" and accuracy[4]["model"] != "GPT-4o"
    )
    assert len(accuracy) == 3 + 1 + 14 and "note" not in mine
    efficiency = evaluation_tables(ev, with_paper=True)[0].rows
    ref = next(r for r in paper_efficiency_rows() if r["model"] == "GPT-4o")
    assert efficiency[2]["seconds_per_frame"] == pytest.approx(
        efficiency[0]["seconds_per_frame"] - ref["seconds_per_frame"]
    )


def test_with_paper_labels_runs_on_synthetic_data(tmp_path, capsys):
    root = tmp_path
    write_results(root / "results")
    import_reference([root / "results" / "gpt-4o"], root / "runs", dataset_kind="synthetic")
    assert main(["evaluate", str(root / "runs"), "--with-paper"]) == 0
    out = capsys.readouterr().out
    assert "| GPT-4o (synthetic data) |" in out and "| GPT-4o (paper) |" in out and "| Δ vs paper |" in out


def test_reports_and_pictures_work_on_imported_runs(imported, tmp_path):
    from PIL import Image

    from lightemma.evaluation import load_run
    from lightemma.report import write_report
    from lightemma.report.pictures import CameraSource

    results, runs = imported
    run = load_run(runs["gpt-4o"])
    fid = run.frame_ids[0]
    record = read_run(runs["gpt-4o"]).records[fid]
    image = tmp_path / "nuscenes" / "samples" / "CAM_FRONT" / record["image_name"]
    image.parent.mkdir(parents=True)
    Image.new("RGB", (64, 36), (10, 20, 30)).save(image)
    source = CameraSource(str(tmp_path / "nuscenes"))
    camera = source.cameras([run], [fid])[fid]
    assert camera.image is not None and camera.image.shape == (36, 64, 3)
    assert np.allclose(camera.intrinsic, record["camera_params"]["camera_intrinsic"])
    assert np.allclose(camera.extrinsic[:3, 3], record["camera_params"]["translation"])
    index = write_report(
        [runs["gpt-4o"], runs["claude-3.7-sonnet"]],
        tmp_path / "report",
        frames=[fid],
        top=1,
        dataroot=str(tmp_path / "nuscenes"),
    )
    text = index.read_text()
    assert "GPT-4o (paper)" in text and "| Δ vs paper |" in text
    assert list((tmp_path / "report" / "figures" / "frames").glob("frame_*_grid.png"))
