"""Type stubs for the compiled module ``lightemma._core`` (private; use ``lightemma``).

Checked against the built module by ``python -m mypy.stubtest lightemma._core`` (.ci/run): every name, parameter
and default here is the binding's (rust/python.rs, rust/python/). A default written ``...`` is one the binding
does not expose to introspection (a tuple or an ``Option``); its value is given in the docstring. The ``Literal``
aliases below list the names each string-mode parameter accepts, in the order of the runtime lists
(``METHODS``, ``CONVENTIONS``, ``PARSE_MODES``, ``PARSE_FAILURES``, ``PARSE_STATUSES``; tests/unit/package/test_core_stub.py
checks that they agree); any other string raises ``lightemma.errors.UnknownNameError`` (a ValueError) naming the
accepted ones.
"""

from typing import Literal, TypeAlias

import numpy as np
import numpy.typing as npt

_Method: TypeAlias = Literal["euler", "midpoint"]
"""Integration methods (docs/definitions.md#integration)."""
_Convention: TypeAlias = Literal["lightemma", "stp3", "uniad"]
"""ADE/FDE conventions (docs/definitions.md#metrics)."""
_ParseMode: TypeAlias = Literal["strict", "lenient", "paper", "json"]
"""Answer parsers (docs/parsing.md)."""
_ParseFailure: TypeAlias = Literal["", "truncated", "implausible", "format", "ambiguous"]
"""Failure kinds by code 0..4 ("" for a frame that did not fail)."""
_ParseStatus: TypeAlias = Literal["ok", "corrected", "failed"]
"""Parse statuses by code 0..2."""

__all__ = [
    "parse_actions",
    "integrate",
    "displacement_errors",
    "evaluate",
    "evaluate_all",
    "frame_metrics",
    "cluster_bootstrap",
    "sign_flip_test",
    "ego_poses",
    "footprint_corners",
    "box_collisions",
    "mask_area",
    "polygon_area",
    "mask_lookup",
    "read_intents",
    "INTENT_RULES",
    "INTENT_LONGITUDINAL",
    "INTENT_LATERAL",
    "INTENT_UNKNOWN",
    "INTENT_MAX_BYTES",
    "read_objects",
    "OBJECT_RULES",
    "OBJECT_CLASSES",
    "OBJECT_MENTIONS",
    "OBJECT_UNKNOWN",
    "simulate",
    "comfort",
    "extended_comfort",
    "COMFORT_BOUNDS",
    "COMFORT_LIMITS",
    "EXTENDED_COMFORT_FEATURES",
    "EXTENDED_COMFORT_LIMITS",
    "planning_subscores",
    "planning_first_bad_box",
    "PLANNING_SCORE_NAMES",
    "PLANNING_REASONS",
    "METHODS",
    "CONVENTIONS",
    "PARSE_MODES",
    "PARSE_FAILURES",
    "PARSE_STATUSES",
    "STEP_SECONDS",
    "EGO_LENGTH",
    "EGO_WIDTH",
    "EGO_OFFSET",
    "MIN_STEP",
    "ZOE_REAR_AXLE_TO_CENTER",
    "__version__",
]

__version__: str
METHODS: list[_Method]
CONVENTIONS: list[_Convention]
PARSE_MODES: list[_ParseMode]
PARSE_FAILURES: list[_ParseFailure]  # indexed by failure code
PARSE_STATUSES: list[_ParseStatus]  # indexed by status code
# lightemma's definitions (rust/definitions.rs; re-exported by lightemma.definitions): every kernel defaults to them
STEP_SECONDS: float  # 0.5: seconds between actions (integrate's and simulate's default step)
EGO_LENGTH: float  # 4.084 m: the ego box's length (the safety and planning kernels' default)
EGO_WIDTH: float  # 1.85 m: the ego box's width
EGO_OFFSET: float  # 1.443713 m: the box centre ahead of the rear axle (the safety kernels' default offset)
MIN_STEP: float  # 1.0 m: a shorter step keeps the previous heading (the safety kernels' default)

def parse_actions(
    texts: list[str],
    n: int = 6,
    mode: _ParseMode = "lenient",
    speed_range: tuple[float, float] | None = ...,
    max_abs_curvature: float | None = ...,
    history: npt.NDArray[np.float64] | None = None,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.uint8], npt.NDArray[np.uint8], list[str]]:
    """Parse answers: actions (N, n, 2) with NaN where failed, status codes (0 ok, 1 corrected, 2 failed),
    failure codes (indices into PARSE_FAILURES), reasons. ``history``: None or a C-contiguous float64
    (N, n, 2) array of the histories the prompts printed (a lenient list equal to its row is a quotation).
    Non-str items, bad limits and a history of another shape raise ValueError. Defaults: speed_range (-10.0, 50.0)
    m/s, max_abs_curvature 1.0 1/m; None turns a limit off."""

