"""nuScenes frames (docs/definitions.md#frames-and-windows): loading, geometry, prompt rendering.

Public names: :func:`load_frames`, :class:`Frame`, :class:`FrameSet`,
:func:`extract_frames`, :func:`load_tables`, :func:`format_number`,
:func:`format_history`, :func:`format_python_list`,
:func:`history_placeholders`. The tables are read without nuscenes-devkit (numpy 1 or 2).
"""

from __future__ import annotations

from lightemma.frames.loader import extract_frames, load_frames, load_tables, window_range
from lightemma.frames.model import Frame, FrameSet
from lightemma.frames.render import format_history, format_number, format_python_list, history_placeholders

__all__ = [
    "Frame",
    "FrameSet",
    "extract_frames",
    "format_history",
    "format_number",
    "format_python_list",
    "history_placeholders",
    "load_frames",
    "load_tables",
    "window_range",
]
