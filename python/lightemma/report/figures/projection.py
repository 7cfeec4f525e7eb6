"""Project ego-frame ground points into the CAM_FRONT image (pinhole, nuScenes calibration).

Trajectories live in the ego frame of the current keyframe: x forward, y left,
z up, origin on the ground at the rear axle. The camera extrinsic is
ego-from-camera (4×4); the intrinsic is the 3×3 pinhole matrix.
"""

from __future__ import annotations

import numpy as np

MIN_DEPTH = 0.1  # metres in front of the camera; points closer or behind are dropped


def ego_to_camera(points: np.ndarray, extrinsic: np.ndarray, *, z: float = 0.0) -> np.ndarray:
    """(N, 2) ego ground points (or (N, 3)) → (N, 3) points in the camera frame."""
    points = np.asarray(points, dtype=np.float64)
    if points.shape[-1] == 2:
        points = np.concatenate([points, np.full((len(points), 1), z)], axis=1)
    cam_from_ego = np.linalg.inv(np.asarray(extrinsic, dtype=np.float64))
    homogeneous = np.concatenate([points, np.ones((len(points), 1))], axis=1)
    return (homogeneous @ cam_from_ego.T)[:, :3]


def project(points: np.ndarray, intrinsic: np.ndarray, extrinsic: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (N, 2) of ego ground points and a mask of those in front of the camera."""
    cam = ego_to_camera(points, extrinsic)
    visible = cam[:, 2] > MIN_DEPTH
    uvw = cam @ np.asarray(intrinsic, dtype=np.float64).T
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = uvw[:, :2] / uvw[:, 2:3]
    uv[~visible] = np.nan
    return uv, visible


def densify(trajectory: np.ndarray, *, steps: int = 8, origin: bool = True) -> np.ndarray:
    """The trajectory as a finely sampled polyline (from the origin), so that clipping is smooth."""
    points = np.asarray(trajectory, dtype=np.float64)
    if origin:
        points = np.concatenate([np.zeros((1, 2)), points], axis=0)
    t = np.linspace(0.0, len(points) - 1, (len(points) - 1) * steps + 1)
    return np.stack([np.interp(t, np.arange(len(points)), points[:, i]) for i in range(2)], axis=1)
