"""Golden reproductions: each published convention pinned on a small fixed input, under its descriptor's versioned id.

The expected values are worked out by hand from the published definitions (docs/definitions.md#metrics and #safety),
not taken from lightemma's output. A change that moves one of them fails here; a deliberate change of a definition
bumps its version in lightemma/evaluation/descriptors.py, and the new id then needs its own golden entry below (the
old entry no longer applies: :func:`test_every_printed_metric_has_a_golden_value` fails until it is added).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from lightemma.evaluation.descriptors import ADE_BY_CONVENTION, COLLISION_BY_CONVENTION, METRICS, miss_descriptor

# --- the fixed input: two frames whose errors e_k (k = 1 … 6) are k m and 0.1·k m, along a slanted direction
_ERRORS = np.array([[1.0, 2.0, 3.0, 4.0, 5.0, 6.0], [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]])
_ANGLE = 0.7


def _trajectories() -> tuple[np.ndarray, np.ndarray]:
    gt = np.stack([np.column_stack([np.arange(1, 7) * 2.0, np.arange(1, 7) * 0.3 * s]) for s in (1.0, -1.0)])
    direction = np.array([np.cos(_ANGLE), np.sin(_ANGLE)])
    return gt + _ERRORS[:, :, None] * direction, gt


#: descriptor id -> column -> value, by hand:
#: lightemma: mean(e1,e2), mean(e3,e4), mean(e5,e6), mean(e1…e6) per frame, then the mean over the two frames
#: stp3 (ST-P3 / VAD): mean(e1,e2), mean(e1…e4), mean(e1…e6), avg the mean of the three columns
#: uniad (UniAD): e2, e4, e6, avg the mean of the three columns
GOLDEN: dict[str, dict[str, float]] = {
    "ade@lightemma/1": {
        "ade_1s": (1.5 + 0.15) / 2,
        "ade_2s": (3.5 + 0.35) / 2,
        "ade_3s": (5.5 + 0.55) / 2,
        "ade_avg": (3.5 + 0.35) / 2,
    },
    "l2@stp3/1": {
        "ade_1s": (1.5 + 0.15) / 2,
        "ade_2s": (2.5 + 0.25) / 2,
        "ade_3s": (3.5 + 0.35) / 2,
        "ade_avg": ((1.5 + 0.15) / 2 + (2.5 + 0.25) / 2 + (3.5 + 0.35) / 2) / 3,
    },
    "l2@uniad/1": {
        "ade_1s": (2 + 0.2) / 2,
        "ade_2s": (4 + 0.4) / 2,
        "ade_3s": (6 + 0.6) / 2,
        "ade_avg": (1.1 + 2.2 + 3.3) / 3,
    },
    "fde/1": {"fde": (6 + 0.6) / 2},
    "miss@2m/1": {"miss_rate": 0.5},  # frame 1's largest error 6 m > 2 m; frame 2's 0.6 m is not
    # FE over the first statuses ok, corrected, failed, ok (an API error and an unknown status are left out)
    "fe@paper/1": {"fe_pct": 50.0},
    "fe_corr@paper/1": {"fe_corr_pct": 25.0},
    # the collision and off-road inputs: see _collisions() and _areas()
    "collision@uniad/1": {
        "collision_1s": 0.5,
        "collision_2s": 0.0,
        "collision_3s": 0.0,
        "collision": (1 / 3 + 0) / 2,
        "collision_vehicle": (1 / 3) / 2,
        "collision_vru": 0.0,
    },
    "collision@stp3/1": {
        "collision_1s": (0.5 + 0) / 2,
        "collision_2s": (0.25 + 0) / 2,
        "collision_3s": (1 / 6 + 0) / 2,
        "collision": ((0.5 + 0.25 + 1 / 6) / 3) / 2,
    },
    "collision@any/1": {
        "collision_1s": 0.5,
        "collision_2s": 0.5,
        "collision_3s": 1.0,
        "collision": 1.0,
        "collision_vru": 0.5,
    },
    "offroad@footprint/1": {"offroad": 0.75, "offroad_1s": 0.25, "offroad_2s": 0.25, "offroad_3s": 0.25},
    "offroad@centre/1": {"offroad_centre": 0.25},
    # NAVSIM's scores on the scene of tests/unit/planning/test_planning_scores.py::test_aggregates_by_hand: a plan at 5 m/s behind a
    # ground truth at 10 m/s in its lane (ep = 15 m / 30 m), nothing hit, on the road; c = hc = 1 and ec = 0 given
    "pdms@nuscenes/1": {"pdms": 1 * 1 * (5 * 0.5 + 5 * 1 + 2 * 1) / 12},
    "epdms@nuscenes/1": {"epdms": 1 * 1 * 1 * 1 * (5 * 0.5 + 5 * 1 + 2 * 1 + 2 * 1 + 2 * 0) / 16},
    "epdms_map@nuscenes/1": {
        "epdms_map": 1 * 1 * (5 * 0.5 + 2 * 1 + 2 * 1 + 2 * 0) / 11
    },  # the same scene without agents
    "nc@navsim/1": {"nc": 1.0},
    "dac@navsim/1": {"dac": 1.0},
    "ddc@navsim/1": {"ddc": 1.0},
    "ttc@navsim/1": {"ttc": 1.0},
    "lk@navsim/1": {"lk": 1.0},
    "ep@navsim/1": {"ep": 0.5},
}

#: descriptors whose values are not computed by the metric code pinned here: tlc is n/a on nuScenes by definition; c, hc
#: and ec are the re-simulation's comfort scores, given to the scorer and pinned by tests/unit/planning/test_planning_simulation.py
NOT_PINNED_HERE = {"tlc@navsim/1", "c@navsim/1", "hc@navsim/1", "ec@navsim/1"}


def test_every_printed_metric_has_a_golden_value():
    printed = set(METRICS) - NOT_PINNED_HERE | {miss_descriptor(2.0).id}
    assert printed - set(GOLDEN) == set(), (
        "a metric's version was bumped (or a metric added): pin its new golden values"
    )
    assert set(GOLDEN) - printed == set(), "a golden entry for an id the registry no longer has: its definition moved"


@pytest.mark.parametrize("convention", ["lightemma", "stp3", "uniad"])
def test_ade_conventions(convention):
    from lightemma import evaluate

    pred, gt = _trajectories()
    got = evaluate(pred, gt, convention=convention, miss_threshold=2.0).to_dict()
    want = GOLDEN[ADE_BY_CONVENTION[convention]]
    assert {k: got[k] for k in want} == pytest.approx(want, rel=1e-12, abs=1e-12)
    assert got["fde"] == pytest.approx(GOLDEN["fde/1"]["fde"], rel=1e-12)
    assert got["miss_rate"] == pytest.approx(GOLDEN[miss_descriptor(2.0).id]["miss_rate"], abs=0)


def test_ade_conventions_from_the_evaluation_pipeline():
    """The same numbers through evaluation.core.score (blocks, frame weighting), as ``lightemma evaluate`` does."""
    from lightemma.evaluation.core import score

    pred, gt = _trajectories()
    run = SimpleNamespace(trajectory=pred, gt_positions=gt)
    got = score(run, np.arange(2), ("lightemma", "stp3", "uniad"), 2.0)  # type: ignore[arg-type]
    for convention, id_ in ADE_BY_CONVENTION.items():
        assert {k: got[convention][k] for k in GOLDEN[id_]} == pytest.approx(GOLDEN[id_], rel=1e-12)


def test_format_error_rates_paper_rule():
    from lightemma.definitions import STATUS_CODES
    from lightemma.evaluation.accounting import format_errors
    from lightemma.runs.columns import API_ERROR_STATUS, UNKNOWN_STATUS

    first = np.array(
        [
            STATUS_CODES["ok"],
            STATUS_CODES["corrected"],
            STATUS_CODES["failed"],
            STATUS_CODES["ok"],
            API_ERROR_STATUS,
            UNKNOWN_STATUS,
        ]
    )
    run = SimpleNamespace(first_status=first, status=np.zeros(6, dtype=np.int64))
    got = format_errors(run, np.arange(6))  # type: ignore[arg-type]
    assert got["fe_pct"] == GOLDEN["fe@paper/1"]["fe_pct"]
    assert got["fe_corr_pct"] == GOLDEN["fe_corr@paper/1"]["fe_corr_pct"]
    assert got["api_error_frames"] == 1


def _collisions():
    """Two frames: A hits a vehicle at step 2 (1.0 s); B hits a pedestrian at step 5 (2.5 s), where the ground truth
    collides too. Off-road is not under test here (every point on the drivable area)."""
    from lightemma.evaluation import safety as S

    def frames(collide):
        n = len(collide)
        return S.FrameSafety(
            area=np.full((n, 6, 5), S.ON, dtype=np.uint8),
            area_ok=np.ones(n, bool),
            area_reason=[""] * n,
            area_kind=["expansion"] * n,
            collide=collide,
            coll_ok=np.ones(n, bool),
            coll_reason=[""] * n,
        )

    plan = np.zeros((2, 6, 2), dtype=bool)
    plan[0, 1, 0] = True  # A: vehicle at step 2
    plan[1, 4, 1] = True  # B: VRU at step 5
    gt = np.zeros((2, 6, 2), dtype=bool)
    gt[1, 4, 0] = True  # the ground truth of B collides at step 5 too
    return frames(plan), frames(gt)


@pytest.mark.parametrize("convention", ["uniad", "stp3", "any"])
def test_collision_conventions(convention):
    """UniAD (at T, ground-truth collisions masked), ST-P3 (prefix mean, masked), BEV-Planner's any (not masked)."""
    from lightemma.evaluation import safety as S

    plan, gt = _collisions()
    got = S.rates(S.safety_values(plan, convention, gt=gt))
    want = GOLDEN[COLLISION_BY_CONVENTION[convention]]
    assert {k: got[k] for k in want} == pytest.approx(want, rel=1e-12, abs=1e-15)


