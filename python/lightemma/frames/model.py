"""Frame and FrameSet: the frames a run predicts on (docs/definitions.md#frames-and-windows)."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lightemma.errors import DatasetError, InputError, ShapeError

SYNTH_MARKER = "lightemma-synth.json"  # written by lightemma.synth at the root of a synthetic dataset


@dataclass(frozen=True, eq=False)
class Frame:
    """One nuScenes keyframe at which a model predicts.

    Positions are in the ego frame of this keyframe (x forward, y left, metres);
    actions are (speed m/s, curvature 1/m) pairs at 0.5 s spacing, most recent
    last. ``history_actions`` are post-processed as docs/definitions.md#history says:
    action k (k = 1..6) is the speed of segment c−7+k → c−6+k and the curvature
    of (c−8+k, c−7+k, c−6+k). ``gt_actions`` are the raw (unthresholded,
    unrounded) future actions by the same formulas shifted to the future: speed
    of segment c+k−1 → c+k, curvature of (c+k−2, c+k−1, c+k); analysis only,
    never scored.
    """

    frame_id: str
    scene_name: str
    scene_token: str
    sample_token: str
    keyframe_index: int
    timestamp: int
    image_path: str
    camera_intrinsic: np.ndarray  # (3, 3)
    camera_extrinsic: np.ndarray  # (4, 4) ego-from-camera
    ego_pose: np.ndarray  # (3,) global x, y, yaw
    history_positions: np.ndarray  # (8, 2): p_{c-7} … p_c
    history_actions: np.ndarray  # (6, 2)
    gt_positions: np.ndarray  # (6, 2): p_{c+1} … p_{c+6}
    gt_actions: np.ndarray  # (6, 2)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict (arrays as nested lists of floats)."""
        out: dict[str, Any] = {}
        for name in self.__dataclass_fields__:
            value = getattr(self, name)
            out[name] = value.tolist() if isinstance(value, np.ndarray) else value
        return out


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class FrameSet:
    """An ordered, immutable collection of frames with stacked arrays.

    Order is deterministic: scenes sorted by name, then keyframe order.
    ``fs[i]`` builds the i-th :class:`Frame`; iteration yields them in order.
    Stacked arrays (read-only): ``history_actions`` (N, 6, 2),
    ``history_positions`` (N, 8, 2), ``gt_positions`` (N, 6, 2),
    ``gt_actions`` (N, 6, 2), ``ego_poses`` (N, 3), ``timestamps`` (N,),
    ``camera_intrinsics`` (N, 3, 3), ``camera_extrinsics`` (N, 4, 4).
    """

    frame_ids: list[str]
    scene_names: list[str]
    scene_tokens: list[str]
    sample_tokens: list[str]
    keyframe_indices: np.ndarray
    timestamps: np.ndarray
    image_paths: list[str]
    camera_intrinsics: np.ndarray
    camera_extrinsics: np.ndarray
    ego_poses: np.ndarray
    history_positions: np.ndarray
    history_actions: np.ndarray
    gt_positions: np.ndarray
    gt_actions: np.ndarray
    dataroot: str = ""
    version: str = ""
    split: str | None = None
    scenes: list[str] = field(default_factory=list)
    window: str = "reference"
    missing_images: list[str] = field(default_factory=list)
    skipped_scenes: list[str] = field(default_factory=list)
    # why scenes were skipped for an unusable record ("scene S: ego_pose TOKEN: field rotation = … has no rotation")
    bad_records: list[str] = field(default_factory=list)

    #: stacked arrays and the shape of one frame's entry (the leading axis is the frame)
    _ARRAYS = {
        "keyframe_indices": (),
        "timestamps": (),
        "camera_intrinsics": (3, 3),
        "camera_extrinsics": (4, 4),
        "ego_poses": (3,),
        "history_positions": (8, 2),
        "history_actions": (6, 2),
        "gt_positions": (6, 2),
        "gt_actions": (6, 2),
    }
    _INTEGER_ARRAYS = ("keyframe_indices", "timestamps")
    _LISTS = ("frame_ids", "scene_names", "scene_tokens", "sample_tokens", "image_paths")

    def __post_init__(self) -> None:
        n = len(self.frame_ids)
        for name, entry in self._ARRAYS.items():
            shape = (n, *entry)
            arr = np.asarray(getattr(self, name))
            if arr.shape != shape:
                raise ShapeError(f"FrameSet.{name} has shape {arr.shape}, expected {shape}")
            dtype = np.int64 if name in self._INTEGER_ARRAYS else np.float64
            object.__setattr__(self, name, _readonly(arr.astype(dtype, copy=False)))
        for name in self._LISTS:
            value = list(getattr(self, name))
            if len(value) != n:
                raise InputError(f"FrameSet.{name} has {len(value)} entries, expected {n}")
            object.__setattr__(self, name, value)
        if len(set(self.frame_ids)) != n:
            raise InputError("FrameSet frame ids are not unique")
        object.__setattr__(self, "_index", {fid: i for i, fid in enumerate(self.frame_ids)})

    # -- sequence protocol -------------------------------------------------
    def __len__(self) -> int:
        return len(self.frame_ids)

    def __getitem__(self, i: int) -> Frame:
        n = len(self)
        if not isinstance(i, (int, np.integer)):
            raise TypeError(f"FrameSet indices must be integers, not {type(i).__name__}")
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"frame index {i} out of range for {n} frames")
        return Frame(
            frame_id=self.frame_ids[i],
            scene_name=self.scene_names[i],
            scene_token=self.scene_tokens[i],
            sample_token=self.sample_tokens[i],
            keyframe_index=int(self.keyframe_indices[i]),
            timestamp=int(self.timestamps[i]),
            image_path=self.image_paths[i],
            camera_intrinsic=self.camera_intrinsics[i],
            camera_extrinsic=self.camera_extrinsics[i],
            ego_pose=self.ego_poses[i],
            history_positions=self.history_positions[i],
            history_actions=self.history_actions[i],
            gt_positions=self.gt_positions[i],
            gt_actions=self.gt_actions[i],
        )

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self[i]

    def __repr__(self) -> str:
        return (
            f"FrameSet({len(self)} frames, {len(self.scenes)} scenes, version={self.version!r}, "
            f"split={self.split!r}, window={self.window!r})"
        )

    def index(self, frame_id: str) -> int:
        """Position of ``frame_id`` in this set (``DatasetError`` if absent)."""
        try:
            return self._index[frame_id]  # type: ignore[attr-defined]  # set by __post_init__
        except KeyError:
            raise DatasetError(f"frame {frame_id!r} is not in this frame set") from None

    def get(self, frame_id: str) -> Frame:
        """The frame with id ``frame_id``."""
        return self[self.index(frame_id)]

    # -- subsets -----------------------------------------------------------
    def _take(self, idx: Sequence[int]) -> FrameSet:
        idx_arr = np.asarray(idx, dtype=np.int64)
        kwargs: dict[str, Any] = {name: getattr(self, name)[idx_arr] for name in self._ARRAYS}
        for name in self._LISTS:
            values = getattr(self, name)
            kwargs[name] = [values[i] for i in idx_arr.tolist()]
        kept = set(kwargs["scene_names"])
        kept_ids = set(kwargs["frame_ids"])
        return FrameSet(
            **kwargs,
            dataroot=self.dataroot,
            version=self.version,
            split=self.split,
            scenes=[s for s in self.scenes if s in kept],
            window=self.window,
            missing_images=[f for f in self.missing_images if f.split("/", 1)[0] in kept or f in kept_ids],
            skipped_scenes=list(self.skipped_scenes),
            bad_records=list(self.bad_records),
        )

    def select(self, frame_ids: Iterable[str]) -> FrameSet:
        """The frames with these ids, in this set's order; unknown ids raise ``DatasetError``."""
        wanted = list(frame_ids)
        unknown = [f for f in wanted if f not in self._index]  # type: ignore[attr-defined]  # set by __post_init__
        if unknown:
            shown = ", ".join(repr(u) for u in unknown[:5])
            more = f" and {len(unknown) - 5} more" if len(unknown) > 5 else ""
            raise DatasetError(f"{len(unknown)} frame id(s) not in this frame set: {shown}{more}")
        keep = sorted({self._index[f] for f in wanted})  # type: ignore[attr-defined]  # set by __post_init__
        return self._take(keep)

    def select_scenes(self, scene_names: Iterable[str]) -> FrameSet:
        """The frames of these scenes (unknown names raise ``DatasetError``)."""
        names = set(scene_names)
        unknown = sorted(names - set(self.scenes))
        if unknown:
            raise DatasetError(f"scene(s) not in this frame set: {', '.join(unknown)}")
        return self._take([i for i, s in enumerate(self.scene_names) if s in names])

    def head(self, n: int) -> FrameSet:
        """The first ``n`` frames."""
        if n < 0:
            raise InputError(f"head(n) needs n >= 0, got {n}")
        return self._take(list(range(min(n, len(self)))))

    # -- description -------------------------------------------------------
    def describe(self) -> dict[str, Any]:
        """JSON-able provenance: kind (``synthetic`` for lightemma's synthetic dataset, else ``nuscenes``),
        dataroot, version, split, scenes, window, n_frames, …"""
        synthetic = bool(self.dataroot) and (Path(self.dataroot) / SYNTH_MARKER).is_file()
        return {
            "kind": "synthetic" if synthetic else ("nuscenes" if self.dataroot else None),
            "dataroot": self.dataroot,
            "version": self.version,
            "split": self.split,
            "scenes": list(self.scenes),
            "window": self.window,
            "n_frames": len(self),
            "missing_images": list(self.missing_images),
            "skipped_scenes": list(self.skipped_scenes),
            "bad_records": list(self.bad_records),
        }

    def summary_line(self) -> str:
        """One line saying which split, how many scenes and frames this set took (see :func:`summary_line`)."""
        return summary_line(self.describe())


