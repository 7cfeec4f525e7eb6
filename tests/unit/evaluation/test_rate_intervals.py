"""Intervals of rates (off-road, collision) at 0 %, 100 % and in between (issue 32 item 2, docs/statistics.md#rates).

A scene bootstrap of a rate of 0 resamples zeros and prints ``0.00 [0.00, 0.00]``: certainty the data does not give.
Rates get an exact binomial interval on the scene-clustered effective sample size instead, which at the boundary
treats every scene as one observation (no event in 24 scenes: [0, 14.2 %])."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import beta, t

from lightemma.evaluation.stats import Resampling, bootstrap_ci, cluster_sums, rate_ci, rate_interval

SCENES_24 = np.repeat(np.arange(24), 30)  # 24 scenes of 30 frames


def test_no_event_in_24_scenes_is_the_exact_bound_on_24_scenes():
    low, high = rate_interval(np.zeros(720), SCENES_24)
    assert low == 0.0 and high == pytest.approx(1 - 0.025 ** (1 / 24)) and high == pytest.approx(0.1425, abs=5e-4)
    low, high = rate_interval(np.ones(720), SCENES_24)
    assert high == 1.0 and low == pytest.approx(0.025 ** (1 / 24))
    # the scene bootstrap it replaces is degenerate there
    boot = bootstrap_ci([(np.zeros(720), SCENES_24)], ["m"], Resampling(n_resamples=500))
    np.testing.assert_array_equal(boot[0, 0], [0.0, 0.0])
    # unequal scenes: still the number of scenes, not of frames
    scenes = np.repeat(np.arange(5), [1, 2, 3, 40, 200])
    assert rate_interval(np.zeros(len(scenes)), scenes)[1] == pytest.approx(1 - 0.025 ** (1 / 5))
    # another confidence
    assert rate_interval(np.zeros(720), SCENES_24, 0.9)[1] == pytest.approx(1 - 0.05 ** (1 / 24))


def _restated(values, scenes, confidence=0.95):
    """The definition in docs/statistics.md, written out again."""
    sums, counts = cluster_sums(values, scenes)
    s, k, n = sums[:, 0], len(counts), counts.sum()
    p, a = s.sum() / n, 1 - confidence
    var = k / (k - 1) * np.sum((s - p * counts) ** 2) / n**2
    n_eff = min(n, p * (1 - p) / var) * (t.ppf(1 - a / 2, n - 1) / t.ppf(1 - a / 2, k - 1)) ** 2
    j = min(np.sum(s > 0), np.sum(s < counts))
    n_eff = min(n_eff, max(k, j * n / k))
    x = p * n_eff
    return beta.ppf(a / 2, x, n_eff - x + 1), beta.ppf(1 - a / 2, x + 1, n_eff - x)


def test_in_between_it_is_the_clustered_exact_interval():
    rng = np.random.default_rng(3)
    for rate, spread in [(0.3, 50.0), (0.3, 1.0), (0.05, 2.0), (0.9, 5.0)]:
        scene_rates = rng.beta(rate * spread, (1 - rate) * spread, size=24)
        values = (rng.random((24, 30)) < scene_rates[:, None]).astype(float).ravel()
        if values.sum() in (0, values.size):
            continue
        low, high = rate_interval(values, SCENES_24)
        assert 0.0 < low < values.mean() < high < 1.0
        assert (low, high) == pytest.approx(_restated(values, SCENES_24), rel=1e-9)
    # frames clustered by scene give a wider interval than the same frames independent of their scenes
    values = np.repeat(rng.random(24) < 0.3, 30).astype(float)  # whole scenes off-road or not
    spread_out = values.reshape(24, 30).T.ravel()  # the same frames, spread over every scene
    wide, narrow = rate_interval(values, SCENES_24), rate_interval(spread_out, SCENES_24)
    assert values.mean() == spread_out.mean() and wide[1] - wide[0] > 2 * (narrow[1] - narrow[0])
    # fractional per-frame values (stp3 / uniad collision shares of steps) are rates too
    low, high = rate_interval(np.where(np.arange(720) % 7 == 0, 0.5, 0.0), SCENES_24)
    assert 0.0 < low < 0.5 / 7 < high < 1.0


def test_a_few_events_in_one_scene_are_no_more_certain_than_that_scene():
    """Events in one scene give no more than that scene's worth of frames: the interval does not collapse from
    [0, 14.2 %] at zero events to a fraction of a percent at one, and its upper end grows with the events."""
    highs = [rate_interval(np.zeros(720), SCENES_24)[1]]
    for events in ([0], [0, 1, 2, 3, 4], list(range(30))):
        values = np.zeros(720)
        values[events] = 1.0
        low, high = rate_interval(values, SCENES_24)
        assert 0.0 < low < values.mean() < high and high > 0.1, (events, low, high)
        highs.append(high)
    assert highs[1] <= highs[2] <= highs[3] and highs[3] > highs[0], highs


def test_coverage_on_clustered_rare_events_where_the_bootstrap_fails():
    """Property: over 300 fixtures whose scenes have their own rate (mean 3 %, strongly clustered, some with no
    event at all), the 95 % interval covers the true rate at least 90 % of the time; the scene bootstrap it
    replaces covers it far less often (it is [0, 0] whenever no scene had an event)."""
    rng = np.random.default_rng(2024)
    truth, groups = 0.03, []
    for _ in range(300):
        scene_rates = rng.beta(truth * 1.0, (1 - truth) * 1.0, size=24)
        values = (rng.random((24, 26)) < scene_rates[:, None]).astype(float).ravel()
        groups.append((values, np.repeat(np.arange(24), 26)))
    ours = rate_ci(groups)[:, 0]
    covered = np.mean((ours[:, 0] <= truth) & (truth <= ours[:, 1]))
    assert covered >= 0.9, covered
    boot = bootstrap_ci(groups, [f"f{i}" for i in range(len(groups))], Resampling(n_resamples=1000, seed=1))[:, 0]
    assert np.mean((boot[:, 0] <= truth) & (truth <= boot[:, 1])) < covered - 0.05
    assert any(v.sum() == 0 for v, _ in groups)  # the fixture holds the boundary case


def test_no_interval_and_bad_input():
    assert np.isnan(rate_interval(np.zeros(30), np.zeros(30))).all()  # one scene
    assert np.isnan(rate_ci([(np.zeros(720), SCENES_24)], Resampling(n_resamples=0))).all()  # --resamples 0
    assert rate_ci([], Resampling()).shape == (0, 1, 2)
    with pytest.raises(ValueError, match=r"finite numbers in \[0, 1\]: value 2\.0 at index 3"):
        rate_interval([0, 0, 0, 2.0], [0, 0, 1, 1])
    with pytest.raises(ValueError, match=r"value nan at index 0"):
        rate_interval([np.nan, 0], [0, 1])
    with pytest.raises(ValueError, match=r"must be \(N,\)"):
        rate_interval(np.zeros((4, 2)), [0, 0, 1, 1])
    with pytest.raises(ValueError, match="clusters"):
        rate_interval(np.zeros(4), [0, 1])
    with pytest.raises(ValueError, match="confidence"):
        rate_interval(np.zeros(4), [0, 0, 1, 1], confidence=1.0)


def test_the_ground_truth_floor_prints_a_real_interval_at_zero(tmp_path):
    """End to end: the floor's off-road and collision are 0 % on the synthetic data; their intervals are the exact
    bound on the floor's scenes, not [0, 0]. ADE keeps its scene bootstrap."""
    from lightemma.cli import main
    from lightemma.evaluation import evaluate_loaded, load_run
    from lightemma.report.evaluation_tables import evaluation_tables
    from lightemma.report.tables import render
    from lightemma.runs.store import find_run_dirs
    from lightemma.synth import write_dataset

    root = write_dataset(tmp_path / "data", scenes=4, keyframes=20, image_size=(32, 18), sweeps=False)
    args = ["--dataroot", str(root), "--version", "v1.0-mini", "--split", "all", "--out", str(tmp_path / "runs")]
    assert main(["run", "--model", "baseline:oracle", *args]) == 0
    run = load_run(find_run_dirs(tmp_path / "runs")[0])
    scenes = len({f.rsplit("/", 1)[0] for f in run.frame_ids})
    ev = evaluate_loaded([run], convention="lightemma", resampling=Resampling(n_resamples=200, seed=0))
    floor, row = ev.safety.floor["lightemma"], ev.accuracy_rows("lightemma")[0]
    bound = 1 - 0.025 ** (1 / scenes)
    assert scenes == 4 and floor["offroad"] == 0.0 and floor["collision"] == 0.0
    for key in ("offroad_ci95", "collision_ci95"):
        assert floor[key] == pytest.approx([0.0, bound]), key
        assert row[key.removesuffix("_ci95")] == 0.0 and row[key] == pytest.approx([0.0, bound]), key  # the oracle
    md = render(evaluation_tables(ev), "md")
    assert f"0.00 [0.00, {100 * bound:.2f}]" in md
