"""NAVSIM's sub-scores on simulated ego states and the aggregates PDMS, EPDMS and EPDMS-map.

Definitions, thresholds, sources and every deviation from NAVSIM: ``docs/definitions.md#sub-scores-and-aggregates``.
The geometry runs in the Rust core (``lightemma._core.planning_subscores``: whole batches, GIL released); this
module types the inputs, turns reason codes into sentences and aggregates with NAVSIM's human-penalty filter.

Units: metres, radians, seconds, m/s; everything in the global (map) frame. States are NAVSIM's ``StateIndex``
layout (x, y, heading, velocity x, velocity y, acceleration x, acceleration y, steering angle, steering rate,
yaw rate, yaw acceleration) of the rear axle, S = T + 1 states ``dt`` apart, the initial state first.

A value that cannot be decided is NaN with a reason (``DriveScores.reasons``), never a silent 0 or 1.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TypedDict

import numpy as np
import numpy.typing as npt

from lightemma import _core
from lightemma.definitions import EGO_LENGTH, EGO_WIDTH, ZOE_REAR_AXLE_TO_CENTER
from lightemma.errors import InputError, ShapeError
from lightemma.nuscenes.map_files import ExpansionLayers, read_expansion_layers

__all__ = [
    "AGENT_KIND",
    "OBJECT_KIND",
    "SUBSCORES",
    "AGGREGATES",
    "DrivableMask",
    "DriveScores",
    "EgoBox",
    "FrameLanes",
    "PlanningMap",
    "PolygonSet",
    "drive_scores",
    "interpolate_boxes",
    "planning_map",
    "read_planning_map",
    "route_lanes",
    "subscores",
]

FloatArray = npt.NDArray[np.float64]

#: ``kind`` value of an agent's box: vehicle, pedestrian, bicycle (nuPlan's ``AGENT_TYPES``; at-fault nc 0).
AGENT_KIND = 0.0
#: ``kind`` value of a static object's box (barrier, cone, debris …; always stopped; at-fault nc 0.5).
OBJECT_KIND = 1.0

#: The per-frame sub-scores, in the order ``DriveScores`` lists them.
SUBSCORES = ("nc", "dac", "ddc", "tlc", "ep", "ttc", "lk", "c", "hc", "ec")
#: The aggregates.
AGGREGATES = ("pdms", "epdms", "epdms_map")

# NAVSIM's weights (pdm_scorer.yaml) and the progress threshold (m)
_W_EP, _W_TTC, _W_LK, _W_HC, _W_EC, _W_C = 5.0, 5.0, 2.0, 2.0, 2.0, 2.0
PROGRESS_THRESHOLD = 5.0

#: Sub-scores the human-penalty filter applies to (NAVSIM's human result can be 0 only on these; its ep is
#: normalised against itself and its hc is scored without history, so neither is ever 0).
FILTERED = ("nc", "dac", "ddc", "ttc", "lk")

_TLC_REASON = "nuScenes has no traffic-light states (counted as 1 in epdms)"


@dataclass(frozen=True)
class PolygonSet:
    """Polygons with holes: vertices ``xy`` (V, 2) float64, ``rings`` (R + 1,) int64 offsets into the vertices,
    ``polygons`` (P + 1,) int64 offsets into the rings (a polygon's first ring is its exterior, the rest holes)."""

    xy: FloatArray
    rings: npt.NDArray[np.int64]
    polygons: npt.NDArray[np.int64]

    @classmethod
    def from_rings(cls, polygons: Sequence[Sequence[npt.ArrayLike]]) -> PolygonSet:
        """Build from a list of polygons, each a list of rings (exterior first), each ring (M, 2) vertices."""
        xy: list[FloatArray] = []
        rings = [0]
        polys = [0]
        for poly in polygons:
            for ring in poly:
                r = np.asarray(ring, dtype=np.float64).reshape(-1, 2)
                xy.append(r)
                rings.append(rings[-1] + len(r))
            polys.append(len(rings) - 1)
        return cls(
            np.ascontiguousarray(np.concatenate(xy) if xy else np.zeros((0, 2))),
            np.asarray(rings, dtype=np.int64),
            np.asarray(polys, dtype=np.int64),
        )

    def arrays(self) -> tuple[FloatArray, npt.NDArray[np.int64], npt.NDArray[np.int64]]:
        return (
            np.ascontiguousarray(self.xy, dtype=np.float64),
            np.ascontiguousarray(self.rings, dtype=np.int64),
            np.ascontiguousarray(self.polygons, dtype=np.int64),
        )


@dataclass(frozen=True)
class DrivableMask:
    """A drivable-area raster in the devkit's ``MapMask`` convention (see ``docs/definitions.md#safety``)."""

    mask: npt.NDArray[np.uint8]
    resolution: float = 0.1
    foreground: int = 255


@dataclass(frozen=True)
class PlanningMap:
    """The map layers of one location. A layer that is ``None`` makes the sub-scores needing it n/a.

    ``drivable``: the drivable area (NAVSIM: roadblocks, intersections, drivable areas, car parks; nuScenes map
    expansion: ``drivable_area``) as polygons or a mask; ``lanes``: lane (and lane-connector) polygons;
    ``intersections``: intersection polygons (nuScenes: ``road_segment`` records with ``is_intersection``)."""

    drivable: PolygonSet | DrivableMask | None = None
    lanes: PolygonSet | None = None
    intersections: PolygonSet | None = None


@dataclass(frozen=True)
class FrameLanes:
    """Per-frame candidate lanes (indices into ``PlanningMap.lanes``' polygons) and their on-route flags:
    frame f's lanes are ``ids[offsets[f]:offsets[f + 1]]``. On-route lanes are those of the route the ground
    truth drives (NAVSIM: the route's lanes); the others are only tested for "in multiple lanes"."""

    offsets: npt.NDArray[np.int64]
    ids: npt.NDArray[np.int64]
    on_route: npt.NDArray[np.uint8]


@dataclass(frozen=True)
class EgoBox:
    """The ego rectangle: length and width (m) and how far its centre lies ahead of the rear axle (m).
    Defaults: lightemma's ego box (``docs/definitions.md#safety``), with the planning score's centre offset
    (:data:`lightemma.definitions.ZOE_REAR_AXLE_TO_CENTER`)."""

    length: float = EGO_LENGTH
    width: float = EGO_WIDTH
    rear_axle_to_center: float = ZOE_REAR_AXLE_TO_CENTER


@dataclass
class DriveScores:
    """Per-plan scores: ``values[name]`` (N,) float64 with NaN where n/a, ``reasons[name]`` (N,) with a sentence
    where n/a (else None), for every name of ``SUBSCORES`` and ``AGGREGATES``; ``gt`` the ground truth's
    sub-scores (F,) per scene frame (unnormalised ep in metres under ``ep_raw``); ``ep_raw`` the plans' raw
    progress (m). ``tlc`` is always NaN with its reason and counted as 1 in ``epdms``."""

    values: dict[str, FloatArray]
    reasons: dict[str, list[str | None]]
    gt: dict[str, FloatArray] = field(default_factory=dict)
    ep_raw: FloatArray = field(default_factory=lambda: np.zeros(0))

    def __getitem__(self, name: str) -> FloatArray:
        return self.values[name]


def interpolate_boxes(boxes: npt.ArrayLike, factor: int = 5) -> FloatArray:
    """Boxes at 2 Hz (F, K, A, 8) → at 10 Hz (F, (K − 1)·factor + 1, A, 8), linearly between keyframes.

    Columns: centre x, y (m), yaw (rad, interpolated along the shorter arc), length, width (m), velocity x, y
    (m/s), kind (copied from the earlier keyframe). A track absent (NaN centre x) at either end of an interval is
    absent inside it. NAVSIM interpolates its tracks to the 0.1 s proposal sampling the same way.
    Raises ValueError on a shape that is not (F, K ≥ 1, A, 8) or a factor < 1."""
    b = np.asarray(boxes, dtype=np.float64)
    if b.ndim != 4 or b.shape[3] != 8 or b.shape[1] < 1:
        raise ShapeError(f"boxes must have shape (F, K, A, 8) with K ≥ 1, got {b.shape}")
    if factor < 1:
        raise InputError(f"factor must be ≥ 1, got {factor}")
    f, k, a, _ = b.shape
    out = np.full((f, (k - 1) * factor + 1, a, 8), np.nan)
    out[:, ::factor] = b
    u = (np.arange(1, factor) / factor)[None, :, None, None]
    for i in range(k - 1):
        lo, hi = b[:, i : i + 1], b[:, i + 1 : i + 2]
        mid = lo + u * (hi - lo)
        dyaw = (hi[..., 2] - lo[..., 2] + np.pi) % (2 * np.pi) - np.pi
        mid[..., 2] = lo[..., 2] + u[..., 0] * dyaw
        mid[..., 7] = lo[..., 7]
        absent = np.isnan(lo[..., 0]) | np.isnan(hi[..., 0])
        mid[np.broadcast_to(absent, mid.shape[:-1])] = np.nan
        out[:, i * factor + 1 : (i + 1) * factor] = mid
    return out


def read_planning_map(path: str | os.PathLike[str]) -> PlanningMap:
    """The layers NAVSIM's sub-scores need from a nuScenes map-expansion JSON (``maps/expansion/<location>.json``),
    read by :func:`lightemma.nuscenes.map_files.read_expansion_layers` (the one reader of map files).

    ``drivable``: the ``drivable_area`` layer; ``lanes``: the polygons of the ``lane`` and ``lane_connector`` records
    (in that order); ``intersections``: the polygons of the ``road_segment`` records with ``is_intersection`` true. A
    layer with no polygon (an expansion before v1.3, or a synthetic one) is ``None``, so the sub-scores needing it are
    n/a with that reason — never scored on an empty map. Raises ``DatasetError`` naming the file and record for
    unreadable JSON, a missing node or polygon, a coordinate that is not a finite number within ±1e6 m, or a ring of
    fewer than 3 nodes."""
    return planning_map(read_expansion_layers(path))


def planning_map(layers: ExpansionLayers) -> PlanningMap:
    """A :class:`PlanningMap` of map-expansion layers already read (:func:`read_expansion_layers`)."""
    area = layers.drivable
    drivable = None
    if area.polygons is not None and len(area.polygons) > 1:
        assert area.xy is not None and area.rings is not None  # read_expansion sets xy, rings and polygons together
        drivable = PolygonSet(area.xy, area.rings, area.polygons)
    return PlanningMap(
        drivable=drivable,
        lanes=PolygonSet.from_rings(layers.lanes) if layers.lanes else None,
        intersections=PolygonSet.from_rings(layers.intersections) if layers.intersections else None,
    )


def _in_ring(ring: FloatArray, pts: FloatArray) -> npt.NDArray[np.bool_]:
    """Crossing-number point-in-ring test of points (M, 2) against a ring (K, 2)."""
    x, y = pts[:, 0:1], pts[:, 1:2]
    xi, yi = ring[:, 0], ring[:, 1]
    xj, yj = np.roll(xi, 1), np.roll(yi, 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        cross = ((yi > y) != (yj > y)) & (x < (xj - xi) * (y - yi) / (yj - yi) + xi)
    inside: npt.NDArray[np.bool_] = cross.sum(axis=1) % 2 == 1
    return inside


def route_lanes(
    lanes: PolygonSet, gt_states: npt.ArrayLike, ego: EgoBox = EgoBox(), radius: float = 50.0
) -> FrameLanes:
    """Each frame's candidate lanes and on-route flags from its ground truth's states (F, S, 11).

    Candidates: the lanes whose bounding box comes within ``radius`` m of a ground-truth state; on route: those
    holding the ground truth's centre (rear axle + ``ego.rear_axle_to_center`` along the heading) at some step
    (NAVSIM: the lanes of the navigation route; nuScenes has none, the ground truth's path stands in). Frames whose
    states are not finite get no lanes (their ddc is n/a). Raises ValueError on a states shape other than (F, S, 11)."""
    gt = np.asarray(gt_states, dtype=np.float64)
    if gt.ndim != 3 or gt.shape[2] != 11:
        raise ShapeError(f"gt_states must have shape (F, S, 11), got {gt.shape}")
    xy, rings, polys = lanes.arrays()
    exteriors = [xy[rings[polys[p]] : rings[polys[p] + 1]] for p in range(len(polys) - 1)]
    bounds = np.array([[*e.min(0), *e.max(0)] for e in exteriors]).reshape(-1, 4)
    h = gt[..., 2]
    centres = gt[..., :2] + ego.rear_axle_to_center * np.stack([np.cos(h), np.sin(h)], -1)
    offsets: list[int] = [0]
    ids: list[int] = []
    flags: list[int] = []
    for f in range(len(gt)):
        c = centres[f]
        if not np.isfinite(gt[f]).all():
            offsets.append(len(ids))
            continue
        lo, hi = gt[f, :, :2].min(0) - radius, gt[f, :, :2].max(0) + radius
        near = np.nonzero(
            (bounds[:, 0] <= hi[0]) & (bounds[:, 2] >= lo[0]) & (bounds[:, 1] <= hi[1]) & (bounds[:, 3] >= lo[1])
        )[0]
        for p in near.tolist():
            r0, r1 = polys[p], polys[p + 1]
            inside = _in_ring(xy[rings[r0] : rings[r0 + 1]], c)
            for r in range(r0 + 1, r1):
                inside &= ~_in_ring(xy[rings[r] : rings[r + 1]], c)
            ids.append(p)
            flags.append(1 if inside.any() else 0)
        offsets.append(len(ids))
    return FrameLanes(np.asarray(offsets, np.int64), np.asarray(ids, np.int64), np.asarray(flags, np.uint8))


_REASONS = {
    "bad_states": "the plan's simulated states hold a NaN or infinity",
    "no_agents": "no annotations (agents' boxes) for this version",
    "no_drivable": "no drivable area given (map expansion or mask)",
    "no_lanes": "no lane polygons (nuScenes map expansion v1.3) given",
    "no_intersections": "no intersection polygons (nuScenes map expansion v1.3) given",
    "undetermined": "a collision's at-fault class needs a map layer that was not given (lanes, drivable area, "
    "intersections)",
    "no_route": "no route: fewer than two finite points (or a NaN before the padding)",
    "no_centreline": "no centreline: fewer than two finite points (or a NaN before the padding)",
    "no_route_lanes": "none of the frame's lanes is on the route (the ground truth is in no lane polygon)",
}


class _SubscoreArgs(TypedDict, total=False):
    """The optional keyword arguments of ``_core.planning_subscores`` that :func:`subscores` passes on."""

    agents: FloatArray
    drivable_mask: npt.NDArray[np.uint8]
    mask_resolution: float
    mask_foreground: int
    drivable: tuple[FloatArray, npt.NDArray[np.int64], npt.NDArray[np.int64]]
    lanes: tuple[FloatArray, npt.NDArray[np.int64], npt.NDArray[np.int64]]
    lane_offsets: npt.NDArray[np.int64]
    lane_ids: npt.NDArray[np.int64]
    lane_on_route: npt.NDArray[np.uint8]
    intersections: tuple[FloatArray, npt.NDArray[np.int64], npt.NDArray[np.int64]]
    route: FloatArray
    centreline: FloatArray


def _polyline_array(a: npt.ArrayLike | None, name: str) -> FloatArray | None:
    if a is None:
        return None
    arr = np.ascontiguousarray(a, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[2] != 2:
        raise ShapeError(f"{name} must have shape (F, R, 2), got {arr.shape}")
    return arr


def subscores(
    states: npt.ArrayLike,
    frame: npt.ArrayLike | None = None,
    *,
    agents: npt.ArrayLike | None = None,
    map: PlanningMap | None = None,
    frame_lanes: FrameLanes | None = None,
    route: npt.ArrayLike | None = None,
    centreline: npt.ArrayLike | None = None,
    n_frames: int | None = None,
    ego: EgoBox = EgoBox(),
    dt: float = 0.1,
) -> tuple[dict[str, FloatArray], dict[str, list[str | None]]]:
    """NAVSIM's geometric sub-scores of N plans: ``nc``, ``dac``, ``ddc``, ``ep_raw`` (m), ``ttc``, ``lk``.

    ``states`` (N, S, 11) float64; ``frame`` (N,) the scene frame (0..F) of each plan (default ``arange(N)``);
    ``agents`` (F, S, A, 8) boxes at the states' steps (``interpolate_boxes`` from 2 Hz), NaN centre x = absent;
    ``map`` one location's layers; ``frame_lanes`` the frames' candidate lanes (needed with ``map.lanes``);
    ``route`` and ``centreline`` (F, R, 2) polylines padded with NaN rows. Returns (values, reasons): (N,) arrays
    with NaN where n/a, and per plan a sentence or None. Raises ValueError on shapes that disagree (naming
    them); bad values inside a frame are n/a with a reason."""
    st = np.ascontiguousarray(states, dtype=np.float64)
    if st.ndim != 3 or st.shape[2] != 11:
        raise ShapeError(f"states must have shape (N, S, 11), got {st.shape}")
    n = st.shape[0]
    fr = np.arange(n, dtype=np.int64) if frame is None else np.ascontiguousarray(frame, dtype=np.int64)
    if fr.shape != (n,):
        raise ShapeError(f"frame must have shape ({n},), got {fr.shape}")
    m = map or PlanningMap()
    kwargs: _SubscoreArgs = {}
    if agents is not None:
        kwargs["agents"] = np.ascontiguousarray(agents, dtype=np.float64)
    if isinstance(m.drivable, DrivableMask):
        kwargs["drivable_mask"] = np.ascontiguousarray(m.drivable.mask, dtype=np.uint8)
        kwargs["mask_resolution"] = float(m.drivable.resolution)
        kwargs["mask_foreground"] = int(m.drivable.foreground)
    elif isinstance(m.drivable, PolygonSet):
        kwargs["drivable"] = m.drivable.arrays()
    if m.lanes is not None:
        if frame_lanes is None:
            raise InputError("map.lanes needs frame_lanes (each frame's candidate lanes and on-route flags)")
        kwargs["lanes"] = m.lanes.arrays()
        kwargs["lane_offsets"] = np.ascontiguousarray(frame_lanes.offsets, dtype=np.int64)
        kwargs["lane_ids"] = np.ascontiguousarray(frame_lanes.ids, dtype=np.int64)
        kwargs["lane_on_route"] = np.ascontiguousarray(frame_lanes.on_route, dtype=np.uint8)
    if m.intersections is not None:
        kwargs["intersections"] = m.intersections.arrays()
    route_arr = _polyline_array(route, "route")
    if route_arr is not None:
        kwargs["route"] = route_arr
    centreline_arr = _polyline_array(centreline, "centreline")
    if centreline_arr is not None:
        kwargs["centreline"] = centreline_arr
    values, codes = _core.planning_subscores(
        st,
        fr,
        n_frames=n_frames,
        length=ego.length,
        width=ego.width,
        rear_axle_to_center=ego.rear_axle_to_center,
        dt=dt,
        **kwargs,
    )
    names = list(_core.PLANNING_SCORE_NAMES)
    table = np.array([None] + [_REASONS.get(r) for r in list(_core.PLANNING_REASONS)[1:]], dtype=object)
    bad_box = list(_core.PLANNING_REASONS).index("bad_box")
    out_values = {name: values[:, j].copy() for j, name in enumerate(names)}
    out_reasons: dict[str, list[str | None]] = {}
    bad_box_cache: dict[int, str] = {}
    for j, name in enumerate(names):
        col: list[str | None] = table[codes[:, j]].tolist()
        for i in np.nonzero(codes[:, j] == bad_box)[0].tolist():
            f = int(fr[i])
            if f not in bad_box_cache:
                where = _core.planning_first_bad_box(kwargs["agents"], f)
                step, slot = where if where is not None else (-1, -1)
                bad_box_cache[f] = (
                    f"frame {f} has a degenerate agent box (step {step}, slot {slot}: a non-finite value, "
                    "a size ≤ 0 or an unknown kind)"
                )
            col[i] = bad_box_cache[f]
        out_reasons[name] = col
    return out_values, out_reasons


def _given(x: npt.ArrayLike | None, n: int, name: str) -> tuple[FloatArray, list[str | None]]:
    """A comfort input (N,) (0/1, NaN n/a) from part A's kernels, or all n/a when not given."""
    if x is None:
        return np.full(n, np.nan), [f"{name} not given"] * n
    a = np.asarray(x, dtype=np.float64)
    if a.shape != (n,):
        raise ShapeError(f"{name} must have shape ({n},), got {a.shape}")
    return a.copy(), [None if ok else f"{name} is n/a in its input" for ok in np.isfinite(a).tolist()]


def _normalised_progress(raw: FloatArray, mult: FloatArray, gt_raw: FloatArray, gt_mult: FloatArray) -> FloatArray:
    """NAVSIM's ``_aggregate_pdm_scores`` progress over the pair (ground truth standing in for PDM-Closed, plan):
    norm = max(raw·mult) over the pair; raw / norm clipped to [0, 1] when norm > 5 m, else 1. NaN in → NaN."""
    norm = np.maximum(raw * mult, gt_raw * gt_mult)
    with np.errstate(invalid="ignore", divide="ignore"):
        ep = np.where(norm > PROGRESS_THRESHOLD, np.clip(raw / np.where(norm > 0, norm, 1.0), 0.0, 1.0), 1.0)
    ep[np.isnan(norm)] = np.nan
    return ep


def _filtered(plan: FloatArray, gt: FloatArray, reasons: list[str | None]) -> tuple[FloatArray, list[str | None]]:
    """NAVSIM's human-penalty filter: 1 where the ground truth scores 0; n/a where the ground truth's value is n/a
    and the plan's is not 1 (the filter's outcome is then unknown). ``reasons`` are the plan's own."""
    out = np.where(gt == 0.0, 1.0, plan)
    unknown = np.isnan(gt) & (plan != 1.0)
    out[unknown] = np.nan
    reasons = list(reasons)
    for i in np.nonzero(np.isnan(plan) & (gt == 0.0))[0].tolist():
        reasons[i] = None  # the ground truth fails it too: taken as 1 whatever the plan's
    for i in np.nonzero(unknown)[0].tolist():
        reasons[i] = "the ground truth's value is n/a (human-penalty filter)"
    return out, reasons


def _aggregate(
    parts: dict[str, tuple[FloatArray, list[str | None]]],
    multipliers: tuple[str, ...],
    weights: dict[str, float],
) -> tuple[FloatArray, list[str | None]]:
    n = len(next(iter(parts.values()))[0])
    total = sum(weights.values())
    value = np.ones(n)
    for name in multipliers:
        value = value * parts[name][0]
    value = value * sum(w * parts[name][0] for name, w in weights.items()) / total
    names = (*multipliers, *weights)
    finite = {name: np.isfinite(parts[name][0]) for name in names}
    reasons: list[str | None] = [None] * n
    for i in np.nonzero(~np.all([finite[name] for name in names], axis=0))[0].tolist():
        missing = [f"{name} ({parts[name][1][i] or 'n/a'})" for name in names if not finite[name][i]]
        reasons[i] = "n/a: " + "; ".join(missing)
    return value, reasons


def drive_scores(
    states: npt.ArrayLike,
    gt_states: npt.ArrayLike,
    *,
    frame: npt.ArrayLike | None = None,
    agents: npt.ArrayLike | None = None,
    map: PlanningMap | None = None,
    frame_lanes: FrameLanes | None = None,
    route: npt.ArrayLike | None = None,
    centreline: npt.ArrayLike | None = None,
    c: npt.ArrayLike | None = None,
    hc: npt.ArrayLike | None = None,
    ec: npt.ArrayLike | None = None,
    ego: EgoBox = EgoBox(),
    dt: float = 0.1,
) -> DriveScores:
    """Per-plan sub-scores and aggregates of NAVSIM's planning score.

    ``states`` (N, S, 11): the plans' simulated states; ``gt_states`` (F, S, 11): the ground truth's, simulated the
    same way (NAVSIM scores the human trajectory for its penalty filter and PDM-Closed for progress; the ground
    truth stands in for both); ``frame`` (N,) each plan's scene frame (default ``arange(N)``, then F = N);
    ``agents``, ``map``, ``frame_lanes``, ``route``, ``centreline``: as ``subscores`` (per scene frame);
    ``c``, ``hc``, ``ec`` (N,): comfort from ``lightemma.comfort`` / ``extended_comfort`` (0/1, NaN n/a).

    Aggregates (``docs/definitions.md#sub-scores-and-aggregates``):
    ``pdms`` = nc·dac·(5ep + 5ttc + 2c)/12 (v1, no filter);
    ``epdms`` = nc·dac·ddc·tlc·(5ep + 5ttc + 2lk + 2hc + 2ec)/16 with the human-penalty filter, tlc counted 1;
    ``epdms_map`` = dac·ddc·(5ep + 2lk + 2hc + 2ec)/11 (filtered) — only when no agents are given (a version without
    annotations); with agents it is n/a and ``epdms`` is the score. ``ep`` is normalised against the ground truth
    with the multipliers that aggregate uses (nc·dac·ddc with agents, dac·ddc without).
    Raises ValueError on shapes that disagree; everything else is n/a with a reason."""
    st = np.asarray(states, dtype=np.float64)
    gt = np.asarray(gt_states, dtype=np.float64)
    if st.ndim != 3 or st.shape[2] != 11:
        raise ShapeError(f"states must have shape (N, S, 11), got {st.shape}")
    if gt.ndim != 3 or gt.shape[1:] != st.shape[1:]:
        raise ShapeError(f"gt_states must have shape (F, {st.shape[1]}, 11), got {gt.shape}")
    n, f = st.shape[0], gt.shape[0]
    fr = np.arange(n, dtype=np.int64) if frame is None else np.asarray(frame, dtype=np.int64)
    if fr.shape != (n,):
        raise ShapeError(f"frame must have shape ({n},), got {fr.shape}")
    if n and (fr.min() < 0 or fr.max() >= f):
        raise InputError(f"frame indices must lie in 0..{f - 1} (gt_states has {f} frames)")
    both = np.concatenate([st, gt])
    both_frame = np.concatenate([fr, np.arange(f, dtype=np.int64)])
    vals, why = subscores(
        both,
        both_frame,
        agents=agents,
        map=map,
        frame_lanes=frame_lanes,
        route=route,
        centreline=centreline,
        n_frames=f,
        ego=ego,
        dt=dt,
    )
    plan = {k: (v[:n], why[k][:n]) for k, v in vals.items()}
    gt_v = {k: v[n:] for k, v in vals.items()}
    gt_of = {k: v[fr] for k, v in gt_v.items()}

    parts: dict[str, tuple[FloatArray, list[str | None]]] = {k: plan[k] for k in ("nc", "dac", "ddc", "ttc", "lk")}
    parts["tlc"] = (np.full(n, np.nan), [_TLC_REASON] * n)
    parts["c"] = _given(c, n, "c")
    parts["hc"] = _given(hc, n, "hc")
    parts["ec"] = _given(ec, n, "ec")
    with_agents = agents is not None
    epdms: tuple[FloatArray, list[str | None]]
    epdms_map: tuple[FloatArray, list[str | None]]
    mult_names = ("nc", "dac", "ddc") if with_agents else ("dac", "ddc")
    mult = np.prod([parts[k][0] for k in mult_names], axis=0)
    gt_mult = np.prod([gt_of[k] for k in mult_names], axis=0)
    ep = _normalised_progress(plan["ep_raw"][0], mult, gt_of["ep_raw"], gt_mult)
    ep_reasons: list[str | None] = [None] * n
    for i in np.nonzero(~np.isfinite(ep))[0].tolist():
        missing = [f"plan's {k}" for k in ("ep_raw", *mult_names) if not np.isfinite(plan[k][0][i])]
        missing += [f"ground truth's {k}" for k in ("ep_raw", *mult_names) if not np.isfinite(gt_of[k][i])]
        ep_reasons[i] = "n/a: needs " + ", ".join(missing)
    parts["ep"] = (ep, ep_reasons)

    pdms = _aggregate(parts, ("nc", "dac"), {"ep": _W_EP, "ttc": _W_TTC, "c": _W_C})
    filt = dict(parts)
    for k in FILTERED:
        filt[k] = _filtered(parts[k][0], gt_of[k], parts[k][1])
    filt["tlc"] = (np.ones(n), [None] * n)  # counted as 1, said so in tlc's own reason
    weights_v2 = {"ep": _W_EP, "ttc": _W_TTC, "lk": _W_LK, "hc": _W_HC, "ec": _W_EC}
    if with_agents:
        epdms = _aggregate(filt, ("nc", "dac", "ddc", "tlc"), weights_v2)
        epdms_map = (np.full(n, np.nan), ["annotations given: the score is epdms"] * n)
    else:
        epdms = (np.full(n, np.nan), [_REASONS["no_agents"] + ": see epdms_map"] * n)
        epdms_map = _aggregate(filt, ("dac", "ddc"), {"ep": _W_EP, "lk": _W_LK, "hc": _W_HC, "ec": _W_EC})

    values: dict[str, FloatArray] = {k: parts[k][0] for k in SUBSCORES}
    reasons: dict[str, list[str | None]] = {k: parts[k][1] for k in SUBSCORES}
    for k, (v, r) in (("pdms", pdms), ("epdms", epdms), ("epdms_map", epdms_map)):
        values[k], reasons[k] = v, r
    return DriveScores(values=values, reasons=reasons, gt=gt_v, ep_raw=plan["ep_raw"][0])
