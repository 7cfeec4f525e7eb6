"""nuScenes' maps as lightemma reads them: base map masks (``maps/<token>.png``) and map expansions
(``maps/expansion/<location>.json``: the drivable area, and the lane and intersection layers of the planning score).

Read without the devkit, by its conventions (``MapMask`` at 0.1 m/px, ``NuScenesMap``'s layers), every file through
:func:`lightemma._files.read_regular_file` or a PNG header check first. What is read is returned parsed — a
:class:`DrivableArea`, an :class:`ExpansionLayers` — for the safety metrics and the planning score, which never open
map files themselves. Problems are :class:`~lightemma.errors.DatasetError` naming the file (and node or record).
"""

from __future__ import annotations

import json
import math
import os
import re
import stat
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypedDict

import numpy as np

from lightemma._files import FileRefused, file_kind, read_regular_file
from lightemma.definitions import EGO_LENGTH, EGO_OFFSET, EGO_WIDTH, MIN_STEP
from lightemma.errors import DatasetError
from lightemma.nuscenes.geometry import MAX_COORDINATE_M

#: the base map masks' native resolution (the devkit's MapMask), metres per pixel
MASK_RESOLUTION = 0.1
MASK_FOREGROUND = 255
#: the largest base map mask read, pixels (width × height from the PNG header, checked before decoding):
#: nuScenes' largest map, singapore-queenstown, spans about 3,229 m × 3,687 m, 1.19 G pixels at 0.1 m/px;
#: a larger header is refused (a 437 KB 1-bit PNG can claim 60,000² pixels: 3.6 GB decoded)
MAX_MASK_PIXELS = 1_500_000_000
#: the largest map expansion read, bytes: far above nuScenes' largest (v1.3, tens of MB); a larger file, a FIFO or a
#: device is refused before it is read
MAX_EXPANSION_BYTES = 4 * 2**30


class EgoKwargs(TypedDict):
    """The ego box as the safety kernels take it, metres (``_core.ego_poses``, ``_core.mask_area`` and the like)."""

    length: float
    width: float
    offset: float
    min_step: float


def _ego_kwargs(ego: Any) -> EgoKwargs:
    """The footprint keywords of the kernels: ``ego.kwargs()`` (an :class:`lightemma.evaluation.safety.EgoModel`), or
    lightemma's ego box (:mod:`lightemma.definitions`) when ``ego`` is None."""
    if ego is not None:
        kwargs: EgoKwargs = ego.kwargs()
        return kwargs.copy()
    return {"length": EGO_LENGTH, "width": EGO_WIDTH, "offset": EGO_OFFSET, "min_step": MIN_STEP}


