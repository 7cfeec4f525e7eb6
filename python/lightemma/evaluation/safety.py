"""Does it drive safely? Collision with annotated agents and leaving the drivable area (docs/definitions.md#safety).

Three layers, one home:

* geometry (Rust core, :mod:`lightemma._core`): :func:`ego_poses`, :func:`footprints`,
  :func:`box_collisions`, :class:`DrivableArea` ``.lookup`` — whole batches, the GIL released;
* the dataset (:func:`load_safety_data`): per keyframe its CAM_FRONT ego pose, the annotated
  agents of the next six keyframes and the drivable area of its log's map, read from the
  dataroot's JSON tables and map files directly (the devkit's conventions, no devkit needed);
* outcomes and rates (:func:`frame_safety`, :func:`safety_values`): per frame and step, the
  footprint's corners on or off the drivable area and its overlap with vehicles and vulnerable
  road users; the rates of the conventions ``uniad``, ``stp3`` and ``any``.

Conventions (all frames 0.5 s apart, steps k = 1..6 at 0.5 … 3.0 s, ``t`` = 1, 2, 3 s):

* ``uniad`` — UniAD's ``obj_box_col``: the share of frames whose footprint overlaps an agent
  *at* step 2t; a step where the ground truth itself collides is not counted (UniAD masks it);
* ``stp3`` — ST-P3 / VAD: the per-step rate averaged over the prefix 1…2t; ground-truth
  collisions masked as in ST-P3's code;
* ``any`` — the frame collides somewhere in 1…2t (BEV-Planner's "any collision up to t"; the
  frame's outcome); ground-truth collisions not masked (as VADv2, BEV-Planner).

The footprint is the ego box of ST-P3/UniAD, 4.084 m × 1.85 m, rotated by the heading along
the trajectory; its reference point is nuScenes' ``ego_pose`` (the rear-axle centre) and its
centre lies :data:`EGO_OFFSET` ahead of it.
"""

from __future__ import annotations

import json
import math
import os
import re
import stat
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lightemma.errors import DatasetError

#: ego box of ST-P3 / UniAD: length × width, metres (the Renault Zoe is 4.084 m long and 1.73 m wide
#: without mirrors; 1.85 m is their margin)
EGO_LENGTH = 4.084
EGO_WIDTH = 1.85
#: the box centre lies this far ahead of the ego_pose reference point (the rear-axle centre), metres:
#: nuScenes' LIDAR_TOP sits 0.943713 m ahead of the rear axle (calibrated_sensor) and UniAD shifts the
#: ego box 0.5 m forward in the LiDAR frame
EGO_OFFSET = 0.943713 + 0.5
#: a step shorter than this keeps the previous heading (BEV-Planner's rule), metres
MIN_STEP = 1.0
#: the base map masks' native resolution (the devkit's MapMask), metres per pixel
MASK_RESOLUTION = 0.1
MASK_FOREGROUND = 255
#: the largest base map mask read, pixels (width × height from the PNG header, checked before decoding):
#: nuScenes' largest map, singapore-queenstown, spans about 3,229 m × 3,687 m, 1.19 G pixels at 0.1 m/px;
#: a larger header is refused (a 437 KB 1-bit PNG can claim 60,000² pixels: 3.6 GB decoded)
MAX_MASK_PIXELS = 1_500_000_000
#: map node and annotation coordinates beyond ± this are refused, metres (nuScenes' maps span under 4 km)
MAX_COORDINATE_M = 1e6
#: annotation boxes longer or wider than this are refused, metres (articulated buses are about 18 m long)
MAX_AGENT_SIZE_M = 100.0
STEPS = 6
SECONDS = (1, 2, 3)

COLLISION_CONVENTIONS: tuple[str, ...] = ("uniad", "stp3", "any")
#: which annotation boxes count as agents (docs/definitions.md#safety): ``all`` (default: every vehicle and
#: VRU box, as UniAD's occupancy labels — ``occ_filter_by_valid_flag=False``, ``filter_invisible=False``),
#: ``valid`` (boxes with ``num_lidar_pts + num_radar_pts > 0``: mmdet3d's ``valid_flag``, VAD's ground-truth
#: boxes), ``visible`` (boxes whose visibility is not ``v0-40``: ST-P3's ``FILTER_INVISIBLE_VEHICLES``)
AGENT_FILTERS: tuple[str, ...] = ("all", "valid", "visible")
#: which collision convention an ADE table shows beside it (the ADE conventions carry the same names)
COLLISION_FOR_ADE = {"uniad": "uniad", "stp3": "stp3", "lightemma": "any"}

# agent classes
VEHICLE, VRU, OTHER = 0, 1, 2
CLASS_NAMES = ("vehicle", "vru")
_VRU_VEHICLES = ("vehicle.bicycle", "vehicle.motorcycle")


def agent_class(category: str) -> int:
    """``VEHICLE`` (``vehicle.*`` but bicycles and motorcycles), ``VRU`` (``human.pedestrian.*``,
    ``vehicle.bicycle``, ``vehicle.motorcycle``: pedestrians, cyclists, motorcyclists) or ``OTHER``
    (barriers, cones, debris, animals, static objects: never counted)."""
    if category.startswith("human.pedestrian") or category.startswith(_VRU_VEHICLES):
        return VRU
    if category.startswith("vehicle."):
        return VEHICLE
    return OTHER


@dataclass(frozen=True)
class EgoModel:
    """The ego footprint and heading rule (defaults: ST-P3/UniAD's box, UniAD's offset, BEV-Planner's rule)."""

    length: float = EGO_LENGTH
    width: float = EGO_WIDTH
    offset: float = EGO_OFFSET
    min_step: float = MIN_STEP

    def kwargs(self) -> dict[str, float]:
        return {"length": self.length, "width": self.width, "offset": self.offset, "min_step": self.min_step}


EGO = EgoModel()


def _traj_poses(traj: Any, poses: Any) -> tuple[np.ndarray, np.ndarray]:
    return np.ascontiguousarray(traj, dtype=np.float64), np.ascontiguousarray(poses, dtype=np.float64)


def ego_poses(traj: Any, poses: Any, ego: EgoModel = EGO) -> np.ndarray:
    """Global (x, y, heading) of every step's reference point.

    ``traj`` (N, T, 2): positions in the ego frame of each keyframe (m); ``poses`` (N, 3): the
    keyframe's global (x, y, yaw) (m, rad). Returns (N, T, 3). The heading of step k is the
    direction of p_{k−1} → p_k (p_0 the origin, heading 0), kept when that step is shorter than
    ``ego.min_step``. Raises ``ValueError`` for wrong shapes or non-finite values (frame, step named).
    """
    from lightemma import _core

    return _core.ego_poses(*_traj_poses(traj, poses), **ego.kwargs())


def footprints(traj: Any, poses: Any, ego: EgoModel = EGO) -> np.ndarray:
    """Global corners (N, T, 4, 2) of the ego footprint: front-left, front-right, rear-right, rear-left (m)."""
    from lightemma import _core

    return _core.footprint_corners(*_traj_poses(traj, poses), **ego.kwargs())


def box_collisions(traj: Any, poses: Any, agents: Any, ego: EgoModel = EGO) -> np.ndarray:
    """(N, T, A) bool: the footprint at step k overlaps agent slot a (exact rotated-rectangle test).

    ``agents`` (N, T, A, 5): global centre x, y (m), yaw (rad), length, width (m) per frame, step
    and slot; NaN centre x marks an empty slot. Touching boxes do not overlap. A non-finite value
    or a size ≤ 0 in a used slot raises ``ValueError`` naming frame, step and slot.
    """
    from lightemma import _core

    t, p = _traj_poses(traj, poses)
    return _core.box_collisions(t, p, np.ascontiguousarray(agents, dtype=np.float64), **ego.kwargs())


# -- the drivable area --------------------------------------------------------------------------

