"""Type stubs for the compiled module ``lightemma._core`` (private; use ``lightemma``)."""

import numpy as np
import numpy.typing as npt

__version__: str
METHODS: list[str]
CONVENTIONS: list[str]
PARSE_MODES: list[str]  # strict, lenient, paper, json
PARSE_FAILURES: list[str]  # failure codes 0..3: "", truncated, implausible, format

def parse_actions(
    texts: list[str],
    n: int = 6,
    mode: str = "lenient",
    speed_range: tuple[float, float] | None = (-10.0, 50.0),
    max_abs_curvature: float | None = 1.0,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.uint8], npt.NDArray[np.uint8], list[str]]:
    """Parse answers: actions (N, n, 2) with NaN where failed, status codes (0 ok, 1 corrected, 2 failed),
    failure codes (indices into PARSE_FAILURES), reasons. Non-str items and bad limits raise ValueError."""

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