def test_collision_masking_is_what_moves_stp3():
    """Without the ground truth, ST-P3's rule counts B's step-5 hit: the golden (masked) value differs, so the masking
    is pinned too."""
    from lightemma.evaluation import safety as S

    plan, _ = _collisions()
    got = S.rates(S.safety_values(plan, "stp3"))
    assert got["collision_3s"] == pytest.approx((1 / 6 + 1 / 6) / 2)
    assert got["collision_3s"] != pytest.approx(GOLDEN["collision@stp3/1"]["collision_3s"])


def test_offroad_footprint_and_centre():
    """Four frames: A a corner off at step 4 (2.0 s); B corners and the reference point off at step 6 (3.0 s); C on the
    road throughout; D a corner outside the mask image at step 2 (1.0 s; counts as off)."""
    from lightemma.evaluation import safety as S

    area = np.full((4, 6, 5), S.ON, dtype=np.uint8)
    area[0, 3, 0] = S.OFF
    area[1, 5, :] = S.OFF
    area[3, 1, 2] = S.OUTSIDE
    fs = S.FrameSafety(
        area=area,
        area_ok=np.ones(4, bool),
        area_reason=[""] * 4,
        area_kind=["mask"] * 4,
        collide=np.zeros((4, 6, 2), bool),
        coll_ok=np.ones(4, bool),
        coll_reason=[""] * 4,
    )
    got = S.rates(S.safety_values(fs, "any"))
    for id_ in ("offroad@footprint/1", "offroad@centre/1"):
        assert {k: got[k] for k in GOLDEN[id_]} == pytest.approx(GOLDEN[id_], abs=0)


