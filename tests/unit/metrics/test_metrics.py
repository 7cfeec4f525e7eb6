"""Errors and metrics: agreement with a NumPy reference for every convention, and bad input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import lightemma

WINDOWS = {  # 0-based inclusive step windows for 1 s, 2 s, 3 s
    "lightemma": [(0, 1), (2, 3), (4, 5)],
    "stp3": [(0, 1), (0, 3), (0, 5)],
    "uniad": [(1, 1), (3, 3), (5, 5)],
}


def reference_metrics(pred, gt, convention, threshold=2.0):
    e = np.sqrt(((pred - gt) ** 2).sum(-1))
    ades = [e[:, a : b + 1].mean(1).mean() for a, b in WINDOWS[convention]]
    # ADE avg: lightemma mean(e1..e6); stp3/uniad the mean of their three columns
    avg = e.mean(1).mean() if convention == "lightemma" else np.mean(ades)
    return {
        "ade_1s": ades[0],
        "ade_2s": ades[1],
        "ade_3s": ades[2],
        "ade_avg": avg,
        "fde": e[:, -1].mean(),
        "miss_rate": (e.max(1) > threshold).mean(),
        "n_frames": len(e),
    }


pairs = st.integers(1, 30).flatmap(
    lambda n: st.tuples(
        *[hnp.arrays(np.float64, (n, 6, 2), elements=st.floats(-100, 100, allow_nan=False, allow_infinity=False))] * 2
    )
)


@settings(max_examples=200, deadline=None)
@given(pairs, st.sampled_from(sorted(WINDOWS)), st.sampled_from([0.0, 0.5, 2.0, 10.0]))
def test_matches_numpy_reference(arrays, convention, threshold):
    pred, gt = arrays
    got = lightemma.evaluate(pred, gt, convention=convention, miss_threshold=threshold).to_dict()
    want = reference_metrics(pred, gt, convention, threshold)
    for key, value in want.items():
        assert got[key] == pytest.approx(value, rel=1e-12, abs=1e-12), key
    assert got["convention"] == convention


@settings(max_examples=100, deadline=None)
@given(pairs)
def test_displacement_errors_match_numpy(arrays):
    pred, gt = arrays
    np.testing.assert_allclose(lightemma.displacement_errors(pred, gt), np.sqrt(((pred - gt) ** 2).sum(-1)))


def test_known_values():
    gt = np.zeros((1, 6, 2))
    pred = gt.copy()
    pred[0, :, 1] = [1, 2, 3, 4, 5, 6]
    m = lightemma.evaluate(pred, gt)
    assert (m.ade_1s, m.ade_2s, m.ade_3s, m.ade_avg, m.fde, m.miss_rate, m.n_frames) == (
        1.5,
        3.5,
        5.5,
        3.5,
        6.0,
        1.0,
        1,
    )
    assert lightemma.evaluate(pred, gt, convention="stp3").ade_2s == 2.5
    assert lightemma.evaluate(pred, gt, convention="uniad").ade_3s == 6.0
    # "ADE avg" as each convention's papers print it: stp3 (1.5 + 2.5 + 3.5) / 3, uniad (2 + 4 + 6) / 3
    assert lightemma.evaluate(pred, gt, convention="stp3").ade_avg == 2.5
    assert lightemma.evaluate(pred, gt, convention="uniad").ade_avg == 4.0
    assert lightemma.evaluate(pred, gt, miss_threshold=6.0).miss_rate == 0.0


@settings(max_examples=100, deadline=None)
@given(pairs, st.sampled_from(sorted(WINDOWS)))
def test_ade_avg_is_the_mean_of_the_columns_and_frame_metrics_agree(arrays, convention):
    from lightemma.metrics import frame_metrics

    pred, gt = arrays
    m = lightemma.evaluate(pred, gt, convention=convention)
    assert m.ade_avg == pytest.approx((m.ade_1s + m.ade_2s + m.ade_3s) / 3, rel=1e-12, abs=1e-12)
    per_frame = frame_metrics(pred, gt, convention=convention)
    assert per_frame.shape == (len(pred), 5)
    np.testing.assert_allclose(
        per_frame.mean(0), [m.ade_1s, m.ade_2s, m.ade_3s, m.ade_avg, m.fde], rtol=1e-12, atol=1e-12
    )


def test_single_frame_errors():
    errors = lightemma.displacement_errors([[3.0, 4.0], [0.0, 1.0]], [[0.0, 0.0], [0.0, 0.0]])
    assert errors.tolist() == [5.0, 1.0]
    assert lightemma.evaluate(np.zeros((6, 2)), np.ones((6, 2))).ade_avg == pytest.approx(np.sqrt(2))


def test_large_batch_agrees():
    rng = np.random.default_rng(1)
    pred, gt = rng.normal(size=(2, 100_000, 6, 2))
    got = lightemma.evaluate(pred, gt, convention="stp3").to_dict()
    for key, value in reference_metrics(pred, gt, "stp3").items():
        assert got[key] == pytest.approx(value, rel=1e-9)


def test_metrics_conventions_listed():
    assert lightemma.CONVENTIONS == ("lightemma", "stp3", "uniad")


@pytest.mark.parametrize(
    ("pred", "gt", "kwargs", "message"),
    [
        (np.zeros((3, 6, 2)), np.zeros((2, 6, 2)), {}, r"pred has shape \(3, 6, 2\) but gt has shape \(2, 6, 2\)"),
        (np.zeros((2, 5, 2)), np.zeros((2, 6, 2)), {}, r"pred has shape \(2, 5, 2\)"),
        (np.zeros((2, 4, 2)), np.zeros((2, 4, 2)), {}, r"defined on 6 steps .* got T=4"),
        (np.zeros((0, 6, 2)), np.zeros((0, 6, 2)), {}, "empty batch"),
        (np.zeros((2, 6, 2)), np.zeros((2, 6, 2)), {"convention": "nuscenes"}, 'unknown convention "nuscenes"'),
        (np.zeros((2, 6, 2)), np.zeros((2, 6, 2)), {"miss_threshold": -1.0}, "miss_threshold"),
        (np.zeros((2, 6, 3)), np.zeros((2, 6, 3)), {}, r"shape \(N, T, 2\)"),
    ],
)
def test_bad_input_is_a_value_error(pred, gt, kwargs, message):
    with pytest.raises(ValueError, match=message):
        lightemma.evaluate(pred, gt, **kwargs)


def test_non_finite_values_name_frame_and_step():
    gt = np.zeros((4, 6, 2))
    gt[2, 5, 1] = np.nan
    with pytest.raises(ValueError, match="ground truth has a non-finite value .* at frame 2, step 5"):
        lightemma.evaluate(np.zeros((4, 6, 2)), gt)
    pred = np.zeros((4, 6, 2))
    pred[3, 0, 0] = np.inf
    with pytest.raises(ValueError, match="prediction has a non-finite value .* at frame 3, step 0"):
        lightemma.evaluate(pred, np.zeros((4, 6, 2)))


# --------------------------------------------------------------------------- mask


@settings(max_examples=100, deadline=None)
@given(pairs, st.sampled_from(sorted(WINDOWS)), st.data())
def test_mask_scores_exactly_the_kept_frames(arrays, convention, data):
    pred, gt = arrays
    keep = np.array(data.draw(st.lists(st.booleans(), min_size=len(pred), max_size=len(pred))), dtype=bool)
    if not keep.any():
        keep[0] = True
    pred = pred.copy()
    pred[~keep] = np.nan  # what a failed parse integrates to
    got = lightemma.evaluate(pred, gt, convention=convention, mask=keep).to_dict()
    want = reference_metrics(pred[keep], gt[keep], convention)
    for key, value in want.items():
        assert got[key] == pytest.approx(value, rel=1e-12, abs=1e-12), key


def test_mask_over_a_large_batch_matches_the_kept_frames():
    rng = np.random.default_rng(2)
    pred, gt = rng.normal(size=(2, 40_000, 6, 2))
    keep = rng.random(40_000) < 0.7
    pred[~keep] = np.nan
    got = lightemma.evaluate(pred, gt, convention="uniad", mask=keep).to_dict()
    for key, value in reference_metrics(pred[keep], gt[keep], "uniad").items():
        assert got[key] == pytest.approx(value, rel=1e-9)


def test_mask_with_parsed_answers_leaves_failed_ones_out():
    answers = ["[(5.0, 0.0), (5.0, 0.0), (5.0, 0.0), (5.0, 0.0), (5.0, 0.0), (5.0, 0.0)]", "I cannot tell."]
    parsed = lightemma.parse_actions(answers)
    traj = lightemma.integrate(parsed.actions)
    assert np.isnan(traj[1]).all()
    gt = np.nan_to_num(traj)
    with pytest.raises(ValueError, match="prediction has a non-finite value .* at frame 1"):
        lightemma.evaluate(traj, gt)
    m = lightemma.evaluate(traj, gt, mask=parsed.ok)
    assert (m.n_frames, m.ade_avg) == (1, 0.0)


def test_a_nan_in_a_kept_frame_is_still_named_by_its_batch_index():
    pred = np.zeros((4, 6, 2))
    pred[2, 3, 0] = np.nan
    gt = np.zeros((4, 6, 2))
    gt[0] = np.nan
    with pytest.raises(ValueError, match="prediction has a non-finite value .* at frame 2, step 3"):
        lightemma.evaluate(pred, gt, mask=[False, True, True, True])
    assert lightemma.evaluate(pred, gt, mask=[False, True, False, True]).n_frames == 2


@pytest.mark.parametrize(
    ("mask", "message"),
    [
        ([1, 0, 1], r"mask must be a boolean array, got dtype int64"),
        ([True, False], r"mask must have shape \(3,\), one entry per frame, got \(2,\)"),
        (np.ones((3, 1), dtype=bool), r"mask must have shape \(3,\)"),
        ([False, False, False], "keeps none of the 3 frames"),
        (["yes", "no", "yes"], "mask must be a boolean array"),
    ],
)
def test_bad_masks_are_value_errors(mask, message):
    with pytest.raises(ValueError, match=message):
        lightemma.evaluate(np.zeros((3, 6, 2)), np.zeros((3, 6, 2)), mask=mask)


def test_single_frame_takes_a_scalar_mask():
    assert lightemma.evaluate(np.zeros((6, 2)), np.ones((6, 2)), mask=True).n_frames == 1
    with pytest.raises(ValueError, match="keeps none"):
        lightemma.evaluate(np.zeros((6, 2)), np.ones((6, 2)), mask=np.bool_(False))


@pytest.mark.parametrize("which", ["pred", "gt"])
def test_bool_trajectories_are_refused_with_their_dtype(which):
    arrays = {"pred": np.zeros((2, 6, 2)), "gt": np.zeros((2, 6, 2))}
    arrays[which] = np.zeros((2, 6, 2), dtype=bool)
    with pytest.raises(ValueError, match=f"{which} must hold numbers, got dtype bool"):
        lightemma.evaluate(arrays["pred"], arrays["gt"])
    with pytest.raises(ValueError, match=f"{which} must hold numbers, got dtype bool"):
        lightemma.displacement_errors(arrays["pred"], arrays["gt"])


def test_evaluate_all_gives_every_convention_bit_for_bit_as_separate_calls():
    from lightemma.metrics import evaluate_all

    rng = np.random.default_rng(11)
    for n in (1, 37, 20_000):  # the largest crosses the parallel threshold and several blocks
        pred, gt = rng.normal(0, 5, (n, 6, 2)), rng.normal(0, 5, (n, 6, 2))
        mask = rng.random(n) < 0.8
        mask[0] = True
        for m in (None, mask):
            every = evaluate_all(pred, gt, miss_threshold=3.0, mask=m)
            assert list(every) == list(lightemma.CONVENTIONS)
            for convention, metrics in every.items():
                assert metrics == lightemma.evaluate(pred, gt, convention=convention, miss_threshold=3.0, mask=m)
    pred[5, 2, 0] = np.nan
    with pytest.raises(ValueError, match="frame 5"):
        evaluate_all(pred, gt)
    assert lightemma.evaluate_all is evaluate_all
