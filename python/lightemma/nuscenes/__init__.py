"""nuScenes on disk: the only code that opens files under a dataroot (docs/architecture.md).

Every other part of lightemma receives what this package parsed — a :class:`~lightemma.frames.FrameSet`, the safety
and planning data (:class:`~lightemma.nuscenes.annotations.SafetyData`), drivable areas and map layers, CAN bus
readings — and never opens a dataroot's files itself (tests/unit/nuscenes/test_nuscenes_reader.py checks it).

Modules: :mod:`~lightemma.nuscenes.json_tables` (the one bounded, checked table reader),
:mod:`~lightemma.nuscenes.frames` (frames, windows and splits: ``splits.json``),
:mod:`~lightemma.nuscenes.annotations` (poses, agents and maps per keyframe for the safety metrics and the planning
score), :mod:`~lightemma.nuscenes.map_files` (base map masks and map expansions), :mod:`~lightemma.nuscenes.can_bus`
(the CAN bus expansion), :mod:`~lightemma.nuscenes.geometry` (poses, quaternions, ego frames, actions). No devkit is
needed (numpy 1 or 2).

Public names: :func:`load_frames`, :func:`load_tables`, :func:`extract_frames`, :func:`dataset_path` (the path of a
file a table names, kept inside the dataroot), :func:`window_range`.
"""

from __future__ import annotations

from lightemma.nuscenes.frames import dataset_path, extract_frames, load_frames, load_tables, window_range

__all__ = ["dataset_path", "extract_frames", "load_frames", "load_tables", "window_range"]