def integrate(
    actions: npt.NDArray[np.float64],
    dt: float = 0.5,
    method: _Method = "euler",
    out: npt.NDArray[np.float64] | None = None,
) -> npt.NDArray[np.float64]:
    """Integrate C-contiguous (N, T, 2) actions into (N, T, 2) positions (written into ``out`` when given, and
    returned)."""

def displacement_errors(pred: npt.NDArray[np.float64], gt: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Per-step Euclidean errors (N, T) of two C-contiguous (N, T, 2) arrays."""

def evaluate(
    pred: npt.NDArray[np.float64],
    gt: npt.NDArray[np.float64],
    convention: _Convention = "lightemma",
    miss_threshold: float = 2.0,
    mask: npt.NDArray[np.bool_] | None = None,
) -> tuple[float, float, float, float, float, float, int]:
    """(ade_1s, ade_2s, ade_3s, ade_avg, fde, miss_rate, n_frames) over (N, 6, 2) arrays; only frames ``mask`` keeps."""

def evaluate_all(
    pred: npt.NDArray[np.float64],
    gt: npt.NDArray[np.float64],
    miss_threshold: float = 2.0,
    mask: npt.NDArray[np.bool_] | None = None,
) -> list[tuple[float, float, float, float, float, float, int]]:
    """One ``evaluate`` tuple per convention, in ``CONVENTIONS`` order, from one error vector per frame."""

def frame_metrics(
    pred: npt.NDArray[np.float64], gt: npt.NDArray[np.float64], convention: _Convention = "lightemma"
) -> npt.NDArray[np.float64]:
    """Per-frame (N, 5): ade_1s, ade_2s, ade_3s, ade_avg, fde over C-contiguous (N, 6, 2) arrays."""

def cluster_bootstrap(
    sums: npt.NDArray[np.float64],
    counts: npt.NDArray[np.float64],
    offsets: npt.NDArray[np.int64],
    streams: npt.NDArray[np.uint64],
    n_resamples: int = 10_000,
    seed: int = 0,
    confidence: float = 0.95,
) -> npt.NDArray[np.float64]:
    """Percentile intervals (R, M, 2) of Σ sums / Σ counts over clusters drawn with replacement.

    sums (K, M) and counts (K,) per cluster; row r owns clusters offsets[r]:offsets[r+1];
    streams (R,) key each row's random numbers. NaN for a row without clusters."""

def sign_flip_test(
    sums: npt.NDArray[np.float64],
    counts: npt.NDArray[np.float64],
    offsets: npt.NDArray[np.int64],
    streams: npt.NDArray[np.uint64],
    n_permutations: int = 10_000,
    seed: int = 0,
) -> npt.NDArray[np.float64]:
    """Two-sided p-values (R,) that the mean of the clusters' summed differences (K, 1) is zero, by random sign
    flips."""

# ---- safety geometry (rust/safety.rs; docs/definitions.md#safety) ----
# traj: (N, T, 2) float64 in the ego frame of each keyframe (x forward, y left, m; origin = ego_pose, the
# rear-axle centre); poses: (N, 3) float64 global (x, y, yaw) of each keyframe. The footprint at step k is
# length × width, centred `offset` m ahead of p_k along the heading of segment p_{k-1} → p_k (p_0 = origin,
# heading 0), kept from the step before when that segment is shorter than `min_step` m.

def ego_poses(
    traj: npt.NDArray[np.float64],
    poses: npt.NDArray[np.float64],
    length: float = 4.084,
    width: float = 1.85,
    offset: float = 1.443713,
    min_step: float = 1.0,
) -> npt.NDArray[np.float64]:
    """Global (x, y, heading) of every step's reference point: (N, T, 3)."""

def footprint_corners(
    traj: npt.NDArray[np.float64],
    poses: npt.NDArray[np.float64],
    length: float = 4.084,
    width: float = 1.85,
    offset: float = 1.443713,
    min_step: float = 1.0,
) -> npt.NDArray[np.float64]:
    """Global footprint corners (N, T, 4, 2): front-left, front-right, rear-right, rear-left."""

def box_collisions(
    traj: npt.NDArray[np.float64],
    poses: npt.NDArray[np.float64],
    agents: npt.NDArray[np.float64],
    length: float = 4.084,
    width: float = 1.85,
    offset: float = 1.443713,
    min_step: float = 1.0,
) -> npt.NDArray[np.bool_]:
    """(N, T, A) overlap of the footprint with agents (N, T, A, 5) = global centre x, y, yaw, length, width
    (exact separating-axis test; touching is no overlap). A slot with NaN centre x is empty; other non-finite
    values or sizes ≤ 0 raise ValueError naming frame, step and slot."""

def mask_area(
    traj: npt.NDArray[np.float64],
    poses: npt.NDArray[np.float64],
    mask: npt.NDArray[np.uint8],
    resolution: float = 0.1,
    foreground: int = 255,
    length: float = 4.084,
    width: float = 1.85,
    offset: float = 1.443713,
    min_step: float = 1.0,
) -> npt.NDArray[np.uint8]:
    """(N, T, 5) lookups of the 4 corners then the reference point in a devkit MapMask raster (H, W):
    0 off, 1 on (pixel == foreground), 2 outside the image. Pixel = (round(x/r), round(-y/r + H)), half to even."""

def polygon_area(
    traj: npt.NDArray[np.float64],
    poses: npt.NDArray[np.float64],
    xy: npt.NDArray[np.float64],
    rings: npt.NDArray[np.int64],
    polygons: npt.NDArray[np.int64],
    length: float = 4.084,
    width: float = 1.85,
    offset: float = 1.443713,
    min_step: float = 1.0,
) -> npt.NDArray[np.uint8]:
    """(N, T, 5) point-in-polygon tests (0 off, 1 on) of the 4 corners then the reference point against the
    union of polygons: vertices xy (V, 2), ring offsets (R+1,) into vertices, polygon offsets (P+1,) into rings
    (first ring exterior, the rest holes)."""

def mask_lookup(
    points: npt.NDArray[np.float64], mask: npt.NDArray[np.uint8], resolution: float = 0.1, foreground: int = 255
) -> npt.NDArray[np.uint8]:
    """(M,) lookups of global points (M, 2) in a MapMask raster: 0 off, 1 on, 2 outside the image."""

# explanations: objects of stage-1 descriptions (rust/objects.rs, rules objects@lightemma/1)

OBJECT_RULES: str  # "objects@lightemma/1"
OBJECT_CLASSES: list[str]  # pedestrian, cyclist, motorcycle, car, truck, bus, traffic_cone, barrier, traffic_light, …
OBJECT_MENTIONS: list[str]  # not_mentioned, affirmed, negated, hedged (code order)
OBJECT_UNKNOWN: int  # 255: the code of "unknown"

def read_objects(texts: list[str]) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.int32], list[str]]:
    """(mention codes (N, C), counts (N, C), reasons) of stage-1 texts, C = len(OBJECT_CLASSES): codes index
    OBJECT_MENTIONS, OBJECT_UNKNOWN where unknown; count -1 where none is stated. ValueError names the first item
    that is not str."""