@pytest.mark.parametrize(
    ("n_keyframes", "window", "frames", "first", "last"),
    [(40, "reference", 26, 7, 32), (40, "full", 27, 7, 33), (14, "reference", 0, None, None), (14, "full", 1, 7, 7)],
)
def test_the_papers_window(n_keyframes, window, frames, first, last):
    """The paper's window keeps keyframes 7 … N−8 (N − 14 frames a scene); ``full`` 7 … N−7 (N − 13)."""
    from lightemma.nuscenes import window_range

    got = window_range(n_keyframes, window)
    assert len(got) == frames
    if frames:
        assert (got[0], got[-1]) == (first, last)


def test_navsim_scores_and_aggregates():
    """PDMS = nc·dac·(5ep + 5ttc + 2c)/12, EPDMS = nc·dac·ddc·tlc·(5ep + 5ttc + 2lk + 2hc + 2ec)/16 (tlc counted as 1),
    EPDMS-map = dac·ddc·(5ep + 2lk + 2hc + 2ec)/11 without annotations
    (docs/definitions.md#sub-scores-and-aggregates)."""
    import math

    from tests.unit.planning.test_planning_scores import _drive, agents_of, run, track

    gt, plan = run(0, -1.75, 10), run(0, -1.75, 5)
    r = _drive(plan, gt, agents=agents_of(track(100, 30, 0)))
    for id_ in (
        "pdms@nuscenes/1",
        "epdms@nuscenes/1",
        "nc@navsim/1",
        "dac@navsim/1",
        "ddc@navsim/1",
        "ttc@navsim/1",
        "lk@navsim/1",
        "ep@navsim/1",
    ):
        assert {k: float(r[k][0]) for k in GOLDEN[id_]} == pytest.approx(GOLDEN[id_], rel=1e-12), id_
    assert math.isnan(r["tlc"][0]) and math.isnan(r["epdms_map"][0])
    r = _drive(plan, gt)
    assert float(r["epdms_map"][0]) == pytest.approx(GOLDEN["epdms_map@nuscenes/1"]["epdms_map"], rel=1e-12)