def _count(n: int, noun: str) -> str:
    return f"{n:,} {noun}" + ("" if n == 1 else "s")


def summary_line(described: Mapping[str, Any]) -> str:
    """One line from a frame-set description (:meth:`FrameSet.describe`, a run manifest's ``dataset``).

    ``v1.0-mini, split all: 10 scenes, 208 frames, reference window`` — plus the
    scenes skipped as too short, the frames dropped for a missing image, and a
    ``limit`` when the description has one.
    """
    n_frames = int(described.get("n_frames") or 0)
    version = described.get("version")
    if not version:
        return f"{_count(n_frames, 'frame')} passed in memory"
    split = described.get("split")
    which = f"split {split}" if split else "scenes given by name"
    scenes = described.get("scenes") or []
    line = f"{version}, {which}: {_count(len(scenes), 'scene')}, {_count(n_frames, 'frame')}, {described.get('window') or 'reference'} window"
    if described.get("limit"):
        line += f" (first {_count(int(described['limit']), 'frame')})"
    sample = described.get("sample")
    if isinstance(sample, Mapping) and sample.get("n"):
        line += f" (sample of {_count(int(sample['n']), 'frame')}, seed {sample.get('seed', 0)}, spread over scenes)"
    if described.get("skipped_scenes"):
        line += f"; {_count(len(described['skipped_scenes']), 'scene')} too short for a frame, skipped"
    if described.get("missing_images"):
        line += f"; {_count(len(described['missing_images']), 'frame')} without an image file"
    return line