@dataclass
class DrivableArea:
    """A map's drivable area: the map expansion's ``drivable_area`` polygons, or a base map mask.

    ``kind``: ``expansion`` (exact point-in-polygon against the union of the layer's polygons,
    holes honoured) or ``mask`` (the devkit's ``MapMask``: pixel (round(x/0.1), round(−y/0.1 + H)),
    NumPy's round, drivable where the pixel is 255 — the *semantic prior*, drivable surface and
    sidewalks). ``source``: the file read. ``version``: the map expansion's own version (its JSON's ``version``
    field, ``"1.0"`` where it has none, as the devkit's ``NuScenesMap`` reads it; :func:`expansion_version`); None for
    a mask (base map masks carry no version).
    """

    kind: str
    source: str
    mask: np.ndarray | None = None  # (H, W) uint8
    xy: np.ndarray | None = None  # (V, 2)
    rings: np.ndarray | None = None  # (R + 1,) int64
    polygons: np.ndarray | None = None  # (P + 1,) int64
    version: str | None = None

    def lookup(self, traj: Any, poses: Any, ego: Any = None) -> np.ndarray:
        """(N, T, 5) uint8 of ``ON`` / ``OFF`` / ``OUTSIDE`` (1 / 0 / 2; the point is not covered by the mask
        image: counted off the drivable area, and reported) for the footprint's 4 corners (front-left,
        front-right, rear-right, rear-left) and then its reference point, at every step. ``traj`` (N, T, 2) in the
        ego frame of each keyframe, ``poses`` (N, 3) its global (x, y, yaw); ``ego``: an
        :class:`lightemma.evaluation.safety.EgoModel` (default: lightemma's ego box)."""
        from lightemma import _core

        t = np.ascontiguousarray(traj, dtype=np.float64)
        p = np.ascontiguousarray(poses, dtype=np.float64)
        if self.kind == "mask":
            assert self.mask is not None  # a mask area holds its mask (read_map_mask)
            return _core.mask_area(t, p, self.mask, MASK_RESOLUTION, MASK_FOREGROUND, **_ego_kwargs(ego))
        assert self.xy is not None and self.rings is not None and self.polygons is not None  # an expansion's polygons
        return _core.polygon_area(t, p, self.xy, self.rings, self.polygons, **_ego_kwargs(ego))

    def contains(self, points: Any) -> np.ndarray:
        """(M,) uint8 ``ON`` / ``OFF`` / ``OUTSIDE`` codes of global points (M, 2)."""
        pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 2)
        from lightemma import _core

        if self.kind == "mask":
            assert self.mask is not None  # a mask area holds its mask
            return _core.mask_lookup(pts, self.mask, MASK_RESOLUTION, MASK_FOREGROUND)
        poses = np.column_stack([pts, np.zeros(len(pts))])  # a one-step trajectory at the origin of each point
        at_point = _PointEgo()  # the reference point itself: lightemma's box with no offset
        return self.lookup(np.zeros((len(pts), 1, 2)), poses, at_point)[:, 0, 4]


class _PointEgo:
    """lightemma's ego box with its centre on the reference point (offset 0), for :meth:`DrivableArea.contains`."""

    @staticmethod
    def kwargs() -> EgoKwargs:
        kwargs = _ego_kwargs(None)
        kwargs["offset"] = 0.0
        return kwargs


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
        raise DatasetError(f"{what} {path} is not a regular file ({file_kind(mode)})")


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
        raise DatasetError(
            f"map mask {path} claims {width} × {height} pixels, more than the {MAX_MASK_PIXELS:,} "
            "a base map mask can have (nuScenes' largest is 1.19 G pixels); not decoded"
        )
    if colour not in (0, 3) or depth == 16:
        kind = f"{depth}-bit {_PNG_COLOUR.get(colour, f'colour type {colour}')}"
        raise DatasetError(
            f"map mask {path} is a {kind} PNG; a base map mask is 8-bit grayscale (255 drivable), "
            "1-bit grayscale or a gray palette"
        )
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
            raise DatasetError(
                f"map mask {path} is a palette PNG with colours (or indices beyond its palette); "
                "a base map mask is grayscale"
            )
        lut = np.zeros(256, dtype=np.uint8)
        lut[: len(rgb)] = rgb[:256, 0]
        mask = lut[mask]
    elif mode != "L":
        raise DatasetError(f"map mask {path} decodes to PIL mode {mode}; a base map mask is 8-bit grayscale")
    if mask.ndim != 2:
        raise DatasetError(f"map mask {path} has shape {mask.shape}; expected a one-channel image")
    top = int(mask.max()) if mask.size else None  # a reduction: no mask-sized temporary
    if top != MASK_FOREGROUND:
        raise DatasetError(
            f"map mask {path} has no pixel of value {MASK_FOREGROUND} (drivable); its largest value is "
            f"{top}: not a drivable-area mask in the devkit's encoding"
        )
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
    raise DatasetError(
        f"map expansion {path}: node {node} has {axis} = {shown}; a coordinate must be a finite number "
        f"within ±{MAX_COORDINATE_M:g} m"
    )


