"""Displacement errors and ADE/FDE under the three conventions (docs/definitions.md#metrics)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, cast

import numpy as np
import numpy.typing as npt
from numpy.typing import ArrayLike

from lightemma import _core
from lightemma._arrays import as_frames, as_mask
from lightemma.definitions import CONVENTIONS as CONVENTIONS  # re-exported: lightemma.CONVENTIONS
from lightemma.errors import ShapeError

if TYPE_CHECKING:
    from lightemma._core import _Convention


@dataclass(frozen=True)
class Metrics:
    """Frame-weighted means over the evaluated frames, in metres (miss rate as a share).

    ``convention`` says how ``ade_1s``/``ade_2s``/``ade_3s`` are defined:
    ``lightemma`` (the paper's table: mean(e1, e2), mean(e3, e4), mean(e5, e6)),
    ``stp3`` (mean over the horizon up to that second) or ``uniad`` (e2, e4, e6).
    ``ade_avg`` is the convention's own average: mean(e1..e6) under ``lightemma``
    (equal to the mean of its three columns), the mean of the three columns under
    ``stp3`` and ``uniad`` (as those papers print "Avg."). ``fde`` = e6,
    ``miss_rate`` = share of frames whose largest error exceeds ``miss_threshold``.
    """

    ade_1s: float
    ade_2s: float
    ade_3s: float
    ade_avg: float
    fde: float
    miss_rate: float
    n_frames: int
    convention: str = "lightemma"
    miss_threshold: float = 2.0

    def to_dict(self) -> dict[str, float | int | str]:
        return asdict(self)


def _pair(pred: ArrayLike, gt: ArrayLike) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], bool]:
    p, single_p = as_frames(pred, "pred")
    g, single_g = as_frames(gt, "gt")
    if p.shape != g.shape:
        shown_p = p.shape[1:] if single_p else p.shape
        shown_g = g.shape[1:] if single_g else g.shape
        raise ShapeError(f"pred has shape {shown_p} but gt has shape {shown_g}; they must match")
    return p, g, single_p and single_g


def displacement_errors(pred: ArrayLike, gt: ArrayLike) -> npt.NDArray[np.float64]:
    """Euclidean error per frame and step: (N, T, 2) × 2 → (N, T); (T, 2) × 2 → (T,).

    NaN in ``pred`` or ``gt`` (a failed parse) gives NaN errors for that step; nothing is
    checked or averaged here, so no mask is needed.

    >>> import lightemma
    >>> lightemma.displacement_errors([[3.0, 4.0]], [[0.0, 0.0]]).tolist()
    [5.0]
    """
    p, g, single = _pair(pred, gt)
    out = _core.displacement_errors(p, g)
    return out[0] if single else out


def evaluate(
    pred: ArrayLike,
    gt: ArrayLike,
    *,
    convention: str = "lightemma",
    miss_threshold: float = 2.0,
    mask: ArrayLike | None = None,
) -> Metrics:
    """Score predicted trajectories (N, 6, 2) against ground truth (N, 6, 2).

    ``mask``: optional boolean array (N,); only frames marked ``True`` are checked and
    scored, and ``n_frames`` counts them. Pass ``parsed.ok`` to leave out answers that
    failed to parse (their actions, and so their trajectories, are NaN).

    Raises ``ValueError`` naming the frame (its index in the batch) and step of any
    NaN/inf in a scored frame, and for an empty batch (or a mask that keeps no frame),
    mismatched shapes, a mask that is not boolean (N,), or an unknown convention.
    Definitions: docs/definitions.md#metrics.

    >>> import numpy as np, lightemma
    >>> gt = np.zeros((2, 6, 2)); pred = gt + [0.0, 1.0]; pred[1] = np.nan
    >>> lightemma.evaluate(pred, gt, mask=[True, False]).ade_avg
    1.0
    """
    p, g, single = _pair(pred, gt)
    m = None if mask is None else as_mask(mask, p.shape[0], single)
    # the core checks the convention is one of CONVENTIONS (UnknownNameError naming them)
    values = _core.evaluate(p, g, cast("_Convention", convention), float(miss_threshold), m)
    return Metrics(*values, convention=convention, miss_threshold=float(miss_threshold))


def evaluate_all(
    pred: ArrayLike,
    gt: ArrayLike,
    *,
    miss_threshold: float = 2.0,
    mask: ArrayLike | None = None,
) -> dict[str, Metrics]:
    """:func:`evaluate` under every convention of :data:`CONVENTIONS`, in one call: ``{convention: Metrics}``.

    The errors of each frame are computed once and aggregated three ways; the
    numbers are identical, bit for bit, to three :func:`evaluate` calls (and so
    are the errors raised). Definitions: docs/definitions.md#metrics.

    >>> import numpy as np, lightemma
    >>> gt = np.zeros((1, 6, 2)); pred = gt.copy(); pred[0, :, 1] = [1, 2, 3, 4, 5, 6]
    >>> {c: m.ade_1s for c, m in evaluate_all(pred, gt).items()}
    {'lightemma': 1.5, 'stp3': 1.5, 'uniad': 2.0}
    """
    p, g, single = _pair(pred, gt)
    m = None if mask is None else as_mask(mask, p.shape[0], single)
    rows = _core.evaluate_all(p, g, float(miss_threshold), m)
    return {
        c: Metrics(*values, convention=c, miss_threshold=float(miss_threshold)) for c, values in zip(CONVENTIONS, rows)
    }


FRAME_METRICS: tuple[str, ...] = ("ade_1s", "ade_2s", "ade_3s", "ade_avg", "fde")


def frame_metrics(pred: ArrayLike, gt: ArrayLike, *, convention: str = "lightemma") -> npt.NDArray[np.float64]:
    """Per-frame values (N, 5) — the columns of :data:`FRAME_METRICS` — whose means :func:`evaluate` returns.

    Used for intervals and paired comparisons, which need one value per frame.
    Raises ``ValueError`` like :func:`evaluate`; an empty batch gives shape (0, 5).

    >>> import numpy as np
    >>> gt = np.zeros((1, 6, 2)); pred = gt + [0.0, 1.0]
    >>> frame_metrics(pred, gt).tolist()
    [[1.0, 1.0, 1.0, 1.0, 1.0]]
    """
    p, g, _ = _pair(pred, gt)
    return _core.frame_metrics(p, g, cast("_Convention", convention))  # the core checks the convention