ON, OFF, OUTSIDE = 1, 0, 2


@dataclass
class DrivableArea:
    """A map's drivable area: the map expansion's ``drivable_area`` polygons, or a base map mask.

    ``kind``: ``expansion`` (exact point-in-polygon against the union of the layer's polygons,
    holes honoured) or ``mask`` (the devkit's ``MapMask``: pixel (round(x/0.1), round(−y/0.1 + H)),
    NumPy's round, drivable where the pixel is 255 — the *semantic prior*, drivable surface and
    sidewalks). ``source``: the file read.
    """

    kind: str
    source: str
    mask: np.ndarray | None = None  # (H, W) uint8
    xy: np.ndarray | None = None  # (V, 2)
    rings: np.ndarray | None = None  # (R + 1,) int64
    polygons: np.ndarray | None = None  # (P + 1,) int64

    def lookup(self, traj: Any, poses: Any, ego: EgoModel = EGO) -> np.ndarray:
        """(N, T, 5) uint8 of ``ON`` / ``OFF`` / ``OUTSIDE`` (the point is not covered by the mask
        image: counted off the drivable area, and reported) for the footprint's 4 corners (front-left,
        front-right, rear-right, rear-left) and then its reference point, at every step."""
        from lightemma import _core

        t, p = _traj_poses(traj, poses)
        if self.kind == "mask":
            return _core.mask_area(t, p, self.mask, MASK_RESOLUTION, MASK_FOREGROUND, **ego.kwargs())
        return _core.polygon_area(t, p, self.xy, self.rings, self.polygons, **ego.kwargs())

    def contains(self, points: Any) -> np.ndarray:
        """(M,) uint8 ``ON`` / ``OFF`` / ``OUTSIDE`` codes of global points (M, 2)."""
        pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 2)
        from lightemma import _core

        if self.kind == "mask":
            return _core.mask_lookup(pts, self.mask, MASK_RESOLUTION, MASK_FOREGROUND)
        poses = np.column_stack([pts, np.zeros(len(pts))])  # a one-step trajectory at the origin of each point
        return self.lookup(np.zeros((len(pts), 1, 2)), poses, EgoModel(offset=0.0))[:, 0, 4]


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: PNG colour types (IHDR) -> what they are
_PNG_COLOUR = {0: "grayscale", 2: "RGB", 3: "palette", 4: "grayscale with alpha", 6: "RGBA"}


def _regular_file(path: str | os.PathLike[str], what: str) -> None:
    """Raise :class:`DatasetError` unless ``path`` (links followed) is a regular file: a FIFO would block the
    reader and ``/dev/zero`` never ends."""
    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        raise DatasetError(f"{what} {path} cannot be read: {exc.strerror or exc}") from None
    if not stat.S_ISREG(mode):
        raise DatasetError(f"{what} {path} is not a regular file ({_file_kind(mode)})")


def _file_kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def _png_header(path: str | os.PathLike[str]) -> tuple[int, int, int, int]:
    """(width, height, bit depth, colour type) from a PNG's IHDR chunk; a file that is not a PNG raises."""
    with open(path, "rb") as f:
        head = f.read(26)
    if len(head) < 26 or head[:8] != _PNG_SIGNATURE or head[12:16] != b"IHDR":
        raise DatasetError(f"map mask {path} is not a PNG image (nuScenes' base map masks are PNG files)")
    width, height, depth, colour = struct.unpack(">IIBB", head[16:26])
    return width, height, depth, colour


def read_map_mask(path: str | os.PathLike[str]) -> DrivableArea:
    """A base map mask (``maps/<token>.png``) as the devkit's ``MapMask`` reads it at 0.1 m/px (no resize).

    Returns an (H, W) uint8 mask, drivable where 255. Read: 8-bit grayscale PNGs as they are (the devkit's
    encoding, 255 drivable), and the encodings PNG optimisers give a two-valued image, mapped to the same
    values: 1-bit grayscale (1 → 255) and palette images whose colours are grays (index → its gray level).
    Refused with :class:`DatasetError` (one line naming the file): a file that is not a regular file or not a
    PNG, a header claiming more than :data:`MAX_MASK_PIXELS` pixels (checked before decoding; PIL's own
    pixel limit is left as it is), 16-bit, colour or alpha images, palettes with colours, and a mask with
    no pixel of 255 (every point would be off the drivable area).
    """
    from PIL import PngImagePlugin

    _regular_file(path, "map mask")
    width, height, depth, colour = _png_header(path)
    if width * height > MAX_MASK_PIXELS:
        raise DatasetError(f"map mask {path} claims {width} × {height} pixels, more than the {MAX_MASK_PIXELS:,} "
                           "a base map mask can have (nuScenes' largest is 1.19 G pixels); not decoded")
    if colour not in (0, 3) or depth == 16:
        kind = f"{depth}-bit {_PNG_COLOUR.get(colour, f'colour type {colour}')}"
        raise DatasetError(f"map mask {path} is a {kind} PNG; a base map mask is 8-bit grayscale (255 drivable), "
                           "1-bit grayscale or a gray palette")
    try:
        with open(path, "rb") as f:
            img = PngImagePlugin.PngImageFile(f)  # Image.open's pixel limit is replaced by the bound above
            img.load()
            mode = img.mode
            palette = img.getpalette() if mode == "P" else None
            used = np.flatnonzero(img.histogram()) if mode == "P" else None  # palette indices in use (C, no copy)
            mask = np.array(img)
            img.close()
            del img
    except (OSError, ValueError, SyntaxError, struct.error) as exc:
        raise DatasetError(f"map mask {path} cannot be read: {exc}") from None
    if mode == "1":
        mask = mask.view(np.uint8)  # in place (masks are up to 1.5 G pixels); PIL's True bytes are not always 1
        np.minimum(mask, 1, out=mask)
        mask *= np.uint8(MASK_FOREGROUND)
    elif mode == "P":
        rgb = np.asarray(palette or [], dtype=np.int64).reshape(-1, 3)
        assert used is not None
        if len(used) and (used.max() >= len(rgb) or not (rgb[used] == rgb[used, :1]).all()):
            raise DatasetError(f"map mask {path} is a palette PNG with colours (or indices beyond its palette); "
                               "a base map mask is grayscale")
        lut = np.zeros(256, dtype=np.uint8)
        lut[: len(rgb)] = rgb[:256, 0]
        mask = lut[mask]
    elif mode != "L":
        raise DatasetError(f"map mask {path} decodes to PIL mode {mode}; a base map mask is 8-bit grayscale")
    if mask.ndim != 2:
        raise DatasetError(f"map mask {path} has shape {mask.shape}; expected a one-channel image")
    top = int(mask.max()) if mask.size else None  # a reduction: no mask-sized temporary
    if top != MASK_FOREGROUND:
        raise DatasetError(f"map mask {path} has no pixel of value {MASK_FOREGROUND} (drivable); its largest value is "
                           f"{top}: not a drivable-area mask in the devkit's encoding")
    return DrivableArea("mask", os.fspath(path), mask=np.ascontiguousarray(mask, dtype=np.uint8))


