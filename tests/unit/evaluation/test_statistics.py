"""Evaluation that holds on real runs: rejected frames never reach a mean, robust history bias,
per-convention averages, scene-bootstrap intervals (coverage), paired comparisons against a
NumPy restatement, Holm's adjustment. Fixtures: lightemma.evaluation.study (near-stationary
frames, a garbage model, known scene-level variance)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from lightemma.cli import main
from lightemma.evaluation import evaluate_runs, load_run
from lightemma.evaluation.stats import Resampling, bootstrap_ci, cluster_sums, holm, sign_flip_p
from lightemma.evaluation.study import StudyModel, study_scenes, write_study
from lightemma.evaluation.synthetic import make_record
from lightemma.report.evaluation_tables import evaluation_tables
from lightemma.report.tables import render
from lightemma.runs.store import FRAMES_FILE, RunWriter, create_run_dir

GARBAGE = "meta-llama/Llama-3.2-11B-Vision-Instruct"
MODELS = [
    StudyModel("gpt-4o", speed_error=0.7, fe_rate=0.05, fail_rate=0.02),
    StudyModel("gpt-5", speed_error=0.75),
    StudyModel("gemini/gemini-2.5-flash", speed_error=1.1, api_error_rate=0.05),
    StudyModel(GARBAGE, speed_error=1.0, garbage_rate=0.6),
]
FAST = Resampling(n_resamples=2000, seed=3)


@pytest.fixture(scope="module")
def scenes():
    return study_scenes(40, 12, seed=5)


@pytest.fixture(scope="module", params=["marked", "unmarked"])
def study(request, tmp_path_factory, scenes):
    """The same study written by a current run (failure field, garbage marked implausible) or an older one (neither)."""
    out = tmp_path_factory.mktemp(request.param)
    dirs = write_study(out, MODELS, scenes=scenes, seed=5, record_failure=request.param == "marked")
    return out, dict(zip([m.model for m in MODELS], dirs))


def records(run_dir):
    return [json.loads(line) for line in (run_dir / FRAMES_FILE).read_text().splitlines()]


def garbage_ids(run_dir):
    return {r["frame_id"] for r in records(run_dir) if r["answer"] == "garbage"}


def numpy_scored(run_dir, convention="lightemma"):
    """ADE avg / FDE per scored frame straight from frames.jsonl: ok or corrected, and no speed above 50 m/s."""
    out = {}
    for r in records(run_dir):
        if r["status"] == "failed" or r.get("failure") or r["trajectory"] is None or r["answer"] == "garbage":
            continue
        e = np.linalg.norm(np.array(r["trajectory"]) - np.array(r["gt_positions"]), axis=1)
        cols = {
            "lightemma": [e[0:2], e[2:4], e[4:6]],
            "stp3": [e[0:2], e[0:4], e[0:6]],
            "uniad": [e[1:2], e[3:4], e[5:6]],
        }[convention]
        avg = e.mean() if convention == "lightemma" else np.mean([c.mean() for c in cols])
        out[r["frame_id"]] = (avg, e[5], r["scene_name"])
    return out


def test_the_fixture_is_as_messy_as_real_runs(study, scenes):
    out, dirs = study
    recs = records(dirs[GARBAGE])
    garbage = [r for r in recs if r["answer"] == "garbage"]
    assert 0.5 < len(garbage) / len(recs) < 0.7
    err = np.linalg.norm(np.array(garbage[0]["actions"])[:, 0]) if garbage[0]["actions"] else 0
    assert err > 1e11  # ADE ≈ 1e12 m
    # near-stationary frames: ground-truth curvature of tens to hundreds of 1/m
    from lightemma.evaluation.scenarios import _with_origin, menger_curvature, path_length

    still = path_length(scenes.gt_positions) < 0.3
    assert still.sum() > 20
    assert np.abs(menger_curvature(_with_origin(scenes.gt_positions[still]))).max() > 50


def test_no_mean_includes_a_rejected_frame(study):
    out, dirs = study
    ev = evaluate_runs([out], convention="all", resampling=FAST, pairwise=True)
    rows = {r["model"]: r for r in ev.accuracy_rows("lightemma")}
    for model, run_dir in dirs.items():
        label = next(m.label for m in ev.models if m.run_dir == run_dir)
        row, ref = rows[label], numpy_scored(run_dir)
        assert row["frames"] == row["scored"] == len(ref), model
        assert row["ade_avg"] == pytest.approx(np.mean([v[0] for v in ref.values()]), rel=1e-12), model
        assert row["fde"] == pytest.approx(np.mean([v[1] for v in ref.values()]), rel=1e-12), model
        assert row["scored"] + row["failed"] + row["implausible"] + row["api_errors"] == row["frames_in_run"]
        for key in ("ade_avg_ci95", "fde_ci95"):
            low, high = row[key]
            assert low < row[key[:-5]] < high < 10.0, (model, key)
    garbage = rows["LLaMA-3.2-11B"]
    assert garbage["implausible"] == len(garbage_ids(dirs[GARBAGE])) and garbage["ade_avg"] < 5.0
    assert garbage["low_coverage"] and garbage["scored_pct"] < 50
    lost = sum(r["failure"] == "api_error" for r in records(dirs["gemini/gemini-2.5-flash"]) if "failure" in r)
    if out.name.startswith("marked"):
        assert rows["Gemini-2.5-Flash"]["api_errors"] == lost > 0
    else:  # an older run cannot tell API errors from format failures: all count as failed
        assert rows["Gemini-2.5-Flash"]["api_errors"] == 0 and rows["Gemini-2.5-Flash"]["failed"] > 0
    assert rows["GPT-4o"]["failed"] > 0
    for convention in ("stp3", "uniad"):
        assert all(r["ade_avg"] < 5.0 for r in ev.accuracy_rows(convention))
    assert all(abs(r["ade_avg_diff"]) < 5.0 for r in ev.pairwise)
    garbage_warned = any("without being marked" in w for w in ev.warnings)
    assert garbage_warned == (out.name.startswith("unmarked"))


def test_the_low_coverage_flag_is_in_every_table(study):
    out, dirs = study
    ev = evaluate_runs([out], resampling=FAST, pairwise=True)
    tables = evaluation_tables(ev)
    assert [t.name for t in tables] == [
        "efficiency",
        "accuracy_lightemma",
        "pairwise_ade",
        "generations",
        "explanations",
    ]
    text = render(tables, "md")
    for block in text.split("### ")[1:]:
        if "LLaMA" in block:
            assert re.search(r"LLaMA-3\.2-11B \(only \d+ % scored\)", block), block[:80]
    assert "LLaMA-3.2-11B (only" not in json.dumps(json.loads(render(tables, "json"))["tables"][1]["rows"][0])


def test_figures_and_frame_picker_use_scored_frames_only(study, tmp_path):
    from lightemma.evaluation.scenarios import disagreements, per_tag_metrics, worst_frame_per_tag
    from lightemma.report import write_report
    from lightemma.report.figures import bubble_points

    out, dirs = study
    runs = [load_run(d, details=True) for d in dirs.values()]
    bad = garbage_ids(dirs[GARBAGE])
    picks = [d["frame_id"] for d in disagreements(runs, top=10)] + [c["frame_id"] for c in worst_frame_per_tag(runs)]
    assert picks and not set(picks) & bad
    assert all(d["spread_m"] < 100 for d in disagreements(runs, top=10))
    for row in per_tag_metrics(runs):
        for run in runs:
            cell = row[run.info.label] if run.info.label in row else None
            assert cell is None or cell["ade_avg"] < 20, row["tag"]
    points = bubble_points(evaluate_runs([out], resampling=FAST))
    assert max(p["ade_avg"] for p in points) < 5
    if out.name.startswith("marked"):
        return  # the report (slow: matplotlib) once, on the runs that do not mark their garbage
    index = write_report(
        [out], tmp_path / "rep", top=2, case_tags=("braking",), resampling=Resampling(n_resamples=200), with_paper=False
    )
    text = index.read_text()
    drawn = set(re.findall(r"— frame `([^`]+)`", text))
    assert drawn and not drawn & bad
    assert "LLaMA-3.2-11B (only" in text and "## Paired comparisons" in text


def test_a_failed_record_without_failure_field_counts_as_format(tmp_path):
    run_dir = create_run_dir(tmp_path, "m", {"model": "m", "finished_at": "t"})
    gt = np.zeros((6, 2))
    with RunWriter(run_dir) as w:
        w.append(make_record("a/1", gt, gt + 0.5))
        w.append(make_record("a/2", gt, None, status="failed"))  # older run: no failure field
        failed = make_record("a/3", gt, None, status="failed")
        failed["failure"] = "api_error"
        w.append(failed)
        truncated = make_record("a/4", gt, None, status="failed")
        truncated["failure"] = "truncated"
        w.append(truncated)
        marked = make_record("a/5", gt, gt + 1.0)
        marked["failure"] = "implausible"  # marked: never scored, whatever it holds
        w.append(marked)
        wild = make_record("a/6", gt, gt + 1.0, actions=[[8.0, 3.0]] * 6)  # |curvature| 3 1/m, unmarked
        w.append(wild)
    row = evaluate_runs([run_dir], resampling=FAST).accuracy_rows()[0]
    assert (row["scored"], row["failed"], row["implausible"], row["api_errors"]) == (1, 2, 2, 1)
    assert row["ade_avg"] == pytest.approx(np.sqrt(0.5))
    assert row["ade_avg_ci95"] is None  # one scene: no interval


def test_plausibility_limits_come_from_the_runs_parse_definition(tmp_path):
    parse = {"mode": "lenient", "speed_range": [-10.0, 100.0], "max_abs_curvature": 1.0}
    run_dir = create_run_dir(tmp_path, "m", {"model": "m", "finished_at": "t", "params": {"parse": parse}})
    gt = np.zeros((6, 2))
    with RunWriter(run_dir) as w:
        w.append(
            make_record("a/1", gt, gt, actions=[[80.0, 0.0]] * 6)
        )  # too fast for the default 50 m/s, not for this run
    assert evaluate_runs([run_dir], resampling=FAST).accuracy_rows()[0]["scored"] == 1


def test_robust_slope_is_positive_where_turns_continue(scenes):
    """The fixture's turns continue; near-stationary frames would drag least squares anywhere."""
    from lightemma.evaluation.scenarios import mean_curvature, path_length, robust_slope

    moving = scenes.history_actions[:, -1, 0] >= 1.0
    x, y = scenes.history_actions[moving, -1, 1], mean_curvature(scenes.gt_positions[moving])
    long = path_length(scenes.gt_positions[moving]) >= 2.0
    fit = robust_slope(x[long], y[long])
    assert fit["slope"] > 0 and fit["ci95"][0] > 0
    turning = long & (np.abs(x) >= 0.03)
    assert np.mean(np.sign(y[turning]) == np.sign(x[turning])) > 0.6  # most turns go on (some end within the 3 s)


