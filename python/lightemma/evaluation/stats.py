"""Uncertainty at the level of scenes: bootstrap intervals, paired sign-flip tests, Holm's adjustment.

Frames of one nuScenes scene are strongly correlated (same road, traffic and
weather for 20 s), so the unit of resampling is the scene: intervals come from
a **cluster bootstrap** (draw as many scenes as there are, with replacement, and
recompute the frame-weighted mean) and p-values from a **sign-flip permutation
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


@dataclass(frozen=True)
class Resampling:
    """How intervals and p-values are resampled (recorded beside every result)."""

    n_resamples: int = 10_000  # bootstrap resamples and sign-flip permutations (0: none)
    seed: int = 0
    confidence: float = 0.95

    def __post_init__(self) -> None:
        if self.n_resamples < 0:
            raise ValueError(f"n_resamples must be 0 (no intervals) or positive, got {self.n_resamples}")
        if not 0.0 < self.confidence < 1.0:
            raise ValueError(f"confidence must lie strictly between 0 and 1, got {self.confidence}")
        if not 0 <= self.seed < 2**64:
            raise ValueError(f"seed must be an integer in [0, 2**64), got {self.seed}")

    def to_dict(self) -> dict[str, Any]:
        return {
            "method": "percentile bootstrap over scenes; sign-flip permutation over scenes",
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
        raise ValueError(f"values must be (N,) or (N, M) and clusters (N,), got {np.shape(values)} and {labels.shape}")
    _, inverse = np.unique(labels, return_inverse=True)
    inverse = inverse.reshape(-1)
    n = int(inverse.max()) + 1 if len(inverse) else 0
    sums = np.stack([np.bincount(inverse, weights=v[:, j], minlength=n) for j in range(v.shape[1])], axis=1) if n else np.zeros((0, v.shape[1]))
    return sums, np.bincount(inverse, minlength=n).astype(np.float64)


def _stack(groups: Sequence[tuple[ArrayLike, ArrayLike]], metrics: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[int]]:
    sums, counts, offsets, n_clusters = [], [], [0], []
    for values, clusters in groups:
        s, c = cluster_sums(values, clusters)
        if metrics is not None and s.shape[1] != metrics:
            raise ValueError(f"expected {metrics} value(s) per frame, got {s.shape[1]}")
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
        raise ValueError(f"{rows} group(s) need {rows} key(s), got {len(keys)}")
    return np.fromiter((stream_id(k) for k in keys), dtype=np.uint64, count=rows)


def bootstrap_ci(groups: Sequence[tuple[ArrayLike, ArrayLike]], keys: Sequence[str], resampling: Resampling = Resampling()) -> np.ndarray:
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
    out = _core.cluster_bootstrap(sums, counts, offsets, _streams(keys, len(n_clusters)), resampling.n_resamples, resampling.seed, resampling.confidence)
    out[np.asarray(n_clusters) < 2] = np.nan
    return out


def sign_flip_p(groups: Sequence[tuple[ArrayLike, ArrayLike]], keys: Sequence[str], resampling: Resampling = Resampling()) -> np.ndarray:
    """Two-sided p-values (R,) of "the mean paired difference is 0", flipping signs of whole scenes.

    ``groups``: per row, (per-frame differences (N,), scene labels (N,)).
    p = (1 + #{flips at least as extreme}) / (1 + n_resamples); NaN for a row
    without frames or when ``resampling.n_resamples`` is 0.
    """
    sums, counts, offsets, n_clusters = _stack(groups, metrics=1)
    if resampling.n_resamples == 0:
        return np.full(len(n_clusters), np.nan)
    return _core.sign_flip_test(sums, counts, offsets, _streams(keys, len(n_clusters)), resampling.n_resamples, resampling.seed)


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