def _map_coordinate(value: Any, path: Any, node: Any, axis: str) -> float:
    """A map node coordinate: a finite number within :data:`MAX_COORDINATE_M` (bools and text refused)."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        try:
            v = float(value)
        except OverflowError:
            v = math.inf
        if math.isfinite(v) and abs(v) <= MAX_COORDINATE_M:
            return v
    shown = repr(value) if len(repr(value)) <= 40 else repr(value)[:37] + "..."
    raise DatasetError(f"map expansion {path}: node {node} has {axis} = {shown}; a coordinate must be a finite number "
                       f"within ±{MAX_COORDINATE_M:g} m")


def read_expansion(path: str | os.PathLike[str]) -> DrivableArea:
    """The ``drivable_area`` layer of a map-expansion JSON (``maps/expansion/<location>.json``) as polygons.

    Each drivable_area record lists ``polygon_tokens``; each polygon has ``exterior_node_tokens``
    and ``holes`` (``node_tokens``); nodes carry global ``x``, ``y`` (the devkit's ``NuScenesMap``).
    Raises :class:`DatasetError` naming the file (and the node or polygon) for a file that is not a regular
    file or not readable JSON (nesting too deep included), a missing record, a node coordinate that is not
    a finite number within :data:`MAX_COORDINATE_M`, or a ring of fewer than 3 nodes.
    """
    _regular_file(path, "map expansion")
    try:
        with open(path, encoding="utf-8") as f:
            doc = json.load(f)
    except RecursionError:
        raise DatasetError(f"map expansion {path}: cannot read its drivable_area layer "
                           "(the JSON is nested too deep)") from None
    except (OSError, ValueError) as exc:
        raise DatasetError(f"map expansion {path}: cannot read its drivable_area layer "
                           f"({type(exc).__name__}: {exc})") from None
    try:
        nodes = {n["token"]: n for n in doc["node"]}
        polys = {p["token"]: p for p in doc["polygon"]}
        xy: list[tuple[float, float]] = []
        rings, polygons = [0], [0]
        for record in doc["drivable_area"]:
            for ptok in record["polygon_tokens"]:
                poly = polys[ptok]
                for ring in [poly["exterior_node_tokens"], *(h["node_tokens"] for h in poly.get("holes", []))]:
                    if not isinstance(ring, list) or len(ring) < 3:
                        n = len(ring) if isinstance(ring, list) else "no list of"
                        raise DatasetError(f"map expansion {path}: polygon {ptok} has a ring of {n} node(s); "
                                           "a ring needs at least 3")
                    for t in ring:
                        node = nodes[t]
                        xy.append((_map_coordinate(node["x"], path, t, "x"), _map_coordinate(node["y"], path, t, "y")))
                    rings.append(len(xy))
                polygons.append(len(rings) - 1)
    except (KeyError, TypeError, AttributeError) as exc:
        raise DatasetError(f"map expansion {path}: cannot read its drivable_area layer ({type(exc).__name__}: {exc})") from None
    if len(polygons) == 1:  # every position would be off-road: no number, as for a mask without a drivable pixel
        raise DatasetError(f"map expansion {path}: its drivable_area layer holds no polygon")
    return DrivableArea("expansion", os.fspath(path), xy=np.asarray(xy, dtype=np.float64).reshape(-1, 2),
                        rings=np.asarray(rings, dtype=np.int64), polygons=np.asarray(polygons, dtype=np.int64))


# -- the dataset ----------------------------------------------------------------------------------


@dataclass
class SafetyData:
    """What the safety metrics need from one nuScenes version, keyed by sample token.

    ``poses``: CAM_FRONT keyframe ego pose (x, y, yaw) — the pose the trajectories are relative to;
    ``future``: the next keyframes of the scene (up to 6); ``map_of``: the map key of the sample's
    log; ``areas``: map key → :class:`DrivableArea`, or the reason there is none; ``boxes`` /
    ``classes`` / ``box_tokens``: the sample's annotated agents (K, 5) (global x, y, yaw, length,
    width), their class codes (K,) and tokens (those the ``agents`` filter keeps); ``annotated``: the version
    has any annotation; ``pose_reasons``: sample → why its ego pose is unusable; ``bad_boxes``: sample → why
    one of its annotations is refused (frames whose six later keyframes include it get collision n/a);
    ``agents``: the filter of :data:`AGENT_FILTERS` applied.
    """

    dataroot: str
    version: str
    poses: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    future: dict[str, list[str]] = field(default_factory=dict)
    map_of: dict[str, str] = field(default_factory=dict)
    areas: dict[str, DrivableArea | str] = field(default_factory=dict)
    boxes: dict[str, np.ndarray] = field(default_factory=dict)
    classes: dict[str, np.ndarray] = field(default_factory=dict)
    box_tokens: dict[str, list[str]] = field(default_factory=dict)
    annotated: bool = False
    warnings: list[str] = field(default_factory=list)
    pose_reasons: dict[str, str] = field(default_factory=dict)
    bad_boxes: dict[str, str] = field(default_factory=dict)
    agents: str = "all"
    #: with ``history`` > 0 (the planning score): sample → its earlier keyframes, nearest first; the poses of those
    #: and of the later keyframes are in ``poses`` too, ``box_instances`` holds each box's instance token and
    #: ``timestamps`` each read sample's timestamp (µs)
    past: dict[str, list[str]] = field(default_factory=dict)
    box_instances: dict[str, list[str | None]] = field(default_factory=dict)
    timestamps: dict[str, float] = field(default_factory=dict)

    def area_kinds(self) -> list[str]:
        """The kinds of drivable area in use (``expansion``, ``mask``), sorted."""
        return sorted({a.kind for a in self.areas.values() if isinstance(a, DrivableArea)})


def _table(root: Path, name: str) -> list[dict[str, Any]]:
    path = root / f"{name}.json"
    try:
        with open(path, encoding="utf-8") as f:
            rows = json.load(f)
    except FileNotFoundError:
        raise DatasetError(f"nuScenes table {path} is missing") from None
    except RecursionError:
        raise DatasetError(f"nuScenes table {path} cannot be read: the JSON is nested too deep") from None
    except (OSError, ValueError) as exc:
        raise DatasetError(f"nuScenes table {path} cannot be read: {exc}") from None
    if not isinstance(rows, list):
        raise DatasetError(f"nuScenes table {path} is not a list of records")
    for i, row in enumerate(rows):
        if not isinstance(row, dict) or not isinstance(row.get("token"), str):
            raise DatasetError(f"nuScenes table {path}: record {i} is not an object with a string token")
    return rows


def _yaw(q: Any) -> float:
    """Yaw (rad) of a nuScenes rotation under the frame reader's rule
    (:func:`lightemma.frames.geometry.unit_quaternion`): a quaternion that is not a unit one raises ``ValueError``."""
    from lightemma.frames.geometry import unit_quaternion, yaw_from_quaternion

    return float(yaw_from_quaternion(unit_quaternion(q)))


def _finite(values: Any, n: int) -> list[float] | None:
    """The first ``n`` entries of ``values`` as floats when they are finite numbers (bools, text refused), else None."""
    if not isinstance(values, (list, tuple)) or len(values) < n:
        return None
    out = []
    for v in values[:n]:
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            return None
        try:
            f = float(v)
        except OverflowError:
            return None
        if not math.isfinite(f):
            return None
        out.append(f)
    return out


def _box(ann: Mapping[str, Any], where: str = "sample_annotation") -> tuple[float, float, float, float, float]:
    """(x, y, yaw, length, width) of a sample_annotation; a box that is not a box raises :class:`DatasetError`
    naming ``where`` (the table file) and the token: a centre that is not finite or beyond
    :data:`MAX_COORDINATE_M`, a size not in (0, :data:`MAX_AGENT_SIZE_M`] m, a rotation that is not a unit
    quaternion (the frame reader's rule)."""
    tok = ann.get("token", "?")
    xy, size = _finite(ann.get("translation"), 2), _finite(ann.get("size"), 2)
    shown = f"size {ann.get('size')}, translation {ann.get('translation')}, rotation {ann.get('rotation')}"
    if xy is None or size is None:
        raise DatasetError(f"{where} {tok}: degenerate box ({shown}); translation and size must be finite numbers")
    w, length = size  # nuScenes size = (width, length, height)
    sized = 0 < w <= MAX_AGENT_SIZE_M and 0 < length <= MAX_AGENT_SIZE_M
    if not sized or max(abs(xy[0]), abs(xy[1])) > MAX_COORDINATE_M:
        raise DatasetError(f"{where} {tok}: degenerate box ({shown}); sizes must be in (0, {MAX_AGENT_SIZE_M:g}] m "
                           f"and the centre within ±{MAX_COORDINATE_M:g} m")
    try:
        yaw = _yaw(ann.get("rotation"))
    except ValueError as exc:
        raise DatasetError(f"{where} {tok}: field rotation = {ann.get('rotation')!r} {exc}") from None
    return xy[0], xy[1], yaw, length, w


def _keeps(ann: Mapping[str, Any], agents: str, v0_40: set[str]) -> bool:
    """Whether the ``agents`` filter (:data:`AGENT_FILTERS`) keeps an annotation; counts that are not counts
    raise ``ValueError``."""
    if agents == "valid":
        counts = [ann.get("num_lidar_pts"), ann.get("num_radar_pts")]
        if not all(isinstance(c, int) and not isinstance(c, bool) and c >= 0 for c in counts):
            raise ValueError(f"num_lidar_pts / num_radar_pts = {counts} are not counts "
                             "(the 'valid' agent filter needs them)")
        return counts[0] + counts[1] > 0
    if agents == "visible":
        return _ref(ann, "visibility_token") not in v0_40
    return True


def _ref(record: Mapping[str, Any], field: str) -> str | None:
    """A token a record refers to, or None when the field is not text (a list would not even be a dict key)."""
    value = record.get(field)
    return value if isinstance(value, str) else None


def _file_problem(path: Path) -> str | None:
    """Why a map file that is there cannot be read as one (a FIFO, a device, a folder), or None."""
    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        return f"{path} cannot be read: {exc.strerror or exc}"
    return None if stat.S_ISREG(mode) else f"{path} is not a regular file ({_file_kind(mode)})"


#: a map location as nuScenes names them (singapore-onenorth, boston-seaport): letters, digits, - and _, no path
_MAP_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,99}")