def test_history_bias_ignores_near_stop_frames_and_reports_sign_agreement(tmp_path):
    import lightemma
    from lightemma.evaluation.scenarios import history_bias

    rng = np.random.default_rng(0)
    run_dir = create_run_dir(tmp_path, "m", {"model": "m", "finished_at": "t"})
    xs, ys = [], []
    with RunWriter(run_dir) as w:
        for i, k in enumerate(rng.uniform(-0.1, 0.1, 60)):  # turns that go on: future curvature = history curvature
            gt = lightemma.integrate(np.array([[6.0, k]] * 6), method="midpoint")
            w.append(make_record(f"s/{i}", gt, gt, history_actions=[[6.0, k]] * 6))
            xs.append(k), ys.append(k)
        for i, k in enumerate(
            rng.uniform(0.02, 0.1, 12)
        ):  # halting: 1 cm of jitter gives a curvature of ±90 against the turn
            gt = np.array([[0.3, 0.0], [0.45, 0.0], [0.5, 0.0], [0.5, -0.01], [0.51, -0.01], [0.5, -0.02]])
            w.append(make_record(f"h/{i}", gt, gt, history_actions=[[1.5, k]] * 6))
            xs.append(k), ys.append(-90.0)
    assert np.polyfit(xs, ys, 1)[0] < 0  # least squares on every moving frame: turns seem to reverse
    (row,) = history_bias([load_run(run_dir, details=True)])
    assert row["short_path_frames"] == 12 and row["frames"] == 60
    assert row["slope_true"] == pytest.approx(1.0, abs=0.02) and row["slope_true_ci95"][0] > 0.9
    assert row["sign_agree_true"] == 1.0 and row["turn_frames"] == int(np.sum(np.abs(xs[:60]) >= 0.03))


