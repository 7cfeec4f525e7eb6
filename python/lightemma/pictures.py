"""Cameras and stage texts for frame pictures: from the dataset a run was made on, if it can be read.

A run's manifest describes its frame set (dataroot, version, split, scenes,
window); the frames are loaded once per distinct description. When the dataset
is not reachable the pictures are still drawn (bird's-eye view, no image) and
the reason is kept for the report.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from lightemma.evaluation.loading import RunData
from lightemma.figures.frame_view import Camera, camera_from_frame


class CameraSource:
    """Looks up :class:`Camera` objects by frame id, loading each dataset at most once."""

    def __init__(self, dataroot: str | None = None) -> None:
        self.dataroot = dataroot  # overrides the manifests' dataroot when set
        self._frames: dict[str, Any] = {}
        self._loaded: set[str] = set()
        self.problems: list[str] = []

    def _load(self, dataset: Mapping[str, Any] | None) -> None:
        key = repr(sorted((dataset or {}).items()))
        if key in self._loaded:
            return
        self._loaded.add(key)
        dataset = dict(dataset or {})
        dataroot = self.dataroot or dataset.get("dataroot")
        if not dataroot or not dataset.get("version"):
            self.problems.append("a run's manifest names no dataset (dataroot and version); pictures have no camera view")
            return
        try:
            from lightemma import load_frames

            frames = load_frames(dataroot, dataset["version"], split=dataset.get("split"), scenes=dataset.get("scenes"), window=dataset.get("window") or "reference")
        except Exception as exc:  # any dataset problem only costs the camera view  # noqa: BLE001
            self.problems.append(f"could not load the dataset at {dataroot} ({type(exc).__name__}: {exc}); pictures have no camera view")
            return
        for frame in frames:
            self._frames.setdefault(frame.frame_id, frame)

    def cameras(self, runs: Iterable[RunData], frame_ids: Iterable[str]) -> dict[str, Camera | None]:
        """frame id → Camera (or None when its dataset could not be read)."""
        for run in runs:
            self._load(run.info.dataset)
        out: dict[str, Camera | None] = {}
        for fid in frame_ids:
            frame = self._frames.get(fid)
            out[fid] = camera_from_frame(frame) if frame is not None else None
        return out


def stage_texts(record: Mapping[str, Any] | None) -> dict[str, str]:
    """The three stage texts of a record: scene, intent and the stage-3 answer."""
    record = record or {}
    return {"scene": record.get("scene_text") or "", "intent": record.get("intent_text") or "", "answer": record.get("answer") or ""}