#: a map expansion's ``version`` field: digits and dots (nuScenes' expansions are ``1.0`` … ``1.3``)
_MAP_VERSION = re.compile(r"[0-9]+(\.[0-9]+){0,3}")


def expansion_version(doc: Any, path: Any) -> str:
    """The version of a map-expansion JSON ``doc`` read from ``path``: its ``version`` field, or ``"1.0"`` when it has
    none (the devkit's ``NuScenesMap`` rule; expansions before 1.3 lack the lane layers). A ``version`` that is not a
    string of digits and dots (``"1.3"``) raises :class:`DatasetError` naming the file: numbers scored against a map
    are recorded with its version (docs/evaluate.md#what-each-number-is), and a version that cannot be read is not
    guessed."""
    if not isinstance(doc, dict) or "version" not in doc:
        return "1.0"
    version = doc["version"]
    if not isinstance(version, str) or not _MAP_VERSION.fullmatch(version):
        shown = repr(version) if len(repr(version)) <= 40 else repr(version)[:37] + "..."
        raise DatasetError(f"map expansion {path}: field version = {shown} is not a version such as '1.3'")
    return version


def read_expansion(path: str | os.PathLike[str]) -> DrivableArea:
    """The ``drivable_area`` layer of a map-expansion JSON (``maps/expansion/<location>.json``) as polygons.

    Each drivable_area record lists ``polygon_tokens``; each polygon has ``exterior_node_tokens``
    and ``holes`` (``node_tokens``); nodes carry global ``x``, ``y`` (the devkit's ``NuScenesMap``).
    Raises :class:`DatasetError` naming the file (and the node or polygon) for a file that is not a regular
    file or not readable JSON (nesting too deep included), a missing record, a node coordinate that is not
    a finite number within :data:`MAX_COORDINATE_M`, a ring of fewer than 3 nodes, or a ``version`` field that is
    not a version (:func:`expansion_version`, recorded as the area's ``version``).
    """
    return _drivable_area(read_expansion_doc(path), path)


def read_expansion_doc(path: str | os.PathLike[str]) -> Any:
    """The parsed JSON of a map expansion: a regular file of at most :data:`MAX_EXPANSION_BYTES`, UTF-8 JSON (nesting
    too deep included, one line naming the file, never a ``RecursionError``); else :class:`DatasetError`."""
    _regular_file(path, "map expansion")
    try:
        data = read_regular_file(path, MAX_EXPANSION_BYTES)
    except FileRefused as exc:
        raise DatasetError(f"map expansion {path} {exc.reason}") from None
    try:
        text = data.decode("utf-8")
        del data
        return json.loads(text)
    except RecursionError:
        raise DatasetError(
            f"map expansion {path}: cannot read its drivable_area layer (the JSON is nested too deep)"
        ) from None
    except ValueError as exc:
        raise DatasetError(
            f"map expansion {path}: cannot read its drivable_area layer ({type(exc).__name__}: {exc})"
        ) from None


def _drivable_area(doc: Any, path: str | os.PathLike[str]) -> DrivableArea:
    """The ``drivable_area`` layer of a parsed map expansion read from ``path`` (see :func:`read_expansion`)."""
    version = expansion_version(doc, path)
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
                        raise DatasetError(
                            f"map expansion {path}: polygon {ptok} has a ring of {n} node(s); a ring needs at least 3"
                        )
                    for t in ring:
                        node = nodes[t]
                        xy.append((_map_coordinate(node["x"], path, t, "x"), _map_coordinate(node["y"], path, t, "y")))
                    rings.append(len(xy))
                polygons.append(len(rings) - 1)
    except (KeyError, TypeError, AttributeError) as exc:
        raise DatasetError(
            f"map expansion {path}: cannot read its drivable_area layer ({type(exc).__name__}: {exc})"
        ) from None
    if len(polygons) == 1:  # every position would be off-road: no number, as for a mask without a drivable pixel
        raise DatasetError(f"map expansion {path}: its drivable_area layer holds no polygon")
    return DrivableArea(
        "expansion",
        os.fspath(path),
        xy=np.asarray(xy, dtype=np.float64).reshape(-1, 2),
        rings=np.asarray(rings, dtype=np.int64),
        polygons=np.asarray(polygons, dtype=np.int64),
        version=version,
    )