def load_safety_data(dataroot: str | os.PathLike[str], version: str, *, samples: set[str] | None = None,
                     agents: str = "all", history: int = 0) -> SafetyData:
    """Read poses, agents and drivable areas of ``dataroot/version`` (only ``samples`` and their futures if given).

    The drivable area of a log is the map expansion's ``drivable_area`` (``maps/expansion/<location>.json``)
    where the dataroot has it, else the base map mask of the ``map`` table that lists the log; an expansion
    path that is there but not a regular file (a FIFO, a link to a device) is that map's n/a reason, not a
    silent fall-back to the mask. Maps that cannot be read, ego poses that are not poses (rotation under the
    frame reader's unit-quaternion rule) and annotation boxes that are not boxes (:func:`_box`) are
    recorded as reasons (the frames they touch get n/a), not raised. ``agents``: which boxes count
    (:data:`AGENT_FILTERS`). ``history`` > 0 (the planning score, :mod:`lightemma.evaluation.planning_score`) also
    reads up to that many earlier keyframes of each sample (``past``), the poses of the earlier and later
    keyframes, the boxes of the keyframe just before, each box's instance token and the samples' timestamps;
    what the safety metrics read is the same either way. A table that is missing, unreadable or holds a record
    that is not an object raises :class:`DatasetError` naming the file.
    """
    if agents not in AGENT_FILTERS:
        raise ValueError(f"unknown agent filter {agents!r}; choose one of {', '.join(AGENT_FILTERS)}")
    root = Path(dataroot).expanduser()
    tables = root / version
    if not tables.is_dir():
        raise DatasetError(f"{tables} is not a folder: no nuScenes version {version!r} under {root}")
    data = SafetyData(os.fspath(root), version, agents=agents)
    channel_of_sensor = {s["token"]: s.get("channel") for s in _table(tables, "sensor")}
    channel_of_cs = {c["token"]: channel_of_sensor.get(_ref(c, "sensor_token"))
                     for c in _table(tables, "calibrated_sensor")}
    sample_rows = _table(tables, "sample")
    by_token = {s["token"]: s for s in sample_rows}
    wanted = set(by_token) if samples is None else {t for t in samples if t in by_token}
    # the scene's next keyframes
    for tok in list(wanted):
        chain, nxt = [], by_token[tok].get("next", "")
        while isinstance(nxt, str) and nxt and len(chain) < STEPS and nxt in by_token:
            chain.append(nxt)
            nxt = by_token[nxt].get("next", "")
        data.future[tok] = chain
    needed = wanted | {t for c in data.future.values() for t in c}
    posed, boxed = wanted, needed
    if history > 0:
        for tok in wanted:
            chain, prv = [], by_token[tok].get("prev", "")
            while isinstance(prv, str) and prv and len(chain) < history and prv in by_token:
                chain.append(prv)
                prv = by_token[prv].get("prev", "")
            data.past[tok] = chain
        posed = needed | {t for c in data.past.values() for t in c}
        boxed = needed | {c[0] for c in data.past.values() if c}
        for tok in posed:
            stamp = by_token[tok].get("timestamp")
            if isinstance(stamp, (int, float)) and not isinstance(stamp, bool) and math.isfinite(stamp):
                data.timestamps[tok] = float(stamp)
    pose_token: dict[str, str] = {}
    for sd in _table(tables, "sample_data"):
        st, cs = sd.get("sample_token"), sd.get("calibrated_sensor_token")
        front = isinstance(cs, str) and channel_of_cs.get(cs) == "CAM_FRONT"
        ep_token = sd.get("ego_pose_token")
        if sd.get("is_key_frame") and isinstance(st, str) and st in posed and front and isinstance(ep_token, str):
            pose_token[st] = ep_token
    by_pose = {tok: st for st, tok in pose_token.items()}
    for ep in _table(tables, "ego_pose"):
        st = by_pose.get(ep["token"])
        if st is None:
            continue
        xy = _finite(ep.get("translation"), 2)
        try:
            yaw = _yaw(ep.get("rotation"))
        except ValueError as exc:  # no usable pose: the frame reads n/a with the reason
            data.pose_reasons[st] = f"{tables / 'ego_pose.json'}: ego_pose {ep['token']}: field rotation {exc}"
            continue
        if xy is None or max(abs(xy[0]), abs(xy[1])) > MAX_COORDINATE_M:
            data.pose_reasons[st] = (f"{tables / 'ego_pose.json'}: ego_pose {ep['token']}: field translation = "
                                     f"{ep.get('translation')!r} is not finite numbers within ±{MAX_COORDINATE_M:g} m")
            continue
        data.poses[st] = (xy[0], xy[1], yaw)
    # maps: scene → log → location, map record of the log
    scene_log = {s["token"]: _ref(s, "log_token") for s in _table(tables, "scene")}
    logs = {lg["token"]: lg for lg in _table(tables, "log")}
    mask_of_log: dict[str, str] = {}
    map_record: dict[str, dict] = {}
    for rec in _table(tables, "map"):
        log_tokens = rec.get("log_tokens", [])
        for lt in log_tokens if isinstance(log_tokens, list) else []:
            if isinstance(lt, str):
                mask_of_log[lt] = rec.get("filename", "")
                map_record[lt] = rec
    for tok in wanted:
        log_token = scene_log.get(_ref(by_token[tok], "scene_token"))
        log = logs.get(log_token or "")
        if log is None:
            continue
        location = str(log.get("location", ""))
        if not _MAP_NAME.fullmatch(location):  # a name, never a path: "../../x" would read a file outside the dataroot
            key = f"location:{location}"
            data.map_of[tok] = key
            data.areas[key] = f"log {log.get('logfile', log_token)}: location {location!r} is not a map name"
            continue
        expansion = root / "maps" / "expansion" / f"{location}.json"
        there = os.path.lexists(expansion)
        key = f"expansion:{location}" if there else f"mask:{mask_of_log.get(log_token, '')}"
        data.map_of[tok] = key
        if key in data.areas:
            continue
        try:
            if key.startswith("expansion:"):
                problem = _file_problem(expansion)  # never a silent fall-back to the mask
                data.areas[key] = f"map expansion {problem}" if problem else read_expansion(expansion)
            elif not mask_of_log.get(log_token):
                data.areas[key] = f"log {log.get('logfile', log_token)} has no map record"
            else:
                from lightemma.frames import dataset_path

                mask_path = Path(dataset_path(root, map_record[log_token], "map"))  # inside the dataroot, or n/a with why
                there = os.path.lexists(mask_path)
                data.areas[key] = read_map_mask(mask_path) if there else f"map mask {mask_path} is missing"
        except DatasetError as exc:
            data.areas[key] = str(exc)
    # agents
    annotations = _table(tables, "sample_annotation")
    data.annotated = bool(annotations)
    if data.annotated:
        categories = {c["token"]: str(c.get("name", "")) for c in _table(tables, "category")}
        klass = {i["token"]: agent_class(categories.get(_ref(i, "category_token"), ""))
                 for i in _table(tables, "instance")}
        v0_40 = set()
        if agents == "visible":
            v0_40 = {v["token"] for v in _table(tables, "visibility") if v.get("level") == "v0-40"}
        where = os.fspath(tables / "sample_annotation.json")
        gathered: dict[str, tuple[list, list, list, list]] = {}
        for ann in annotations:
            st = _ref(ann, "sample_token")
            if st not in boxed:
                continue
            cls = klass.get(_ref(ann, "instance_token"), OTHER)
            if cls == OTHER:
                continue
            try:
                if not _keeps(ann, agents, v0_40):
                    continue
                box = _box(ann, where)
            except DatasetError as exc:
                data.bad_boxes.setdefault(st, str(exc))
                continue
            except ValueError as exc:
                data.bad_boxes.setdefault(st, f"{where} {ann['token']}: {exc}")
                continue
            b, c, t, inst = gathered.setdefault(st, ([], [], [], []))
            b.append(box)
            c.append(cls)
            t.append(ann["token"])
            inst.append(_ref(ann, "instance_token"))
        for st in boxed:
            b, c, t, inst = gathered.get(st, ([], [], [], []))
            data.boxes[st] = np.asarray(b, dtype=np.float64).reshape(-1, 5)
            data.classes[st] = np.asarray(c, dtype=np.int8)
            data.box_tokens[st] = t
            if history > 0:
                data.box_instances[st] = inst
    return data


