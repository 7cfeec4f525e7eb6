"""Uncertainty at the level of scenes: bootstrap intervals, rate intervals, paired sign-flip tests, Holm's adjustment.

Frames of one nuScenes scene are strongly correlated (same road, traffic and
weather for 20 s), so the unit of resampling is the scene: intervals of means
(ADE, FDE) come from a **cluster bootstrap** (draw as many scenes as there are,
with replacement, and recompute the frame-weighted mean), intervals of rates
(off-road, collision) from an exact binomial interval on the scene-clustered
effective sample size (:func:`rate_interval`: a bootstrap of a rate of 0 is
[0, 0]), and p-values from a **sign-flip permutation
test** of scene-level paired differences. The resampling runs in the Rust core
(one call for all rows, all cores, deterministic for a seed). Definitions:
docs/statistics.md.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from lightemma import _core
from lightemma.errors import InputError, ShapeError


@dataclass(frozen=True)
class Resampling:
    """How intervals and p-values are resampled (recorded beside every result)."""

    n_resamples: int = 10_000  # bootstrap resamples and sign-flip permutations (0: none)
    seed: int = 0
    confidence: float = 0.95

    def __post_init__(self) -> None:
        if self.n_resamples < 0:
            raise InputError(f"n_resamples must be 0 (no intervals) or positive, got {self.n_resamples}")
        if not 0.0 < self.confidence < 1.0:
            raise InputError(f"confidence must lie strictly between 0 and 1, got {self.confidence}")
        if not 0 <= self.seed < 2**64:
            raise InputError(f"seed must be an integer in [0, 2**64), got {self.seed}")

    def to_dict(self) -> dict[str, Any]:
        return {
            "method": "percentile bootstrap over scenes; sign-flip permutation over scenes; "
            "rates: Clopper-Pearson on the scene-clustered effective sample size",
            "unit": "scene",
            "n_resamples": self.n_resamples,
            "seed": self.seed,
            "confidence": self.confidence,
        }


def stream_id(key: str) -> int:
    """A stable 64-bit id for ``key`` (e.g. a model label): a row's random numbers depend on it alone."""
    return int.from_bytes(hashlib.blake2b(key.encode("utf-8"), digest_size=8).digest(), "little")


