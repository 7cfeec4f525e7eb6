"""Closed-form frame geometry (docs/definitions.md#frames-and-windows): yaw, ego-frame transform, actions.

Everything here is vectorised NumPy over a leading batch axis, so the loader
can compute all frames of a dataset in a handful of array operations.

Conventions: positions are (x, y) metres; the ego frame of a keyframe has its
origin at the ego position, x forward, y left; yaw is counter-clockwise from
the global +x axis; curvature is positive for a left (counter-clockwise) turn.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from lightemma.errors import InputError, ShapeError

#: the paper's post-processing thresholds of the history (docs/definitions.md#history)
SPEED_ZERO_BELOW = 0.2  # m/s: speeds strictly below are set to 0
CURVATURE_ZERO_ABOVE = 0.2  # 1/m: |curvature| strictly above is set to 0 (zeroed, not clipped)
ROUND_DECIMALS = 3


#: largest allowed deviation of a rotation quaternion's norm from 1 (|‖q‖ − 1|): nuScenes stores unit
#: quaternions to ~1e-15; 1e-5 also admits quaternions written in float32 or to 6 decimals, and refuses
#: anything that is visibly not a rotation (a scaled, truncated or zero quaternion). One rule for every
#: reader of nuScenes rotations: the frame reader (ego_pose, calibrated_sensor) and the safety metrics
#: (ego_pose, sample_annotation), docs/definitions.md#frames-and-windows and #safety.
QUATERNION_TOLERANCE = 1e-5

#: global coordinates (m) beyond ± this are refused by every reader: ego pose and annotation x, y, map nodes
#: (nuScenes' maps span under 4 km; a larger value is a corrupt record, not a place)
MAX_COORDINATE_M = 1e6

#: an ego pose whose implied speed from the keyframe before it exceeds this is physically impossible for a
#: car on a city street (252 km/h), metres per second (docs/definitions.md#safety, "Pose jumps"): it is
#: flagged, not corrected
POSE_JUMP_SPEED = 70.0


def unit_quaternion(values: object) -> np.ndarray:
    """``values`` as a unit quaternion ``(w, x, y, z)`` (4,), renormalised.

    The rule of every nuScenes rotation lightemma reads: exactly 4 finite numbers (bools and text refused)
    whose norm is within :data:`QUATERNION_TOLERANCE` of 1. Raises ``ValueError`` saying what is wrong (the
    caller names the file, table and token). A nuScenes quaternion that is not a unit one is a corrupt
    record: the yaw formula misreads it (30° scaled by 2 reads as 76.9°), and silently normalising it would
    hide the corruption.
    """
    numbers = (int, float, np.floating, np.integer)
    if (
        not isinstance(values, (list, tuple, np.ndarray))
        or len(values) != 4
        or not all(isinstance(v, numbers) and not isinstance(v, (bool, np.bool_)) for v in values)
    ):
        raise InputError("is not a list of 4 numbers (a quaternion w, x, y, z)")
    try:
        q = np.asarray([float(v) for v in values], dtype=np.float64)
    except OverflowError:
        raise InputError("is not finite") from None
    if not np.isfinite(q).all():
        raise InputError("is not finite")
    norm = float(np.linalg.norm(q))
    if not abs(norm - 1.0) <= QUATERNION_TOLERANCE:
        raise InputError(f"is not a unit quaternion (norm {norm:.6g}; allowed |norm - 1| <= {QUATERNION_TOLERANCE:g})")
    return q / norm


def pose_jumps(
    xy: np.ndarray, timestamps_us: np.ndarray, max_speed: float = POSE_JUMP_SPEED
) -> list[tuple[int, float, float]]:
    """Physically impossible moves between consecutive keyframes of one scene.

    ``xy`` (N, 2) global positions (m), ``timestamps_us`` (N,) strictly increasing µs. Returns
    ``(k, distance m, seconds)`` for each keyframe ``k`` ≥ 1 whose implied speed from keyframe ``k − 1``
    exceeds ``max_speed`` (m/s); empty when there is none.
    """
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    t = np.asarray(timestamps_us, dtype=np.int64).reshape(-1)
    if len(xy) < 2:
        return []
    dist = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    dt = np.diff(t).astype(np.float64) * 1e-6
    with np.errstate(divide="ignore", invalid="ignore"):
        speed = np.where(dt > 0, dist / np.where(dt > 0, dt, 1.0), np.inf)
    return [(int(k) + 1, float(dist[k]), float(dt[k])) for k in np.flatnonzero(speed > max_speed)]


def yaw_from_quaternion(q: np.ndarray) -> np.ndarray:
    """Yaw of quaternion(s) ``(w, x, y, z)``: ``atan2(2(wz + xy), 1 - 2(y² + z²))``.

    ``q`` has shape ``(..., 4)``; the result has shape ``(...)``.
    """
    q = np.asarray(q, dtype=np.float64)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def quaternion_to_matrix(q: ArrayLike) -> np.ndarray:
    """3x3 rotation matrix of a unit quaternion ``(w, x, y, z)`` (normalised first)."""
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q)
    if not np.isfinite(n) or n == 0.0:
        raise InputError(f"quaternion {q.tolist()} has no rotation (norm {n})")
    w, x, y, z = q / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def extrinsic_matrix(translation, rotation) -> np.ndarray:
    """4x4 ego-from-sensor transform from a ``calibrated_sensor`` translation + quaternion."""
    m = np.eye(4)
    m[:3, :3] = quaternion_to_matrix(rotation)
    m[:3, 3] = np.asarray(translation, dtype=np.float64)[:3]
    return m


def to_ego_frame(points: np.ndarray, origin: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Global ``points`` ``(B, T, 2)`` into the ego frames given by ``origin`` ``(B, 2)``, ``yaw`` ``(B,)``.

    Subtract the origin, then rotate by ``-yaw``.
    """
    d = points - origin[:, None, :]
    c = np.cos(yaw)[:, None]
    s = np.sin(yaw)[:, None]
    x = c * d[..., 0] + s * d[..., 1]
    y = -s * d[..., 0] + c * d[..., 1]
    return np.stack([x, y], axis=-1)