# -- per-frame outcomes ------------------------------------------------------------------------


@dataclass
class FrameSafety:
    """Per-frame safety outcomes of N trajectories.

    ``area``: (N, 6, 5) uint8 lookups (4 corners, then the reference point), valid where
    ``area_ok``; ``collide``: (N, 6, 2) bool overlap with a vehicle / a vulnerable road user at each
    step, valid where ``coll_ok``; ``area_reason`` / ``coll_reason``: why a frame has no value ("" when
    it has one); ``area_kind``: per frame ``expansion`` / ``mask`` / "".
    """

    area: np.ndarray
    area_ok: np.ndarray
    area_reason: list[str]
    area_kind: list[str]
    collide: np.ndarray
    coll_ok: np.ndarray
    coll_reason: list[str]

    @property
    def off_steps(self) -> np.ndarray:
        """(N, 6) bool: some corner of the footprint is off the drivable area (or off the mask image)."""
        return (self.area[:, :, :4] != ON).any(axis=2)

    @property
    def outside_mask(self) -> np.ndarray:
        """(N,) bool: some tested point fell outside the mask image (counted off, reported)."""
        return (self.area == OUTSIDE).any(axis=(1, 2)) & self.area_ok


def frame_safety(traj: Any, sample_tokens: Sequence[str], data: SafetyData, ego: EgoModel = EGO) -> FrameSafety:
    """Outcomes of trajectories (N, 6, 2), each in the ego frame of keyframe ``sample_tokens[i]``.

    Frames without a pose, a map, six future keyframes or annotations (or with a non-finite
    trajectory) get ``*_ok`` False and a reason; nothing is silently 0.
    """
    traj = np.ascontiguousarray(traj, dtype=np.float64)
    n = len(sample_tokens)
    if traj.shape != (n, STEPS, 2):
        raise ValueError(f"trajectories must have shape ({n}, {STEPS}, 2), got {traj.shape}")
    finite = np.isfinite(traj).all(axis=(1, 2))
    poses = np.zeros((n, 3))
    has_pose = np.zeros(n, dtype=bool)
    for i, st in enumerate(sample_tokens):
        if st in data.poses:
            poses[i], has_pose[i] = data.poses[st], True
    usable = finite & has_pose
    safe_traj = np.where(usable[:, None, None], traj, 0.0)

    def base_reason(i: int) -> str:
        if not has_pose[i]:
            why = data.pose_reasons.get(sample_tokens[i])
            if why:
                return f"unusable CAM_FRONT ego pose: {why}"
            return f"no CAM_FRONT ego pose for sample {sample_tokens[i]} in {data.version}"
        return "" if finite[i] else "no trajectory"

    # drivable area, per map
    area = np.zeros((n, STEPS, 5), dtype=np.uint8)
    area_ok = np.zeros(n, dtype=bool)
    area_reason = [base_reason(i) for i in range(n)]
    area_kind = [""] * n
    by_map: dict[str, list[int]] = {}
    for i, st in enumerate(sample_tokens):
        key = data.map_of.get(st)
        if key is None:
            area_reason[i] = area_reason[i] or f"sample {st} has no log/map in {data.version}"
        elif usable[i]:
            by_map.setdefault(key, []).append(i)
    for key, rows in by_map.items():
        found = data.areas.get(key)
        if not isinstance(found, DrivableArea):
            for i in rows:
                area_reason[i] = f"no drivable area: {found}"
            continue
        idx = np.asarray(rows)
        area[idx] = found.lookup(safe_traj[idx], poses[idx], ego)
        area_ok[idx] = True
        for i in rows:
            area_kind[i] = found.kind

    # collisions
    collide = np.zeros((n, STEPS, 2), dtype=bool)
    coll_ok = np.zeros(n, dtype=bool)
    coll_reason = [base_reason(i) for i in range(n)]
    if not data.annotated:
        coll_reason = ["no annotations"] * n
    else:
        rows = []
        for i, st in enumerate(sample_tokens):
            if coll_reason[i]:
                continue
            if len(data.future.get(st, [])) < STEPS:
                coll_reason[i] = f"sample {st} has fewer than {STEPS} later keyframes"
                continue
            bad = next((data.bad_boxes[f] for f in data.future[st] if f in data.bad_boxes), None)
            if bad is not None:
                coll_reason[i] = f"a refused annotation: {bad}"
                continue
            rows.append(i)
        if rows:
            idx = np.asarray(rows)
            slots = max(1, max(len(data.boxes[f]) for i in rows for f in data.future[sample_tokens[i]]))
            agents = np.full((len(rows), STEPS, slots, 5), np.nan)
            classes = np.full((len(rows), STEPS, slots), -1, dtype=np.int8)
            for r, i in enumerate(rows):
                for k, ft in enumerate(data.future[sample_tokens[i]]):
                    b = data.boxes[ft]
                    agents[r, k, : len(b)] = b
                    classes[r, k, : len(b)] = data.classes[ft]
            hits = box_collisions(safe_traj[idx], poses[idx], agents, ego)
            collide[idx, :, 0] = (hits & (classes == VEHICLE)).any(axis=2)
            collide[idx, :, 1] = (hits & (classes == VRU)).any(axis=2)
            coll_ok[idx] = True
    return FrameSafety(area, area_ok, area_reason, area_kind, collide, coll_ok, coll_reason)


# -- rates ---------------------------------------------------------------------------------------

