"""Integrating (speed, curvature) actions into trajectories (docs/definitions.md#integration)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from lightemma import _core
from lightemma._arrays import as_frames

METHODS: tuple[str, ...] = tuple(_core.METHODS)


def integrate(actions: ArrayLike, *, dt: float = 0.5, method: str = "euler") -> np.ndarray:
    """Integrate (speed, curvature) actions from the origin, heading along +x.

    Args:
        actions: (N, T, 2) or (T, 2) array of (speed m/s, curvature 1/m).
        dt: seconds per action (0.5 in nuScenes).
        method: ``"euler"`` (the paper's equations 1–3: x += v cos θ dt,
            y += v sin θ dt, then θ += κ v dt) or ``"midpoint"`` (move along the
            heading at mid-step; removes Euler's bias on arcs).

    Returns:
        Positions after each step (origin excluded), same shape as ``actions``.
        NaN actions (failed parses) give NaN positions.

    >>> import lightemma
    >>> lightemma.integrate([[2.0, 0.0], [2.0, 0.0]]).tolist()
    [[1.0, 0.0], [2.0, 0.0]]
    """
    array, single = as_frames(actions, "actions")
    out = _core.integrate(array, float(dt), method)
    return out[0] if single else out
