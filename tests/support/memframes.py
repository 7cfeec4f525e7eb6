"""Small in-memory frames for run tests: the Frame attributes the runner relies on, tiny JPEGs."""

from __future__ import annotations

import base64
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image


@dataclass
class MemFrame:
    frame_id: str
    scene_name: str
    sample_token: str
    image_path: str
    history_actions: np.ndarray
    gt_positions: np.ndarray


def _camera_like(width: int, height: int) -> np.ndarray:
    """A gradient with mild noise: compresses like a CAM_FRONT photo (about 160 KiB at 1600×900)."""
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:height, 0:width]
    base = np.stack([x * 255 // width, y * 255 // height, (x + y) * 255 // (width + height)], -1)
    return np.clip(base + rng.integers(-8, 9, base.shape), 0, 255).astype(np.uint8)


def make_frames(directory: Path, n: int, image_size: tuple[int, int] | None = None) -> list[MemFrame]:
    """``n`` frames over two scenes, each with its own image (so a server can tell them apart).

    Images are 8×8 unless ``image_size`` (width, height) asks for camera-sized ones.
    """
    frames = []
    photo = _camera_like(*image_size) if image_size else None
    for i in range(n):
        path = directory / f"cam{i}.jpg"
        if photo is None:
            Image.new("RGB", (8, 8), (i * 20 % 256, 40, 90)).save(path, quality=95)
        else:
            photo[:8, :8] = i % 256  # a distinct corner per frame
            Image.fromarray(photo).save(path, quality=85)
        history = np.column_stack([np.full(6, 5.0 + 0.5 * i), np.zeros(6)])
        gt = np.column_stack([2.5 * np.arange(1, 7), np.zeros(6)])
        scene = f"scene-{i % 2:04d}"
        frames.append(MemFrame(f"{scene}/token{i:03d}", scene, f"token{i:03d}", str(path), history, gt))
    return frames


class FrameIndex:
    """Which frame a request belongs to, from its image data URL."""

    def __init__(self, frames: list[MemFrame]) -> None:
        self._by_url = {}
        for i, f in enumerate(frames):
            data = base64.b64encode(Path(f.image_path).read_bytes()).decode()
            self._by_url[f"data:image/jpeg;base64,{data}"] = i

    def __call__(self, req) -> int:
        """The frame of an OpenAI-protocol request: its image is the first image part of its turns."""
        parts = (p for m in req.body["messages"] if isinstance(m["content"], list) for p in m["content"])
        url = next(p["image_url"]["url"] for p in parts if p["type"] == "image_url")
        return self._by_url[url]