#: per-frame value keys of :func:`safety_values`, in table order
AREA_KEYS = ("offroad", "offroad_1s", "offroad_2s", "offroad_3s", "offroad_centre")
COLLISION_KEYS = ("collision", "collision_1s", "collision_2s", "collision_3s", "collision_vehicle", "collision_vru")


def _collision_seconds(c: np.ndarray, convention: str) -> np.ndarray:
    """(N, 3) per-frame values at 1/2/3 s from per-step indicators c (N, 6) under a convention."""
    c = c.astype(np.float64)
    if convention == "uniad":
        return c[:, [1, 3, 5]]
    if convention == "stp3":
        return np.column_stack([c[:, : 2 * s].mean(axis=1) for s in SECONDS])
    if convention == "any":
        return np.column_stack([c[:, : 2 * s].max(axis=1) for s in SECONDS])
    raise ValueError(f"unknown collision convention {convention!r} (choose from {', '.join(COLLISION_CONVENTIONS)})")


def _summary(sec: np.ndarray, convention: str) -> np.ndarray:
    """The headline value per frame: the frame outcome (3 s) for ``any``, the mean of 1/2/3 s ("Avg.") otherwise."""
    return sec[:, 2] if convention == "any" else sec.mean(axis=1)


def safety_values(fs: FrameSafety, convention: str, *, gt: FrameSafety | None = None) -> dict[str, np.ndarray]:
    """Per-frame values (N,) of :data:`AREA_KEYS` and :data:`COLLISION_KEYS` under a collision convention.

    A rate is the mean of its values over frames; NaN marks a frame without a value (the reasons are
    in ``fs``). Off-road values do not depend on the convention: ``offroad`` = some corner of some step
    off the drivable area (NAVSIM's DAC), ``offroad_Ts`` = at step 2T, ``offroad_centre`` = the reference
    point (the devkit's own off-road test) at some step. With ``gt`` (the ground truth's outcomes on
    the same frames) ``uniad`` and ``stp3`` do not count a step where the ground truth collides too.
    """
    off = fs.off_steps
    na_area = ~fs.area_ok
    out: dict[str, np.ndarray] = {}
    out["offroad"] = off.any(axis=1).astype(np.float64)
    for s in SECONDS:
        out[f"offroad_{s}s"] = off[:, 2 * s - 1].astype(np.float64)
    out["offroad_centre"] = (fs.area[:, :, 4] != ON).any(axis=1).astype(np.float64)
    for key in AREA_KEYS:
        out[key][na_area] = np.nan
    per_class = fs.collide.copy()
    na_coll = ~fs.coll_ok
    if gt is not None and convention in ("uniad", "stp3"):
        gt_any = gt.collide.any(axis=2) & gt.coll_ok[:, None]
        per_class &= ~gt_any[:, :, None]
    both = per_class.any(axis=2)
    sec = _collision_seconds(both, convention)
    out["collision"] = _summary(sec, convention)
    for j, s in enumerate(SECONDS):
        out[f"collision_{s}s"] = sec[:, j]
    for c, name in enumerate(CLASS_NAMES):
        out[f"collision_{name}"] = _summary(_collision_seconds(per_class[:, :, c], convention), convention)
    for key in COLLISION_KEYS:
        out[key] = out[key].astype(np.float64)
        out[key][na_coll] = np.nan
    return out


def rates(values: Mapping[str, np.ndarray]) -> dict[str, float | None]:
    """The mean of each key's values over the frames that have one (None when none has)."""
    out: dict[str, float | None] = {}
    for key, v in values.items():
        ok = np.isfinite(v)
        out[key] = float(v[ok].mean()) if ok.any() else None
    return out


def na_reason(fs: FrameSafety, which: str) -> str | None:
    """Why no frame of ``fs`` has a value for ``which`` (``area`` / ``collision``), or None when some do."""
    ok, reasons = (fs.area_ok, fs.area_reason) if which == "area" else (fs.coll_ok, fs.coll_reason)
    if ok.any() or not len(reasons):
        return None
    counts: dict[str, int] = {}
    for r in reasons:
        if r:
            counts[r] = counts.get(r, 0) + 1
    return max(counts, key=counts.get) if counts else None


def frame_warnings(fs: FrameSafety, frame_ids: Sequence[str], what: str) -> list[str]:
    """One warning per kind of missing value, with a count and an example frame; mask coverage too."""
    out = []
    for which, ok, reasons in (("off-road", fs.area_ok, fs.area_reason), ("collision", fs.coll_ok, fs.coll_reason)):
        groups: dict[str, list[int]] = {}
        for i in np.flatnonzero(~ok):
            if reasons[i] and reasons[i] not in ("no trajectory", "no annotations"):
                groups.setdefault(reasons[i], []).append(int(i))
        for reason, rows in groups.items():
            out.append(f"{what}: {len(rows)} frame(s) have no {which} value (n/a): {reason} (e.g. {frame_ids[rows[0]]})")
    outside = np.flatnonzero(fs.outside_mask)
    if len(outside):
        out.append(f"{what}: the map mask does not cover the footprint of {len(outside)} frame(s) (e.g. {frame_ids[outside[0]]}); "
                   "those points count as off the drivable area")
    return out


# -- evaluation of runs ------------------------------------------------------------------------------

#: row keys this module adds to every accuracy row (values are shares 0..1; tables print %)
ROW_KEYS = (*AREA_KEYS, *COLLISION_KEYS, "offroad_ci95", "collision_ci95", "safety_frames", "offroad_frames", "collision_frames",
            "area_source", "offroad_na", "collision_na", "collision_convention")
FLOOR_LABEL = "Ground truth (floor)"
_NO_DATAROOT = "no dataroot (pass --dataroot and --version)"


def sample_token_of(frame_id: str) -> str:
    """The sample token in a frame id ``scene/sample_token``."""
    return frame_id.rsplit("/", 1)[-1]


@dataclass
class RunSafety:
    """One run's outcomes on its scored frames (model and ground truth), for tables, tests, tags and figures."""

    frame_ids: list[str]
    rows: np.ndarray
    model: FrameSafety | None
    truth: FrameSafety | None
    reason: str | None = None  # why there is nothing (no dataroot, unreadable dataset)
    data: SafetyData | None = None  # the dataset the outcomes come from (for figures)


@dataclass
class SafetyResult:
    """Safety rows per model and ADE convention, the ground-truth floor, and the per-frame outcomes."""

    rows: dict[str, dict[str, dict[str, Any]]]  # label -> ADE convention -> row keys
    floor: dict[str, dict[str, Any]]  # ADE convention -> row keys (ground truth, unmasked)
    runs: dict[str, RunSafety]
    warnings: list[str] = field(default_factory=list)
    gt_off_scenes: list[str] = field(default_factory=list)  # scenes whose ground truth leaves the drivable area
    gt_collision_scenes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {"floor": self.floor, "gt_off_road_scenes": self.gt_off_scenes, "gt_collision_scenes": self.gt_collision_scenes}


def _resolve_dataset(run: Any, dataroot: str | os.PathLike[str] | None, version: str | None) -> tuple[str, str] | str:
    """(dataroot, version) for a run: the given ones, else the run's manifest's; or the reason there is none
    (none recorded, or the recorded folder is gone)."""
    if dataroot is not None:
        if not version:
            return "--dataroot needs --version"
        return os.fspath(dataroot), version
    ds = run.info.dataset or {}
    root, ver = ds.get("dataroot"), ds.get("version")
    if isinstance(root, str) and root and isinstance(ver, str) and ver:
        if Path(root, ver).is_dir():
            return root, ver
        gone = root if not Path(root).is_dir() else os.path.join(root, ver)
        return f"recorded dataroot {gone} is gone; pass --dataroot"
    return _NO_DATAROOT