def segment_speeds(points: np.ndarray, timestamps_us: np.ndarray) -> np.ndarray:
    """Speeds of consecutive segments: ``|p[k+1] - p[k]| / ((t[k+1] - t[k]) · 1e-6)``.

    ``points`` ``(B, T, 2)``, ``timestamps_us`` ``(B, T)`` (integer µs) → ``(B, T-1)``.
    Timestamps must strictly increase.
    """
    dist = np.linalg.norm(np.diff(points, axis=1), axis=-1)
    dt = np.diff(np.asarray(timestamps_us, dtype=np.int64), axis=1).astype(np.float64) * 1e-6
    return dist / dt


def menger_curvature(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Signed three-point (Menger) curvature ``4·A / (|ab|·|bc|·|ca|)`` of triangles ``(a, b, c)``.

    ``A`` is the signed area, positive when ``a → b → c`` turns left
    (counter-clockwise). Zero where the side-length product is zero.
    Inputs have shape ``(..., 2)``; the output has shape ``(...)``.
    """
    ab = b - a
    ac = c - a
    cross = ab[..., 0] * ac[..., 1] - ab[..., 1] * ac[..., 0]  # = 2·A
    prod = np.linalg.norm(ab, axis=-1) * np.linalg.norm(c - b, axis=-1) * np.linalg.norm(ac, axis=-1)
    out = np.zeros(np.broadcast(cross, prod).shape)
    nz = prod != 0.0
    out[nz] = 2.0 * cross[nz] / prod[nz]
    return out


def raw_actions(points: np.ndarray, timestamps_us: np.ndarray) -> np.ndarray:
    """Six (speed, curvature) actions from eight consecutive positions.

    ``points`` ``(B, 8, 2)`` are ``p_0 … p_7`` and ``timestamps_us`` ``(B, 8)``.
    Action ``k`` (k = 1..6) is the speed of the segment ``p_k → p_{k+1}`` and the
    Menger curvature of ``(p_{k-1}, p_k, p_{k+1})``, both centred on keyframe ``k``.
    With ``p_0 … p_7 = p_{c-7} … p_c`` these are the history actions (docs/definitions.md#history);
    with ``p_{c-1} … p_{c+6}`` the ground-truth (future) actions.
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 3 or points.shape[1:] != (8, 2):
        raise ShapeError(f"expected points of shape (B, 8, 2), got {points.shape}")
    speeds = segment_speeds(points[:, 1:], np.asarray(timestamps_us)[:, 1:])
    curv = menger_curvature(points[:, :-2], points[:, 1:-1], points[:, 2:])
    return np.stack([speeds, curv], axis=-1)


def round_like_python(values: np.ndarray, ndigits: int = ROUND_DECIMALS) -> np.ndarray:
    """Element-wise Python ``round(x, ndigits)`` (correctly rounded, unlike ``np.round``); ``-0.0`` → ``0.0``."""
    arr = np.asarray(values, dtype=np.float64)
    flat = [round(v, ndigits) for v in arr.ravel().tolist()]
    return np.asarray(flat, dtype=np.float64).reshape(arr.shape) + 0.0


def postprocess_reference(actions: np.ndarray) -> np.ndarray:
    """The paper's post-processing (docs/definitions.md#history) of ``(..., 2)`` (speed, curvature) actions.

    Speed < 0.2 m/s → 0; |curvature| > 0.2 → 0 (zeroed, not clipped); both
    thresholds apply to the unrounded values, then both are rounded to three
    decimals exactly as Python's ``round(x, 3)`` does.
    """
    a = np.array(actions, dtype=np.float64, copy=True)
    speed = a[..., 0]
    curv = a[..., 1]
    speed[speed < SPEED_ZERO_BELOW] = 0.0
    curv[np.abs(curv) > CURVATURE_ZERO_ABOVE] = 0.0
    return round_like_python(a)
