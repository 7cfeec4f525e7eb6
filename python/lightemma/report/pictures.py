"""Cameras and stage texts for frame pictures: from the dataset a run was made on, if it can be read.

A run's manifest describes its frame set (dataroot, version, split, scenes,
window); the frames are loaded once per distinct description. When the dataset
is not reachable the pictures are still drawn (bird's-eye view, no image) and
the reason is kept for the report.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from lightemma._text import printable
from lightemma.evaluation.loading import RunData, read_frame_records
from lightemma.nuscenes import load_frames
from lightemma.nuscenes.geometry import extrinsic_matrix
from lightemma.report.figures.frame_view import Camera, camera_from_frame, load_image


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
            self.problems.append(
                "a run's manifest names no dataset (dataroot and version); pictures have no camera view"
            )
            return
        try:
            frames = load_frames(
                dataroot,
                dataset["version"],
                split=dataset.get("split"),
                scenes=dataset.get("scenes"),
                window=dataset.get("window") or "reference",
            )
        except Exception as exc:  # any dataset problem only costs the camera view  # noqa: BLE001
            self.problems.append(
                f"could not load the dataset at {dataroot} ({type(exc).__name__}: {exc}); pictures have no camera view"
            )
            return
        for frame in frames:
            self._frames.setdefault(frame.frame_id, frame)

    def cameras(
        self,
        runs: Iterable[RunData],
        frame_ids: Iterable[str],
        *,
        load: bool = True,
        records: Mapping[str, Mapping[str, Any]] | None = None,
    ) -> dict[str, Camera | None]:
        """frame id → Camera (or None when its dataset could not be read).

        Imported runs carry each frame's calibration and image name in their
        records; their images are looked for under ``dataroot``
        (``samples/CAM_FRONT/<image name>``), else at the path the reference stored.
        With ``load=False`` no image is decoded (each Camera has its ``path``); ``records`` (frame id →
        its ``camera_params``, ``image_name``, ``image_path``) spares reading imported runs again.
        """
        frame_ids = list(frame_ids)
        out: dict[str, Camera | None] = {}
        for run in runs:
            if run.info.imported:
                wanted = [fid for fid in frame_ids if out.get(fid) is None]
                found = (
                    {fid: records[fid] for fid in wanted if fid in records}
                    if records is not None
                    else read_frame_records(run.info.run_dir, wanted)
                )
                for fid, record in found.items():
                    out[fid] = self._from_record(record, load=load)
            else:
                self._load(run.info.dataset)
        for fid in frame_ids:
            frame = self._frames.get(fid)
            if frame is not None:
                out[fid] = camera_from_frame(frame, load=load)
            out.setdefault(fid, None)
        return out

    def _from_record(self, record: Mapping[str, Any], *, load: bool = True) -> Camera | None:
        """The camera of an imported record (calibration as the reference stored it), or None."""
        params = record.get("camera_params")
        if not isinstance(params, Mapping):
            return None
        candidates = []
        if self.dataroot and record.get("image_name"):
            candidates.append(Path(self.dataroot) / "samples" / "CAM_FRONT" / str(record["image_name"]))
        if record.get("image_path"):
            candidates.append(Path(str(record["image_path"])))
        path = next((c for c in candidates if c.is_file()), None)
        if path is None:
            self.problems.append(
                "images of imported runs not found; pass --dataroot (the nuScenes folder holding samples/CAM_FRONT)"
            )
        return Camera(
            image=load_image(path) if load else None,
            intrinsic=np.asarray(params["camera_intrinsic"], dtype=np.float64),
            extrinsic=extrinsic_matrix(params["translation"], params["rotation"]),
            path=path,
        )


def visible_lines(text: Any) -> str:
    """A model's text as it may be shown: its lines kept, every other control or bidirectional character a visible
    escape (:func:`~lightemma._text.printable` per line: an ESC is no SVG text, a right-to-left override no reorder)."""
    return "\n".join(printable(line) for line in str(text).split("\n"))


def stage_texts(record: Mapping[str, Any] | None) -> dict[str, str]:
    """The three stage texts of a record: scene, intent and the stage-3 answer (:func:`visible_lines`)."""
    record = record or {}
    return {
        key: visible_lines(record.get(field) or "")
        for key, field in (("scene", "scene_text"), ("intent", "intent_text"), ("answer", "answer"))
    }