def _row(values: Mapping[str, np.ndarray], fs: FrameSafety, convention: str) -> dict[str, Any]:
    r = rates(values)
    area_ok, coll_ok = np.isfinite(values["offroad"]), np.isfinite(values["collision"])
    kinds = sorted({k for k in fs.area_kind if k})
    return {**r, "safety_frames": int(len(fs.area_ok)), "offroad_frames": int(area_ok.sum()), "collision_frames": int(coll_ok.sum()),
            "area_source": "+".join(kinds) if kinds else None, "offroad_na": None if area_ok.any() else (na_reason(fs, "area") or "no frame"),
            "collision_na": None if coll_ok.any() else (na_reason(fs, "collision") or "no frame"), "collision_convention": convention}


def _intervals(groups: list[tuple[np.ndarray, np.ndarray]], keys: list[str], resampling: Any) -> np.ndarray:
    from lightemma.evaluation.stats import bootstrap_ci

    if not groups or not resampling.n_resamples:
        return np.full((len(groups), 1, 2), np.nan)
    return bootstrap_ci(groups, keys, resampling)


def _rate_intervals(groups: list[tuple[np.ndarray, np.ndarray]], resampling: Any) -> np.ndarray:
    """(R, 1, 2) intervals of rates: exact binomial on the scene-clustered effective sample size, never [0, 0]
    at a rate of 0 (:func:`lightemma.evaluation.stats.rate_ci`, docs/statistics.md#rates)."""
    from lightemma.evaluation.stats import rate_ci

    return rate_ci(groups, resampling)


def _scenes(frame_ids: Sequence[str]) -> np.ndarray:
    """Scene names of frame ids ``scene/sample_token`` (the clusters of the scene bootstrap)."""
    return np.asarray([f.rsplit("/", 1)[0] for f in frame_ids], dtype=object)


def evaluate_safety(
    entries: Sequence[tuple[str, Any, np.ndarray]],
    conventions: Sequence[str],
    resampling: Any,
    *,
    dataroot: str | os.PathLike[str] | None = None,
    version: str | None = None,
    ego: EgoModel = EGO,
    agents: str = "all",
    history: int = 0,
) -> SafetyResult:
    """Safety rows for evaluated runs: ``entries`` = (label, RunData, scored rows) as in :func:`evaluate_loaded`.

    Each ADE convention's table shows the collision convention of the same name (``lightemma`` → ``any``);
    off-road values are the same in every table. Intervals: :func:`_rate_intervals`. The floor is the
    ground truth's own (unmasked) rates over every frame with usable ground truth in any run. ``agents``:
    which annotation boxes count (:data:`AGENT_FILTERS`). A run whose ground truth moves faster than
    :data:`lightemma.frames.geometry.POSE_JUMP_SPEED` between keyframes gets a warning (a pose jump). ``history``:
    as :func:`load_safety_data` (the planning score reuses the data read here).
    """
    warnings: list[str] = []
    for label, run, _ in entries:  # every frame with ground truth, scored or not
        warnings.extend(pose_jump_warnings(run.gt_positions, run.frame_ids, label))
    datasets: dict[tuple[str, str], list[int]] = {}
    resolved = []
    for i, (_, run, _) in enumerate(entries):
        ds = _resolve_dataset(run, dataroot, version)
        resolved.append(ds)
        if isinstance(ds, tuple):
            datasets.setdefault(ds, []).append(i)
    loaded: dict[tuple[str, str], SafetyData | str] = {}
    for ds, members in datasets.items():
        tokens = {sample_token_of(f) for i in members for f in entries[i][1].frame_ids}
        try:
            loaded[ds] = load_safety_data(ds[0], ds[1], samples=tokens, agents=agents, history=history)
        except DatasetError as exc:
            loaded[ds] = str(exc)
            warnings.append(f"safety metrics: {exc}")
    result = SafetyResult(rows={}, floor={}, runs={}, warnings=warnings)
    groups: list[tuple[np.ndarray, np.ndarray]] = []
    keys: list[str] = []
    slots: list[tuple[str, str, str]] = []
    floor_frames: dict[str, tuple[np.ndarray, str, Any]] = {}
    for (label, run, rows), ds in zip(entries, resolved):
        data = loaded.get(ds) if isinstance(ds, tuple) else None
        reason = ds if isinstance(ds, str) else (data if isinstance(data, str) else None)
        fids = [run.frame_ids[i] for i in rows]
        if reason is not None or not isinstance(data, SafetyData):
            result.runs[label] = RunSafety(fids, rows, None, None, reason)
            na = {k: None for k in ROW_KEYS}
            result.rows[label] = {c: {**na, "offroad_na": reason, "collision_na": reason, "collision_convention": COLLISION_FOR_ADE[c]} for c in conventions}
            continue
        tokens = [sample_token_of(f) for f in fids]
        conflicts = _recorded_pose_conflicts(run, fids, tokens, data, warnings, label) if getattr(run.info, "imported", False) else {}
        model = frame_safety(run.trajectory[rows], tokens, data, ego)
        truth = frame_safety(run.gt_positions[rows], tokens, data, ego)
        for j, why in conflicts.items():
            for fs in (model, truth):
                fs.area_ok[j] = fs.coll_ok[j] = False
                fs.area_reason[j] = fs.coll_reason[j] = why
        result.runs[label] = RunSafety(fids, rows, model, truth, data=data)
        warnings.extend(frame_warnings(model, fids, label))
        result.rows[label] = {}
        scenes = _scenes(fids)
        for c in conventions:
            cc = COLLISION_FOR_ADE[c]
            values = safety_values(model, cc, gt=truth)
            result.rows[label][c] = _row(values, model, cc)
            for key in ("offroad", "collision"):
                ok = np.isfinite(values[key])
                if ok.sum() > 0:
                    groups.append((values[key][ok], scenes[ok]))
                    keys.append(f"safety|{label}|{cc}|{key}")
                    slots.append((label, c, key))
        for j, fid in enumerate(fids):
            if j in conflicts:
                continue
            floor_frames.setdefault(fid, (run.gt_positions[rows[j]], tokens[j], data))
    # the floor: every frame's ground truth once
    if floor_frames:
        by_data: dict[int, list[str]] = {}
        for fid, (_, _, data) in floor_frames.items():
            by_data.setdefault(id(data), []).append(fid)
        parts = []
        for fids in by_data.values():
            data = floor_frames[fids[0]][2]
            gt = np.stack([floor_frames[f][0] for f in fids])
            parts.append((fids, frame_safety(gt, [floor_frames[f][1] for f in fids], data, ego)))
        fids = [f for p in parts for f in p[0]]
        truth = _concat([p[1] for p in parts])
        scenes = _scenes(fids)
        warnings.extend(frame_warnings(truth, fids, "ground truth"))
        off = truth.off_steps.any(axis=1) & truth.area_ok
        hit = truth.collide.any(axis=(1, 2)) & truth.coll_ok
        result.gt_off_scenes = sorted({f.rsplit("/", 1)[0] for f, o in zip(fids, off) if o})
        result.gt_collision_scenes = sorted({f.rsplit("/", 1)[0] for f, o in zip(fids, hit) if o})
        if result.gt_off_scenes:
            warnings.append(f"the ground truth itself leaves the drivable area in {int(off.sum())} frame(s) of scene(s) "
                            f"{', '.join(result.gt_off_scenes[:10])}{' …' if len(result.gt_off_scenes) > 10 else ''} (the floor row counts them)")
        for c in conventions:
            cc = COLLISION_FOR_ADE[c]
            values = safety_values(truth, cc)  # unmasked: the ground truth's own rate
            result.floor[c] = {"model": FLOOR_LABEL, **_row(values, truth, cc)}
            for key in ("offroad", "collision"):
                ok = np.isfinite(values[key])
                if ok.sum() > 0:
                    groups.append((values[key][ok], scenes[ok]))
                    keys.append(f"safety|{FLOOR_LABEL}|{cc}|{key}")
                    slots.append((FLOOR_LABEL, c, key))
    ci = _rate_intervals(groups, resampling)
    for (label, c, key), pair in zip(slots, ci[:, 0]):
        target = result.floor[c] if label == FLOOR_LABEL else result.rows[label][c]
        target[f"{key}_ci95"] = [float(pair[0]), float(pair[1])] if np.isfinite(pair).all() else None
    return result