# planning: simulation and comfort (rust/planning/simulate.rs, comfort.rs;
# docs/definitions.md#re-simulation-and-comfort)

ZOE_REAR_AXLE_TO_CENTER: float  # 1.444 m: the planning score's Zoe, box centre ahead of the rear axle
COMFORT_BOUNDS: list[str]  # lon_acceleration, lat_acceleration, jerk, lon_jerk, yaw_acceleration, yaw_rate
COMFORT_LIMITS: list[tuple[float, float]]  # exclusive (lower, upper): m/s², m/s², m/s³, m/s³, rad/s², rad/s
EXTENDED_COMFORT_FEATURES: list[str]  # acceleration, jerk, yaw_rate, yaw_acceleration
EXTENDED_COMFORT_LIMITS: list[float]  # inclusive RMS-difference limits: 0.7, 0.5, 0.1, 0.1

def simulate(
    poses: npt.NDArray[np.float64],
    initial: npt.NDArray[np.float64],
    plan_dt: float = 0.5,
    dt: float = 0.1,
    vehicle: tuple[float, float, float, float, float] = ...,
) -> npt.NDArray[np.float64]:
    """(N, T+1, 11) states in NAVSIM's layout: plans (N, K, 3) x, y, heading at plan_dt … K plan_dt resampled at dt
    and tracked by nuPlan's LQR on a kinematic bicycle from initial (N, 11); T = K plan_dt / dt. vehicle = (wheel_base,
    rear_axle_to_center, max_steering_angle, accel_time_constant, steering_angle_time_constant), by default nuPlan's
    Pacifica (2.588, 1.444, π/3, 0.2, 0.05). A frame with a
    non-finite input is NaN throughout; ValueError for shapes, a horizon not a whole number of steps, bad vehicle."""

