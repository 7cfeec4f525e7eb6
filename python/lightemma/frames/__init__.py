"""Frames in memory (docs/definitions.md#frames-and-windows): the frame set, its fingerprint and samples, prompt rendering.

Public names: :class:`Frame`, :class:`FrameSet`, :func:`format_number`, :func:`format_history`,
:func:`format_python_list`, :func:`history_placeholders`. Frames are read from a nuScenes dataroot by
:mod:`lightemma.nuscenes` (:func:`lightemma.nuscenes.load_frames`, also ``lightemma.load_frames``).
"""

from __future__ import annotations

from lightemma.frames.model import Frame, FrameSet
from lightemma.frames.render import format_history, format_number, format_python_list, history_placeholders

__all__ = [
    "Frame",
    "FrameSet",
    "format_history",
    "format_number",
    "format_python_list",
    "history_placeholders",
]