#: nuScenes keyframes are 0.5 s apart (2 Hz): the step of the ground-truth check below
KEYFRAME_SECONDS = 0.5


def pose_jump_warnings(gt: Any, frame_ids: Sequence[str], label: str) -> list[str]:
    """One warning when some frame's ground truth (N, 6, 2) (m, ego frame; p_0 the origin) moves faster than
    :data:`lightemma.frames.geometry.POSE_JUMP_SPEED` over a :data:`KEYFRAME_SECONDS` step: an ego pose that
    jumps in the dataset (its frames' ADE and safety values are then measured against a wrong ground truth)."""
    from lightemma.frames.geometry import POSE_JUMP_SPEED

    if not len(frame_ids):
        return []
    gt = np.asarray(gt, dtype=np.float64).reshape(len(frame_ids), -1, 2)
    pts = np.concatenate([np.zeros((len(gt), 1, 2)), gt], axis=1)
    with np.errstate(invalid="ignore"):
        step = np.linalg.norm(np.diff(pts, axis=1), axis=2).max(axis=1)
    bad = np.flatnonzero(step > POSE_JUMP_SPEED * KEYFRAME_SECONDS)  # NaN (no ground truth) is not a jump
    if not len(bad):
        return []
    worst = int(bad[np.argmax(step[bad])])
    most = POSE_JUMP_SPEED * KEYFRAME_SECONDS
    return [(f"{label}: the ground truth of {len(bad)} frame(s) moves more than {most:g} m "
             f"in one {KEYFRAME_SECONDS:g} s step (over {POSE_JUMP_SPEED:g} m/s: a physically impossible ego pose jump "
             f"in the dataset; e.g. {frame_ids[worst]}: {step[worst]:.1f} m); their ADE and safety values are measured "
             "against it")]


#: an imported frame whose recorded pose is further than this from the dataroot's is not placed (n/a)
POSE_CONFLICT_M = 5.0
POSE_NOTE_M = 0.05  # smaller differences are sensor timing (CAM_FRONT vs another channel's pose), noted only


def _recorded_pose_conflicts(run: Any, fids: list[str], tokens: list[str], data: SafetyData, warnings: list[str], label: str) -> dict[int, str]:
    """Compare an imported run's recorded global position and heading (``ego_position``, ``ego_heading``) with
    the dataroot's pose of the same sample; frames that disagree by more than :data:`POSE_CONFLICT_M` get n/a."""
    from lightemma.evaluation.loading import read_frame_records

    records = read_frame_records(run.info.run_dir, fids)
    out: dict[int, str] = {}
    worst, noted = 0.0, 0
    for j, (fid, tok) in enumerate(zip(fids, tokens)):
        rec, pose = records.get(fid, {}), data.poses.get(tok)
        pos, heading = rec.get("ego_position"), rec.get("ego_heading")
        if pose is None or not isinstance(pos, list) or len(pos) < 2:
            continue
        try:
            d = math.hypot(float(pos[0]) - pose[0], float(pos[1]) - pose[1])
            dh = abs((float(heading) - pose[2] + math.pi) % (2 * math.pi) - math.pi) if heading is not None else 0.0
        except (TypeError, ValueError):
            continue
        if d > POSE_CONFLICT_M:
            out[j] = f"the recorded ego position is {d:.1f} m from {data.version}'s pose of sample {tok} (another dataset?)"
        elif d > POSE_NOTE_M or dh > 1e-3:
            noted += 1
            worst = max(worst, d)
    if out:
        warnings.append(f"{label}: {len(out)} frame(s) have no safety value: {next(iter(out.values()))} (is --dataroot the dataset the run was made on?)")
    if noted:
        warnings.append(f"{label}: the recorded pose differs from {data.version}'s CAM_FRONT pose in {noted} frame(s), by up to {worst:.2f} m "
                        "(the dataroot's pose is used)")
    return out


def _concat(parts: Sequence[FrameSafety]) -> FrameSafety:
    if len(parts) == 1:
        return parts[0]
    return FrameSafety(np.concatenate([p.area for p in parts]), np.concatenate([p.area_ok for p in parts]), [r for p in parts for r in p.area_reason],
                       [k for p in parts for k in p.area_kind], np.concatenate([p.collide for p in parts]),
                       np.concatenate([p.coll_ok for p in parts]), [r for p in parts for r in p.coll_reason])


def pairwise_safety(result: SafetyResult, labels: Sequence[str], convention: str, resampling: Any, *, only: set[str] | None = None) -> list[dict[str, Any]]:
    """Every pair of runs (a before b) on the frames where both have a value: mean paired difference a − b of
    ``offroad`` and of ``collision`` (the collision convention of ``convention``'s table), scene-bootstrap
    interval, sign-flip p-value over scenes, Holm over all pairs and both metrics. Rows as :func:`pairwise_ade`'s,
    with ``metric`` and ``diff``."""
    from lightemma.evaluation.stats import mark_holm, sign_flip_p

    cc = COLLISION_FOR_ADE[convention]
    per: dict[str, dict[str, dict[str, float]]] = {}
    scene_of: dict[str, str] = {}
    for label in labels:
        rs = result.runs.get(label)
        if rs is None or rs.model is None:
            continue
        values = safety_values(rs.model, cc, gt=rs.truth)
        per[label] = {}
        for key in ("offroad", "collision"):
            per[label][key] = {f: float(v) for f, v in zip(rs.frame_ids, values[key]) if math.isfinite(v) and (only is None or f in only)}
        for f in rs.frame_ids:
            scene_of.setdefault(f, f.rsplit("/", 1)[0])
    codes: dict[str, int] = {}
    out, groups, keys, where = [], [], [], []
    for key in ("offroad", "collision"):
        for a in range(len(labels)):
            for b in range(a + 1, len(labels)):
                la, lb = labels[a], labels[b]
                row: dict[str, Any] = {"model_a": la, "model_b": lb, "metric": key, "convention": cc, "frames": 0, "scenes": 0, "diff": None, "ci95": None, "p_value": None}
                if la in per and lb in per:
                    common = sorted(set(per[la][key]) & set(per[lb][key]))
                    if common:
                        d = np.array([per[la][key][f] - per[lb][key][f] for f in common])
                        sc = np.array([codes.setdefault(scene_of[f], len(codes)) for f in common])
                        row.update(frames=len(common), scenes=int(len(np.unique(sc))), diff=float(d.mean()))
                        groups.append((d, sc))
                        keys.append(f"{la}|{lb}|{cc}|{key}")
                        where.append(len(out))
                out.append(row)
    if groups and resampling.n_resamples:
        ci = _intervals(groups, keys, resampling)
        p = sign_flip_p(groups, keys, resampling)
        for k, i in enumerate(where):
            pair = ci[k, 0]
            out[i]["ci95"] = [float(pair[0]), float(pair[1])] if np.isfinite(pair).all() else None
            out[i]["p_value"] = None if np.isnan(p[k]) else float(p[k])
    mark_holm(out, resampling.confidence)
    return out


def frame_tags(rs: RunSafety) -> dict[str, np.ndarray]:
    """Scenario tags of a run's scored frames from the model's own outcomes: ``collides`` (any step, any
    agent) and ``off_road`` (some corner off the drivable area at some step); False where n/a."""
    n = len(rs.frame_ids)
    if rs.model is None:
        return {"collides": np.zeros(n, bool), "off_road": np.zeros(n, bool)}
    return {"collides": rs.model.collide.any(axis=(1, 2)) & rs.model.coll_ok, "off_road": rs.model.off_steps.any(axis=1) & rs.model.area_ok}
