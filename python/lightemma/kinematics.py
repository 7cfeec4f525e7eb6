"""Integrating (speed, curvature) actions into trajectories (docs/definitions.md#integration)."""

from __future__ import annotations

from typing import TYPE_CHECKING, cast

import numpy as np
import numpy.typing as npt
from numpy.typing import ArrayLike

from lightemma import _core
from lightemma._arrays import as_frames
from lightemma.definitions import STEP_SECONDS
from lightemma.errors import ShapeError

if TYPE_CHECKING:
    from lightemma._core import _Method


def integrate(
    actions: ArrayLike,
    *,
    dt: float = STEP_SECONDS,
    method: str = "euler",
    out: npt.NDArray[np.float64] | None = None,
) -> npt.NDArray[np.float64]:
    """Integrate (speed, curvature) actions from the origin, heading along +x.

    Args:
        actions: (N, T, 2) or (T, 2) array of (speed m/s, curvature 1/m).
        dt: seconds per action (:data:`lightemma.definitions.STEP_SECONDS`, 0.5 in nuScenes).
        method: ``"euler"`` (the paper's equations 1–3: x += v cos θ dt,
            y += v sin θ dt, then θ += κ v dt) or ``"midpoint"`` (move along the
            heading at mid-step; removes Euler's bias on arcs).

        out: optional C-contiguous float64 array of the shape of ``actions`` (N, T, 2) to write the
            positions into (and return), e.g. one buffer reused across calls at large N; it must not
            share memory with ``actions``. :class:`~lightemma.errors.ShapeError` for another shape, dtype or layout.

    Returns:
        Positions after each step (origin excluded), same shape as ``actions``
        (``out`` itself when given). NaN actions (failed parses) give NaN positions.

    >>> import lightemma
    >>> lightemma.integrate([[2.0, 0.0], [2.0, 0.0]]).tolist()
    [[1.0, 0.0], [2.0, 0.0]]
    """
    array, single = as_frames(actions, "actions")
    core_method = cast("_Method", method)  # the core checks it is one of METHODS (UnknownNameError naming them)
    if out is not None:
        if single or not isinstance(out, np.ndarray) or out.dtype != np.float64 or out.ndim != 3:
            raise ShapeError("out must be a float64 array of shape (N, T, 2), for (N, T, 2) actions")
        return _core.integrate(array, float(dt), core_method, out)
    result = _core.integrate(array, float(dt), core_method)
    return result[0] if single else result