def file_problem(path: Path) -> str | None:
    """Why a map file that is there cannot be read as one (a FIFO, a device, a folder), or None."""
    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        return f"{path} cannot be read: {exc.strerror or exc}"
    return None if stat.S_ISREG(mode) else f"{path} is not a regular file ({file_kind(mode)})"


#: a map location as nuScenes names them (singapore-onenorth, boston-seaport): letters, digits, - and _, no path
MAP_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,99}")


@dataclass(frozen=True)
class ExpansionLayers:
    """What the planning score reads of a map expansion: ``drivable`` its ``drivable_area`` (:func:`read_expansion`);
    ``lanes`` the rings of each ``lane`` and then each ``lane_connector`` record; ``intersections`` those of each
    ``road_segment`` record with ``is_intersection`` true. A record's rings: its exterior, then its holes, each
    (K ≥ 3, 2) float64 global x, y (m)."""

    drivable: DrivableArea
    lanes: list[list[np.ndarray]] = field(default_factory=list)
    intersections: list[list[np.ndarray]] = field(default_factory=list)


def _layer_rings(doc: Any, records: list[Any], name: str, path: str | os.PathLike[str]) -> list[list[np.ndarray]]:
    """The rings of each record of a polygon layer (``polygon_token`` → exterior and holes), coordinates checked as the
    drivable area's are (:func:`_map_coordinate`)."""
    try:
        nodes = {n["token"]: n for n in doc["node"]}
        polys = {p["token"]: p for p in doc["polygon"]}
        out: list[list[np.ndarray]] = []
        for rec in records:
            poly = polys[rec["polygon_token"]]
            rings = []
            for ring in [poly["exterior_node_tokens"], *(h["node_tokens"] for h in poly.get("holes", []))]:
                if not isinstance(ring, list) or len(ring) < 3:
                    raise DatasetError(
                        f"map expansion {path}: {name} {rec.get('token')} has a ring of fewer than 3 nodes"
                    )
                rings.append(
                    np.array(
                        [
                            [_map_coordinate(nodes[t]["x"], path, t, "x"), _map_coordinate(nodes[t]["y"], path, t, "y")]
                            for t in ring
                        ],
                        dtype=np.float64,
                    )
                )
            out.append(rings)
    except (KeyError, TypeError, AttributeError, ValueError) as exc:
        if isinstance(exc, DatasetError):
            raise
        raise DatasetError(
            f"map expansion {path}: cannot read its {name} layer ({type(exc).__name__}: {exc})"
        ) from None
    return out


def read_expansion_layers(path: str | os.PathLike[str]) -> ExpansionLayers:
    """The drivable area, lanes and intersections of a map expansion (``maps/expansion/<location>.json``), the file
    read once. A layer the file lacks (an expansion before v1.3) is an empty list. Raises :class:`DatasetError`
    naming the file and record for what :func:`read_expansion` refuses, a missing node or polygon, a coordinate that
    is not a finite number within :data:`MAX_COORDINATE_M`, or a ring of fewer than 3 nodes."""
    doc = read_expansion_doc(path)
    drivable = _drivable_area(doc, path)
    try:
        lane_records = list(doc.get("lane", [])) + list(doc.get("lane_connector", []))
        crossings = [r for r in doc.get("road_segment", []) if r.get("is_intersection") is True]
    except (TypeError, AttributeError) as exc:
        raise DatasetError(f"map expansion {path}: cannot read its lane / road_segment layers ({exc})") from None
    return ExpansionLayers(
        drivable, _layer_rings(doc, lane_records, "lane", path), _layer_rings(doc, crossings, "road_segment", path)
    )