@pytest.mark.parametrize("convention", ["stp3", "uniad"])
def test_stp3_and_uniad_avg_is_the_mean_of_their_columns(study, convention):
    out, dirs = study
    ev = evaluate_runs([dirs["gpt-4o"]], convention=convention, resampling=Resampling(n_resamples=0))
    row = ev.accuracy_rows(convention)[0]
    assert row["ade_avg"] == pytest.approx((row["ade_1s"] + row["ade_2s"] + row["ade_3s"]) / 3, rel=1e-12)
    ref = numpy_scored(dirs["gpt-4o"], convention)
    assert row["ade_avg"] == pytest.approx(np.mean([v[0] for v in ref.values()]), rel=1e-12)
    lightemma_avg = evaluate_runs([dirs["gpt-4o"]], resampling=Resampling(n_resamples=0)).accuracy_rows()[0]["ade_avg"]
    assert row["ade_avg"] != pytest.approx(lightemma_avg, rel=1e-3)  # not mean(e1..e6)


def simulate(rng, scenes=30, mu=1.0, tau=0.5, sigma=1.0):
    """Per-frame values with a scene effect: mu + u_s + e_i, u_s ~ N(0, tau²), e ~ N(0, sigma²), 5–30 frames a scene."""
    sizes = rng.integers(5, 31, scenes)
    labels = np.repeat(np.arange(scenes), sizes)
    values = mu + rng.normal(0, tau, scenes)[labels] + rng.normal(0, sigma, len(labels))
    return values, labels


