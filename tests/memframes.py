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


def make_frames(directory: Path, n: int) -> list[MemFrame]:
    """``n`` frames over two scenes, each with its own image (so a server can tell them apart)."""
    frames = []
    for i in range(n):
        path = directory / f"cam{i}.jpg"
        Image.new("RGB", (8, 8), (i * 20 % 256, 40, 90)).save(path, quality=95)
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
        content = req.body["messages"][-1]["content"]
        url = next(p["image_url"]["url"] for p in content if p["type"] == "image_url")
        return self._by_url[url]