def cluster_sums(values: ArrayLike, clusters: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Per-cluster sums (S, M) of per-frame ``values`` (N,) or (N, M), and frame counts (S,).

    ``clusters`` (N,) labels each frame's scene (any hashable values, e.g. codes
    or names); clusters come out in sorted label order.
    """
    v = np.asarray(values, dtype=np.float64)
    v = v[:, None] if v.ndim == 1 else v
    labels = np.asarray(clusters)
    if v.ndim != 2 or labels.shape != (len(v),):
        raise ShapeError(f"values must be (N,) or (N, M) and clusters (N,), got {np.shape(values)} and {labels.shape}")
    _, inverse = np.unique(labels, return_inverse=True)
    inverse = inverse.reshape(-1)
    n = int(inverse.max()) + 1 if len(inverse) else 0
    sums = (
        np.stack([np.bincount(inverse, weights=v[:, j], minlength=n) for j in range(v.shape[1])], axis=1)
        if n
        else np.zeros((0, v.shape[1]))
    )
    return sums, np.bincount(inverse, minlength=n).astype(np.float64)


def _stack(
    groups: Sequence[tuple[ArrayLike, ArrayLike]], metrics: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[int]]:
    sums, counts, offsets, n_clusters = [], [], [0], []
    for values, clusters in groups:
        s, c = cluster_sums(values, clusters)
        if metrics is not None and s.shape[1] != metrics:
            raise ShapeError(f"expected {metrics} value(s) per frame, got {s.shape[1]}")
        sums.append(s)
        counts.append(c)
        offsets.append(offsets[-1] + len(c))
        n_clusters.append(len(c))
    width = sums[0].shape[1] if sums else (metrics or 1)
    all_sums = np.ascontiguousarray(np.concatenate(sums) if sums else np.zeros((0, width)))
    all_counts = np.concatenate(counts) if counts else np.zeros(0)
    return all_sums, all_counts, np.asarray(offsets, dtype=np.int64), n_clusters


def _streams(keys: Sequence[str], rows: int) -> np.ndarray:
    if len(keys) != rows:
        raise InputError(f"{rows} group(s) need {rows} key(s), got {len(keys)}")
    return np.fromiter((stream_id(k) for k in keys), dtype=np.uint64, count=rows)


def bootstrap_ci(
    groups: Sequence[tuple[ArrayLike, ArrayLike]], keys: Sequence[str], resampling: Resampling = Resampling()
) -> np.ndarray:
    """Scene-bootstrap intervals of frame-weighted means, all groups in one core call.

    ``groups``: per row, (values (N,) or (N, M), scene labels (N,)); values must be
    finite. ``keys``: per row a string that fixes its random numbers (the same key
    and seed give the same interval whatever else is in the call). Returns
    (R, M, 2) (low, high); NaN for a row with fewer than 2 scenes (no interval
    can be drawn from one cluster) or when ``resampling.n_resamples`` is 0.
    """
    sums, counts, offsets, n_clusters = _stack(groups)
    if resampling.n_resamples == 0:
        return np.full((len(n_clusters), sums.shape[1], 2), np.nan)
    out = _core.cluster_bootstrap(
        sums,
        counts,
        offsets,
        _streams(keys, len(n_clusters)),
        resampling.n_resamples,
        resampling.seed,
        resampling.confidence,
    )
    out[np.asarray(n_clusters) < 2] = np.nan
    return out


def rate_interval(values: ArrayLike, clusters: ArrayLike, confidence: float = 0.95) -> tuple[float, float]:
    """Interval (low, high) of a rate — the frame-weighted mean of per-frame ``values`` in [0, 1] — that
    accounts for scene clustering and is never degenerate at 0 or 1 (docs/statistics.md#rates).

    Clopper–Pearson (exact binomial) at ``confidence`` on the effective sample size of Korn and Graubard
    (1998): with n frames in k scenes, rate p = Σ values / n and the scene-level (linearised) variance
    v = k / (k − 1) · Σ_s (S_s − p · n_s)² / n² (S_s, n_s: the scene's sum and frame count), n_eff =
    min(n, p (1 − p) / v) · (t_{n−1} / t_{k−1})² (design effect ≥ 1, then the degrees-of-freedom correction
    for k scenes), at most max(k, j · n / k) where j is the number of scenes with an event (or, when
    fewer, without one): the clustering is measured on those scenes only, so a few events in a few scenes
    give no more than those scenes' worth of frames. x = p · n_eff events: low = Beta⁻¹(α/2; x, n_eff − x + 1)
    (0 at x = 0), high = Beta⁻¹(1 − α/2; x + 1, n_eff − x) (1 at x = n_eff). At p = 0 or 1 the data
    cannot measure how strongly a scene's frames hang together, so the worst case is taken: n_eff = k
    (every scene one observation; the cap above at j = 0) — no event in 24 scenes gives [0, 0.142].

    ``values`` (N,): per-frame values in [0, 1] (1: the frame has the event; ``stp3``/``uniad`` collision
    values are shares of steps); ``clusters`` (N,): scene labels. Returns (NaN, NaN) with fewer than 2
    scenes (as :func:`bootstrap_ci`). Raises ``ValueError`` for values that are not finite numbers in [0, 1],
    mismatched shapes, or a confidence outside (0, 1).
    """
    from scipy.stats import beta, t

    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 1:
        raise ShapeError(f"rate values must be (N,), got shape {v.shape}")
    bad = np.flatnonzero(~np.isfinite(v) | (v < 0.0) | (v > 1.0))
    if len(bad):
        raise InputError(f"rate values must be finite numbers in [0, 1]: value {v[bad[0]]!r} at index {int(bad[0])}")
    if not 0.0 < confidence < 1.0:
        raise InputError(f"confidence must lie strictly between 0 and 1, got {confidence}")
    sums, counts = cluster_sums(v, clusters)
    k, n = len(counts), float(counts.sum())
    if k < 2:
        return (float("nan"), float("nan"))
    total = float(sums[:, 0].sum())
    p = total / n
    alpha = 1.0 - confidence
    if total <= 0.0 or total >= n:
        p = 0.0 if total <= 0.0 else 1.0
        n_eff = float(k)
    else:
        var = k / (k - 1) * float(np.sum((sums[:, 0] - p * counts) ** 2)) / n**2
        n_eff = n if var <= 0.0 else min(n, p * (1.0 - p) / var)
        n_eff *= (t.ppf(1.0 - alpha / 2, n - 1) / t.ppf(1.0 - alpha / 2, k - 1)) ** 2
        # the clustering is measured on the scenes that differ from the rest: no more than theirs to go on
        j = int(min(np.count_nonzero(sums[:, 0] > 0.0), np.count_nonzero(sums[:, 0] < counts)))
        n_eff = min(n_eff, max(float(k), j * n / k))
    x = p * n_eff
    low = 0.0 if x <= 0.0 else float(beta.ppf(alpha / 2, x, n_eff - x + 1.0))
    high = 1.0 if x >= n_eff else float(beta.ppf(1.0 - alpha / 2, x + 1.0, n_eff - x))
    return (low, high)


def rate_ci(groups: Sequence[tuple[ArrayLike, ArrayLike]], resampling: Resampling = Resampling()) -> np.ndarray:
    """:func:`rate_interval` of every group (per row: per-frame values (N,) in [0, 1], scene labels (N,)).

    Returns (R, 1, 2) (low, high), shaped like :func:`bootstrap_ci` with one metric; NaN for a row with
    fewer than 2 scenes or when ``resampling.n_resamples`` is 0 (``--resamples 0``: no intervals). Only
    ``resampling.confidence`` enters: the interval is not resampled, so it needs no seed.
    """
    out = np.full((len(groups), 1, 2), np.nan)
    if resampling.n_resamples == 0:
        return out
    for r, (values, clusters) in enumerate(groups):
        out[r, 0] = rate_interval(values, clusters, resampling.confidence)
    return out


def sign_flip_p(
    groups: Sequence[tuple[ArrayLike, ArrayLike]], keys: Sequence[str], resampling: Resampling = Resampling()
) -> np.ndarray:
    """Two-sided p-values (R,) of "the mean paired difference is 0", flipping signs of whole scenes.

    ``groups``: per row, (per-frame differences (N,), scene labels (N,)).
    p = (1 + #{flips at least as extreme}) / (1 + n_resamples); NaN for a row
    without frames or when ``resampling.n_resamples`` is 0.
    """
    sums, counts, offsets, n_clusters = _stack(groups, metrics=1)
    if resampling.n_resamples == 0:
        return np.full(len(n_clusters), np.nan)
    return _core.sign_flip_test(
        sums, counts, offsets, _streams(keys, len(n_clusters)), resampling.n_resamples, resampling.seed
    )


def holm(p_values: ArrayLike) -> np.ndarray:
    """Holm's step-down adjustment (Holm 1979) of a family of p-values; NaN stays NaN and is not counted.

    adjusted p_(i) = max over j ≤ i of min(1, (m − j + 1) · p_(j)), p sorted ascending;
    reject at level α where the adjusted p is ≤ α (strong control of the family-wise error).
    """
    p = np.asarray(p_values, dtype=np.float64)
    out = np.full(p.shape, np.nan)
    known = np.flatnonzero(np.isfinite(p))
    order = known[np.argsort(p[known], kind="stable")]
    m = len(order)
    scaled = (m - np.arange(m)) * p[order]
    out[order] = np.minimum(1.0, np.maximum.accumulate(scaled))
    return out


def mark_holm(rows: Sequence[dict], confidence: float) -> None:
    """Set each row's ``p_holm`` (Holm over the rows' ``p_value``, None where a row has none) and ``significant``
    (``p_holm`` ≤ 1 − ``confidence``), in place: one family, the rows given (docs/statistics.md)."""
    p_values = [np.nan if r["p_value"] is None else r["p_value"] for r in rows]
    adjusted: np.ndarray | list[float] = holm(p_values) if rows else []
    alpha = 1.0 - confidence
    for row, adj in zip(rows, adjusted):
        row["p_holm"] = None if np.isnan(adj) else float(adj)
        row["significant"] = bool(row["p_holm"] is not None and row["p_holm"] <= alpha)
