"""Type stubs for the compiled module ``lightemma._core`` (private; use ``lightemma``)."""

import numpy as np
import numpy.typing as npt

__version__: str
METHODS: list[str]
CONVENTIONS: list[str]
PARSE_MODES: list[str]  # strict, lenient, paper, json
PARSE_FAILURES: list[str]  # failure codes 0..4: "", truncated, implausible, format, ambiguous

def parse_actions(
    texts: list[str],
    n: int = 6,
    mode: str = "lenient",
    speed_range: tuple[float, float] | None = (-10.0, 50.0),
    max_abs_curvature: float | None = 1.0,
    history: npt.NDArray[np.float64] | None = None,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.uint8], npt.NDArray[np.uint8], list[str]]:
    """Parse answers: actions (N, n, 2) with NaN where failed, status codes (0 ok, 1 corrected, 2 failed),
    failure codes (indices into PARSE_FAILURES), reasons. ``history``: None or a C-contiguous float64
    (N, n, 2) array of the histories the prompts printed (a lenient list equal to its row is a quotation).
    Non-str items, bad limits and a history of another shape raise ValueError."""

def integrate(
    actions: npt.NDArray[np.float64], dt: float = 0.5, method: str = "euler", out: npt.NDArray[np.float64] | None = None
) -> npt.NDArray[np.float64]:
    """Integrate C-contiguous (N, T, 2) actions into (N, T, 2) positions (written into ``out`` when given, and returned)."""

def displacement_errors(pred: npt.NDArray[np.float64], gt: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Per-step Euclidean errors (N, T) of two C-contiguous (N, T, 2) arrays."""

def evaluate(
    pred: npt.NDArray[np.float64],
    gt: npt.NDArray[np.float64],
    convention: str = "lightemma",
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
    pred: npt.NDArray[np.float64], gt: npt.NDArray[np.float64], convention: str = "lightemma"
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
    """Two-sided p-values (R,) that the mean of the clusters' summed differences (K, 1) is zero, by random sign flips."""

# ---- safety geometry (rust/safety.rs; docs/definitions.md#safety) ----
# traj: (N, T, 2) float64 in the ego frame of each keyframe (x forward, y left, m; origin = ego_pose, the
# rear-axle centre); poses: (N, 3) float64 global (x, y, yaw) of each keyframe. The footprint at step k is
# length × width, centred `offset` m ahead of p_k along the heading of segment p_{k-1} → p_k (p_0 = origin,
# heading 0), kept from the step before when that segment is shorter than `min_step` m.

def ego_poses(
    traj: npt.NDArray[np.float64], poses: npt.NDArray[np.float64],
    length: float = 4.084, width: float = 1.85, offset: float = 0.0, min_step: float = 1.0,
) -> npt.NDArray[np.float64]:
    """Global (x, y, heading) of every step's reference point: (N, T, 3)."""

def footprint_corners(
    traj: npt.NDArray[np.float64], poses: npt.NDArray[np.float64],
    length: float = 4.084, width: float = 1.85, offset: float = 0.0, min_step: float = 1.0,
) -> npt.NDArray[np.float64]:
    """Global footprint corners (N, T, 4, 2): front-left, front-right, rear-right, rear-left."""

def box_collisions(
    traj: npt.NDArray[np.float64], poses: npt.NDArray[np.float64], agents: npt.NDArray[np.float64],
    length: float = 4.084, width: float = 1.85, offset: float = 0.0, min_step: float = 1.0,
) -> npt.NDArray[np.bool_]:
    """(N, T, A) overlap of the footprint with agents (N, T, A, 5) = global centre x, y, yaw, length, width
    (exact separating-axis test; touching is no overlap). A slot with NaN centre x is empty; other non-finite
    values or sizes ≤ 0 raise ValueError naming frame, step and slot."""

def mask_area(
    traj: npt.NDArray[np.float64], poses: npt.NDArray[np.float64], mask: npt.NDArray[np.uint8],
    resolution: float = 0.1, foreground: int = 255,
    length: float = 4.084, width: float = 1.85, offset: float = 0.0, min_step: float = 1.0,
) -> npt.NDArray[np.uint8]:
    """(N, T, 5) lookups of the 4 corners then the reference point in a devkit MapMask raster (H, W):
    0 off, 1 on (pixel == foreground), 2 outside the image. Pixel = (round(x/r), round(-y/r + H)), half to even."""

def polygon_area(
    traj: npt.NDArray[np.float64], poses: npt.NDArray[np.float64], xy: npt.NDArray[np.float64],
    rings: npt.NDArray[np.int64], polygons: npt.NDArray[np.int64],
    length: float = 4.084, width: float = 1.85, offset: float = 0.0, min_step: float = 1.0,
) -> npt.NDArray[np.uint8]:
    """(N, T, 5) point-in-polygon tests (0 off, 1 on) of the 4 corners then the reference point against the
    union of polygons: vertices xy (V, 2), ring offsets (R+1,) into vertices, polygon offsets (P+1,) into rings
    (first ring exterior, the rest holes)."""

def mask_lookup(
    points: npt.NDArray[np.float64], mask: npt.NDArray[np.uint8], resolution: float = 0.1, foreground: int = 255
) -> npt.NDArray[np.uint8]:
    """(M,) lookups of global points (M, 2) in a MapMask raster: 0 off, 1 on, 2 outside the image."""