def test_scene_bootstrap_covers_the_truth_at_about_the_nominal_rate():
    """Property: over 300 fixtures with known scene-level variance, the 95 % interval covers the mean 0.88–0.99 of
    the time; resampling frames instead of scenes (the error the cluster bootstrap avoids) covers far less."""
    rng = np.random.default_rng(2024)
    groups = [simulate(rng) for _ in range(300)]
    keys = [f"fixture {i}" for i in range(len(groups))]
    ci = bootstrap_ci(groups, keys, Resampling(n_resamples=2000, seed=11))[:, 0]
    coverage = np.mean((ci[:, 0] <= 1.0) & (1.0 <= ci[:, 1]))
    assert 0.88 <= coverage <= 0.99, coverage
    naive = bootstrap_ci([(v, np.arange(len(v))) for v, _ in groups], keys, Resampling(n_resamples=2000, seed=11))[:, 0]
    assert np.mean((naive[:, 0] <= 1.0) & (1.0 <= naive[:, 1])) < 0.8


def numpy_cluster_bootstrap(values, labels, n, rng):
    sums, counts = cluster_sums(values, labels)
    idx = rng.integers(0, len(counts), (n, len(counts)))
    means = sums[idx, 0].sum(1) / counts[idx].sum(1)
    return np.quantile(means, [0.025, 0.975])


def numpy_sign_flip(values, labels, n, rng):
    sums, _ = cluster_sums(values, labels)
    d = sums[:, 0]
    flips = rng.choice([-1.0, 1.0], (n, len(d)))
    return (1 + np.sum(np.abs(flips @ d) >= abs(d.sum()) - 1e-12)) / (1 + n)


def test_bootstrap_agrees_with_a_numpy_restatement_and_is_deterministic():
    rng = np.random.default_rng(7)
    values, labels = simulate(rng, scenes=60)
    ours = bootstrap_ci([(values, labels)], ["m"], Resampling(n_resamples=20_000, seed=1))[0, 0]
    ref = numpy_cluster_bootstrap(values, labels, 20_000, np.random.default_rng(1))
    assert ours == pytest.approx(ref, abs=0.02 * (ref[1] - ref[0]) + 0.005)
    again = bootstrap_ci([(values, labels), simulate(rng)], ["m", "other"], Resampling(n_resamples=20_000, seed=1))[
        0, 0
    ]
    np.testing.assert_array_equal(ours, again)  # a row's interval does not depend on the other rows
    other_seed = bootstrap_ci([(values, labels)], ["m"], Resampling(n_resamples=20_000, seed=2))[0, 0]
    assert not np.array_equal(ours, other_seed)


