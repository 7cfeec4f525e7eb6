"""The synthetic CAM_FRONT: nuScenes-like calibration scaled to the image size."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lightemma.errors import InputError
from lightemma.nuscenes.geometry import quaternion_to_matrix

# a real nuScenes CAM_FRONT calibration (1600 x 900 images)
NUSCENES_SIZE = (1600, 900)
TRANSLATION = (1.70079118954, 0.0159456324149, 1.51095763913)
ROTATION = (0.4998015430569128, -0.5030316162024876, 0.4997798114386805, -0.49737083824542755)
FOCAL = 1266.417203046554
PRINCIPAL = (816.2670197447984, 491.50706579294757)


@dataclass(frozen=True)
class Camera:
    """Pinhole camera with ego-from-camera pose ``translation`` + ``rotation`` (w, x, y, z)."""

    width: int = 800
    height: int = 450
    translation: tuple[float, float, float] = TRANSLATION
    rotation: tuple[float, float, float, float] = ROTATION

    def __post_init__(self) -> None:
        if self.width < 16 or self.height < 16:
            raise InputError(f"image size {self.width}x{self.height} is too small")

    @property
    def intrinsic(self) -> np.ndarray:
        """3x3 intrinsic matrix scaled from the 1600 x 900 calibration."""
        sx = self.width / NUSCENES_SIZE[0]
        sy = self.height / NUSCENES_SIZE[1]
        return np.array([[FOCAL * sx, 0.0, PRINCIPAL[0] * sx], [0.0, FOCAL * sy, PRINCIPAL[1] * sy], [0.0, 0.0, 1.0]])

    def ego_to_cam(self, pts: np.ndarray) -> np.ndarray:
        """Ego-frame points ``(N, 3)`` into camera coordinates (x right, y down, z forward)."""
        r = quaternion_to_matrix(self.rotation)
        return (np.asarray(pts, dtype=np.float64) - np.asarray(self.translation)) @ r

    def project(self, cam: np.ndarray) -> np.ndarray:
        """Camera-space points ``(N, 3)`` (z > 0) to pixels ``(N, 2)``."""
        k = self.intrinsic
        z = cam[:, 2]
        return np.stack([k[0, 0] * cam[:, 0] / z + k[0, 2], k[1, 1] * cam[:, 1] / z + k[1, 2]], axis=-1)