def comfort(
    states: npt.NDArray[np.float64],
    dt: float = 0.1,
    rear_axle_to_center: float = 1.444,
    history: npt.NDArray[np.float64] | None = None,
) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.float64]]:
    """nuPlan's six comfort bounds on states (N, T, 11) at dt, each frame preceded by its history (N, H, 11) when
    given (H + T ≥ 4): (within (N, 6), extremes (N, 6, 2) min, max of each filtered signal). A non-finite frame: no
    bound met, NaN extremes."""

def extended_comfort(
    now: npt.NDArray[np.float64], prev: npt.NDArray[np.float64], dt: float = 0.1, shift: int = 5
) -> npt.NDArray[np.float64]:
    """(N, 4) RMS differences of NAVSIM v2's extended-comfort features between now[:, :T-shift] and prev[:, shift:]
    (both (N, T, 11)); NaN for a non-finite pair."""

# explanations: intents (rust/intent.rs; docs/parsing.md#intents, rules intent@lightemma/1)

INTENT_RULES: str  # "intent@lightemma/1"
INTENT_LONGITUDINAL: list[str]  # accelerate, keep_speed, decelerate, stop, stay_stopped, start (code order)
INTENT_LATERAL: list[str]  # follow_lane, turn_left, turn_right, change_lane_left, change_lane_right (code order)
INTENT_UNKNOWN: int  # 255: the code of "unknown"
INTENT_MAX_BYTES: int  # texts longer than this (bytes) are unknown, "text too long"

def read_intents(
    texts: list[str],
) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8], list[str], list[str], list[str]]:
    """(longitudinal codes (N,), lateral codes (N,), reasons, longitudinal sentences, lateral sentences) of the
    planned part of stage-2 texts; code INTENT_UNKNOWN where an axis is unknown (the reason says why). ValueError
    names the first item that is not str; a bad text never raises."""

# planning: sub-scores (rust/planning/scores.rs; docs/definitions.md#sub-scores-and-aggregates)

PLANNING_SCORE_NAMES: list[str]  # columns of planning_subscores: nc, dac, ddc, ep_raw, ttc, lk
PLANNING_REASONS: list[str]  # reason code names, indexed by code (0 "ok")

def planning_subscores(
    states: npt.NDArray[np.float64],
    frame: npt.NDArray[np.int64],
    *,
    agents: npt.NDArray[np.float64] | None = None,
    drivable_mask: npt.NDArray[np.uint8] | None = None,
    mask_resolution: float = 0.1,
    mask_foreground: int = 255,
    drivable: tuple[npt.NDArray[np.float64], npt.NDArray[np.int64], npt.NDArray[np.int64]] | None = None,
    lanes: tuple[npt.NDArray[np.float64], npt.NDArray[np.int64], npt.NDArray[np.int64]] | None = None,
    lane_offsets: npt.NDArray[np.int64] | None = None,
    lane_ids: npt.NDArray[np.int64] | None = None,
    lane_on_route: npt.NDArray[np.uint8] | None = None,
    intersections: tuple[npt.NDArray[np.float64], npt.NDArray[np.int64], npt.NDArray[np.int64]] | None = None,
    route: npt.NDArray[np.float64] | None = None,
    centreline: npt.NDArray[np.float64] | None = None,
    n_frames: int | None = None,
    length: float = 4.084,
    width: float = 1.85,
    rear_axle_to_center: float = 1.444,
    dt: float = 0.1,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.uint8]]:
    """NAVSIM's sub-scores of N plans: (values (N, 6) float64 with NaN where n/a, reason codes (N, 6) uint8), columns
    PLANNING_SCORE_NAMES (ep_raw in metres, clipped at 0). states (N, S, 11) float64 in NAVSIM's StateIndex layout
    (rear axle, global frame, m, rad, m/s), S ≥ 2 states dt s apart; frame (N,) the scene frame of each plan, indexing
    the per-frame inputs: agents (F, S, A, 8) = centre x, y, yaw, length, width, velocity x, y, kind (0 agent,
    1 static object; NaN centre x = absent slot); route, centreline (F, R, 2) polylines padded with NaN rows; lane
    lists lane_offsets (F + 1,), lane_ids (K,), lane_on_route (K,) into the lane polygons. Map layers: drivable as a
    devkit MapMask raster or polygons, lanes and intersections as polygons (xy (V, 2), ring offsets (R + 1,), polygon
    offsets (P + 1,)). A missing input makes the sub-scores needing it n/a (a reason code); ValueError on shapes that
    disagree, a frame index ≥ F, S < 2. GIL released for large batches."""

def planning_first_bad_box(agents: npt.NDArray[np.float64], frame: int) -> tuple[int, int] | None:
    """(step, slot) of the first degenerate box of that frame of agents (F, S, A, 8), or None."""