def test_pairwise_against_a_numpy_restatement(study):
    out, dirs = study
    resampling = Resampling(n_resamples=20_000, seed=4)
    ev = evaluate_runs([out], resampling=resampling, pairwise=True)
    labels = {m.run_dir: m.label for m in ev.models}
    rows = {(r["model_a"], r["model_b"]): r for r in ev.pairwise}
    assert len(rows) == 6
    refs = {labels[d]: numpy_scored(d) for d in dirs.values()}
    p_values = []
    for (a, b), row in rows.items():
        common = sorted(set(refs[a]) & set(refs[b]))
        diff = np.array([refs[a][f][0] - refs[b][f][0] for f in common])
        scenes = np.array([refs[a][f][2] for f in common])
        assert row["frames"] == len(common) and row["scenes"] == len(set(scenes))
        assert row["ade_avg_diff"] == pytest.approx(diff.mean(), rel=1e-9, abs=1e-12)
        low, high = numpy_cluster_bootstrap(diff, scenes, 20_000, np.random.default_rng(9))
        width = high - low
        assert row["ci95"] == pytest.approx([low, high], abs=0.03 * width + 1e-3), (a, b)
        assert np.sign(row["ade_avg_diff"]) == np.sign(diff.mean())
        p = numpy_sign_flip(diff, scenes, 20_000, np.random.default_rng(9))
        assert row["p_value"] == pytest.approx(p, abs=max(0.01, 0.15 * p)), (a, b)
        p_values.append(row["p_value"])
    np.testing.assert_allclose([r["p_holm"] for r in rows.values()], holm(p_values))
    assert all(r["significant"] == (r["p_holm"] <= 0.05) for r in rows.values())
    # GPT-4o is clearly better than the noisier Gemini-2.5-Flash on this fixture
    best = rows[("GPT-4o", "Gemini-2.5-Flash")]
    assert best["ade_avg_diff"] < 0 and best["ci95"][1] < 0 and best["significant"]


def test_generation_verdicts(study):
    out, dirs = study
    ev = evaluate_runs([out], resampling=FAST, pairwise=True)
    (gpt,) = [g for g in ev.generations() if g["family"] == "GPT"]
    assert (gpt["model"], gpt["predecessor"]) == ("GPT-5.0", "GPT-4o")
    row = next(r for r in ev.pairwise if (r["model_a"], r["model_b"]) == ("GPT-4o", "GPT-5.0"))
    assert gpt["change"] == pytest.approx(-row["ade_avg_diff"])
    assert gpt["verdict"] == (
        "not distinguishable" if not row["significant"] else ("better" if gpt["change"] < 0 else "worse")
    )


def test_holm_step_down():
    np.testing.assert_allclose(holm([0.01, 0.04, 0.03, 0.005]), [0.03, 0.06, 0.06, 0.02])
    np.testing.assert_allclose(holm([0.5, np.nan, 0.01]), [0.5, np.nan, 0.02])
    assert holm([]).shape == (0,)
    assert holm([0.9, 0.8]).max() <= 1.0


def test_sign_flip_p_values_detect_a_shift_and_not_noise():
    rng = np.random.default_rng(3)
    values, labels = simulate(rng, scenes=40, mu=0.0)
    shifted = values + 1.0
    p_null, p_shift = sign_flip_p(
        [(values, labels), (shifted, labels)], ["null", "shift"], Resampling(n_resamples=5000)
    )
    assert p_shift < 0.001 and p_null > 0.01


def test_cli_pairwise_json_and_bad_resamples(study, capsys):
    out, dirs = study
    assert main(["evaluate", str(out), "--pairwise", "--format", "json", "--resamples", "500", "--seed", "9"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert (
        doc["resampling"]["n_resamples"] == 500
        and doc["resampling"]["seed"] == 9
        and doc["resampling"]["unit"] == "scene"
    )
    table = next(t for t in doc["tables"] if t["name"] == "pairwise_ade")
    assert set(table["rows"][0]) >= {"model_a", "model_b", "ade_avg_diff", "ci95", "p_value", "p_holm", "significant"}
    accuracy = next(t for t in doc["tables"] if t["name"] == "accuracy_lightemma")
    assert len(accuracy["rows"][0]["ade_avg_ci95"]) == 2 and len(accuracy["rows"][0]["fde_ci95"]) == 2
    assert main(["evaluate", str(out), "--resamples", "-1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("lightemma evaluate: error:") and "--resamples" in err and "\n" not in err
