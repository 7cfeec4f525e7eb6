"""nuScenes frames (docs/definitions.md#frames-and-windows): loading, geometry, prompt rendering.

Public names: :func:`load_frames`, :class:`Frame`, :class:`FrameSet`,
:func:`extract_frames`, :func:`load_tables`, :func:`format_number`,
:func:`format_history`, :func:`format_python_list`,
:func:`history_placeholders`, :func:`dataset_path` (the path of a file a table names, kept
inside the dataroot). The tables are read without nuscenes-devkit (numpy 1 or 2).
"""

from __future__ import annotations

from lightemma.frames.loader import dataset_path, extract_frames, load_frames, load_tables, window_range
from lightemma.frames.model import Frame, FrameSet
from lightemma.frames.render import format_history, format_number, format_python_list, history_placeholders

__all__ = [
    "Frame",
    "FrameSet",
    "dataset_path",
    "extract_frames",
    "format_history",
    "format_number",
    "format_python_list",
    "history_placeholders",
    "load_frames",
    "load_tables",
    "window_range",
]
