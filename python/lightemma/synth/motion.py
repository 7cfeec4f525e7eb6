"""Closed-form motion: piecewise-constant acceleration along a piecewise-constant-curvature path.

A :class:`SpeedProfile` gives arc length s(t) and speed v(t) exactly; a
:class:`Path` gives the planar pose (x, y, yaw) and curvature at arc length s
exactly (straight lines and circular arcs). Composed, they are the "truth"
that synthetic scenes are generated from and that tests check frames against.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lightemma.errors import InputError


@dataclass(frozen=True)
class SpeedProfile:
    """Speed from ``v0`` through phases of constant acceleration ``(duration s, accel m/s²)``.

    After the last phase the speed stays constant. Phases must never make the
    speed negative (a braking phase should last exactly ``v / a``).
    """

    v0: float
    phases: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        v = self.v0
        if v < 0:
            raise InputError(f"initial speed {v} < 0")
        for duration, accel in self.phases:
            if duration < 0:
                raise InputError(f"phase duration {duration} < 0")
            v += accel * duration
            if v < -1e-9:
                raise InputError(f"speed profile goes negative ({v})")

    def _breaks(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        t, s, v = 0.0, 0.0, float(self.v0)
        ts, ss, vs, accs = [], [], [], []
        for duration, accel in self.phases:
            ts.append(t)
            ss.append(s)
            vs.append(v)
            accs.append(accel)
            s += v * duration + 0.5 * accel * duration**2
            v = max(0.0, v + accel * duration)
            t += duration
        ts.append(t)
        ss.append(s)
        vs.append(v)
        accs.append(0.0)
        return np.array(ts), np.array(ss), np.array(vs), np.array(accs)

    def s(self, t) -> np.ndarray:
        """Arc length travelled by time ``t`` (s ≥ 0; before t = 0 the start speed is extrapolated)."""
        t = np.asarray(t, dtype=np.float64)
        ts, ss, vs, accs = self._breaks()
        i = _piece(ts, t)
        tau = t - ts[i]
        a = np.where(tau < 0, 0.0, accs[i])
        return ss[i] + vs[i] * tau + 0.5 * a * tau**2

    def v(self, t) -> np.ndarray:
        """Speed at time ``t``."""
        t = np.asarray(t, dtype=np.float64)
        ts, _, vs, accs = self._breaks()
        i = _piece(ts, t)
        tau = t - ts[i]
        a = np.where(tau < 0, 0.0, accs[i])
        return np.maximum(vs[i] + a * tau, 0.0)

    def a(self, t) -> np.ndarray:
        """Acceleration at time ``t``."""
        t = np.asarray(t, dtype=np.float64)
        ts, _, _, accs = self._breaks()
        i = _piece(ts, t)
        return np.where(t < 0, 0.0, accs[i])


@dataclass(frozen=True)
class Path:
    """A planar path from pose ``(x0, y0, yaw0)`` through segments ``(length m, curvature 1/m)``.

    Curvature is positive to the left. Before s = 0 and after the last
    segment the path continues straight.
    """

    x0: float
    y0: float
    yaw0: float
    segments: tuple[tuple[float, float], ...] = ()

    def _starts(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        s, x, y, yaw = 0.0, self.x0, self.y0, self.yaw0
        ss, xs, ys, yaws, ks = [], [], [], [], []
        for length, k in self.segments:
            ss.append(s)
            xs.append(x)
            ys.append(y)
            yaws.append(yaw)
            ks.append(k)
            x, y, yaw = _advance(x, y, yaw, k, length)
            s += length
        ss.append(s)
        xs.append(x)
        ys.append(y)
        yaws.append(yaw)
        ks.append(0.0)
        return np.array(ss), np.array(xs), np.array(ys), np.array(yaws), np.array(ks)

    def pose(self, s) -> np.ndarray:
        """``(..., 3)`` array of (x, y, yaw) at arc length(s) ``s``."""
        s = np.asarray(s, dtype=np.float64)
        ss, xs, ys, yaws, ks = self._starts()
        i = _piece(ss, s)
        ds = s - ss[i]
        k = np.where(s < 0, 0.0, ks[i])
        x, y, yaw = _advance(xs[i], ys[i], yaws[i], k, ds)
        return np.stack([x, y, yaw], axis=-1)

    def curvature(self, s) -> np.ndarray:
        """Curvature at arc length(s) ``s`` (the segment's constant curvature)."""
        s = np.asarray(s, dtype=np.float64)
        ss, _, _, _, ks = self._starts()
        i = _piece(ss, s)
        return np.where(s < 0, 0.0, ks[i])

    @property
    def length(self) -> float:
        """Total length of the explicit segments."""
        return float(sum(length for length, _ in self.segments))


def _piece(starts: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Index of the piece (phase or segment) holding each ``x``, given the pieces' sorted ``starts``.

    Before the first start this is the first piece, after the last start the last one.
    """
    return np.clip(np.searchsorted(starts, x, side="right") - 1, 0, len(starts) - 1)


def _advance(x, y, yaw, k, ds):
    """Exact pose after arc length ``ds`` on a constant-curvature ``k`` curve (vectorised)."""
    x, y, yaw, k, ds = (np.asarray(v, dtype=np.float64) for v in (x, y, yaw, k, ds))
    straight = k == 0.0
    safe_k = np.where(straight, 1.0, k)
    yaw1 = yaw + k * ds
    x_arc = x + (np.sin(yaw1) - np.sin(yaw)) / safe_k
    y_arc = y - (np.cos(yaw1) - np.cos(yaw)) / safe_k
    x_new = np.where(straight, x + ds * np.cos(yaw), x_arc)
    y_new = np.where(straight, y + ds * np.sin(yaw), y_arc)
    return x_new, y_new, yaw1
