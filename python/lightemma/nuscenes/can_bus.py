"""CAN bus readings at keyframes: nuScenes' CAN bus expansion, ``<dataroot>/can_bus/<scene>_pose.json``.

The ``pose`` message (50 Hz; nuscenes-devkit ``nuscenes/can_bus/can_bus_api.py``) is a JSON list of objects with
``utime`` (µs, the clock of the tables' timestamps), ``pos`` (m), ``orientation`` (w, x, y, z), ``vel`` (m/s),
``accel`` (m/s²) and ``rotation_rate`` (rad/s), the last three in the ego frame (x forward, y left, z up).
:func:`frame_can_readings` gives, per frame, the message nearest its keyframe timestamp — speed ``vel[0]``,
longitudinal and lateral acceleration ``accel[0]``, ``accel[1]``, yaw rate ``rotation_rate[2]`` — as the ``can=``
rows of :func:`lightemma.planning.simulation.initial_state` (docs/frames.md#can-bus).

Reads are bounded: a regular file of at most :data:`MAX_CAN_FILE_BYTES`, opened without blocking. A file that is
there but unreadable or malformed raises :class:`~lightemma.errors.DatasetError` in one line naming it (and the
message); a scene without a file, or a keyframe farther than :data:`MAX_OFFSET_US` from every message, is not
available (a NaN row and its reason), never filled in.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lightemma._files import FileRefused, read_regular_file
from lightemma.errors import DatasetError, InputError

__all__ = [
    "CAN_COLUMNS",
    "CanReadings",
    "MAX_CAN_FILE_BYTES",
    "MAX_OFFSET_US",
    "PoseMessages",
    "can_bus_folder",
    "can_readings",
    "frame_can_readings",
    "pose_file",
    "read_pose_messages",
]

#: folder of the CAN bus expansion under a dataroot (the devkit's ``NuScenesCanBus.can_dir``)
CAN_FOLDER = "can_bus"
#: the columns of a reading row, in the order ``initial_state(..., can=)`` takes them
CAN_COLUMNS = ("speed", "acceleration_x", "acceleration_y", "yaw_rate")
#: largest pose file read (bytes): a real one is about 1,000 messages (20 s at 50 Hz), well under 1 MB
MAX_CAN_FILE_BYTES = 64 * 2**20
#: a keyframe farther than this (µs) from the nearest pose message has no reading (2.5 periods of 50 Hz)
MAX_OFFSET_US = 50_000


@dataclass(frozen=True)
class PoseMessages:
    """The fields of one scene's ``pose`` messages that the readings need: ``utime`` (M,) int64 µs, non-decreasing;
    ``vel``, ``accel``, ``rotation_rate`` (M, 3) float64, finite."""

    path: str
    utime: npt.NDArray[np.int64]
    vel: npt.NDArray[np.float64]
    accel: npt.NDArray[np.float64]
    rotation_rate: npt.NDArray[np.float64]


@dataclass(frozen=True)
class CanReadings:
    """Per frame: ``values`` (N, 4) speed (m/s), longitudinal and lateral acceleration (m/s²), yaw rate (rad/s)
    (:data:`CAN_COLUMNS`), a NaN row where not available; ``utime`` (N,) int64 the message used (−1 where none);
    ``reasons`` None where read, else why not (one line)."""

    values: npt.NDArray[np.float64]
    utime: npt.NDArray[np.int64]
    reasons: list[str | None]

    @property
    def available(self) -> npt.NDArray[np.bool_]:
        """(N,) bool: the frame has a reading."""
        return np.array([r is None for r in self.reasons], dtype=bool)


def can_bus_folder(dataroot: str | os.PathLike[str]) -> str | None:
    """``<dataroot>/can_bus`` when it is a folder, else ``None`` (the expansion is a separate download)."""
    folder = os.path.join(os.fspath(dataroot), CAN_FOLDER)
    return folder if os.path.isdir(folder) else None


def pose_file(folder: str | os.PathLike[str], scene_name: str) -> str:
    """``<folder>/<scene_name>_pose.json``; raises DatasetError for a scene name that is not a plain file name."""
    if (
        not isinstance(scene_name, str)
        or not scene_name
        or scene_name in (".", "..")
        or "\0" in scene_name
        or "/" in scene_name
        or os.sep in scene_name
    ):
        raise DatasetError(f"scene name {scene_name!r} cannot name a CAN bus file in {folder}")
    return os.path.join(os.fspath(folder), f"{scene_name}_pose.json")


def _vector(msg: dict, field: str, path: str, i: int) -> list[float]:
    value = msg.get(field)
    if (
        not isinstance(value, list)
        or len(value) != 3
        or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
    ):
        shown = repr(value) if len(repr(value)) <= 60 else repr(value)[:57] + "..."
        raise DatasetError(f"CAN bus file {path}: message {i} has {field} = {shown}; expected 3 finite numbers")
    return [float(v) for v in value]


def read_pose_messages(path: str | os.PathLike[str]) -> PoseMessages:
    """One scene's ``pose`` messages (``utime``, ``vel``, ``accel``, ``rotation_rate``; other fields are not read).

    Raises DatasetError (one line naming the file, and the message where one is at fault) for a file that is not a
    regular file of at most :data:`MAX_CAN_FILE_BYTES`, not JSON, not a non-empty list of objects, a ``utime`` that
    is not a non-negative integer or goes backwards, or a vector that is not 3 finite numbers."""
    path = os.fspath(path)
    try:
        data = read_regular_file(path, MAX_CAN_FILE_BYTES)
    except FileRefused as exc:
        raise DatasetError(f"CAN bus file {path} {exc.reason}") from None
    try:
        doc = json.loads(data)
    except (ValueError, UnicodeDecodeError) as exc:
        raise DatasetError(f"CAN bus file {path} is not valid JSON: {exc}") from None
    except RecursionError:
        raise DatasetError(f"CAN bus file {path} is not valid JSON: nested too deeply") from None
    if not isinstance(doc, list) or not doc:
        raise DatasetError(f"CAN bus file {path} is not a non-empty list of pose messages")
    utime, vel, accel, rate = [], [], [], []
    previous = -1
    for i, msg in enumerate(doc):
        if not isinstance(msg, dict):
            raise DatasetError(f"CAN bus file {path}: message {i} is not an object")
        t = msg.get("utime")
        if not isinstance(t, int) or isinstance(t, bool) or not 0 <= t <= np.iinfo(np.int64).max:
            raise DatasetError(
                f"CAN bus file {path}: message {i} has utime = {t!r:.40}; expected a non-negative integer (µs)"
            )
        if t < previous:
            raise DatasetError(
                f"CAN bus file {path}: message {i} has utime {t}, before the previous message's {previous}"
            )
        previous = t
        utime.append(t)
        vel.append(_vector(msg, "vel", path, i))
        accel.append(_vector(msg, "accel", path, i))
        rate.append(_vector(msg, "rotation_rate", path, i))
    return PoseMessages(path, np.asarray(utime, dtype=np.int64), np.asarray(vel), np.asarray(accel), np.asarray(rate))


def _readings_at(messages: PoseMessages, timestamps: npt.NDArray[np.int64]) -> CanReadings:
    """The message nearest each timestamp (µs; a tie takes the earlier message) within :data:`MAX_OFFSET_US`."""
    n = len(timestamps)
    values = np.full((n, 4), np.nan)
    used = np.full(n, -1, dtype=np.int64)
    reasons: list[str | None] = [None] * n
    u = messages.utime
    after = np.clip(np.searchsorted(u, timestamps, side="left"), 0, len(u) - 1)
    before = np.clip(after - 1, 0, len(u) - 1)
    pick = np.where(np.abs(u[before] - timestamps) <= np.abs(u[after] - timestamps), before, after)
    for i, (t, j) in enumerate(zip(timestamps.tolist(), pick.tolist())):
        offset = abs(int(u[j]) - t)
        if offset > MAX_OFFSET_US:
            reasons[i] = (
                f"no CAN bus pose message within {MAX_OFFSET_US} µs of keyframe time {t} in "
                f"{messages.path} (nearest {offset} µs away)"
            )
            continue
        values[i] = (messages.vel[j, 0], messages.accel[j, 0], messages.accel[j, 1], messages.rotation_rate[j, 2])
        used[i] = u[j]
    return CanReadings(values, used, reasons)


def can_readings(
    dataroot: str | os.PathLike[str], scene_names: Sequence[str], timestamps: npt.ArrayLike
) -> CanReadings | None:
    """The CAN bus readings of N keyframes given by scene name and timestamp (µs), or ``None`` when the dataroot
    has no ``can_bus`` folder. A scene without its ``_pose.json`` has NaN rows with that reason; each scene's file
    is read once. Raises DatasetError for a file that is there but unreadable (see :func:`read_pose_messages`) and
    ValueError when the two inputs' lengths differ."""
    folder = can_bus_folder(dataroot)
    if folder is None:
        return None
    ts = np.asarray(timestamps, dtype=np.int64).reshape(-1)
    names = list(scene_names)
    if len(names) != len(ts):
        raise InputError(f"scene_names has {len(names)} entries but timestamps has {len(ts)}")
    values = np.full((len(ts), 4), np.nan)
    used = np.full(len(ts), -1, dtype=np.int64)
    reasons: list[str | None] = [None] * len(ts)
    for scene in dict.fromkeys(names):
        rows = np.array([i for i, name in enumerate(names) if name == scene], dtype=np.int64)
        path = pose_file(folder, scene)
        if not os.path.lexists(path):
            for i in rows.tolist():
                reasons[i] = f"no CAN bus pose file for scene {scene} ({path})"
            continue
        part = _readings_at(read_pose_messages(path), ts[rows])
        values[rows], used[rows] = part.values, part.utime
        for i, why in zip(rows.tolist(), part.reasons):
            reasons[i] = why
    return CanReadings(values, used, reasons)


def frame_can_readings(frames) -> CanReadings | None:
    """:func:`can_readings` of a :class:`~lightemma.frames.FrameSet`'s frames (its ``dataroot``, ``scene_names``
    and keyframe ``timestamps``): pass ``.values`` as ``initial_state(..., can=)``. ``None`` without a can_bus
    folder."""
    return can_readings(frames.dataroot, frames.scene_names, frames.timestamps)
