"""Maps and agents of the synthetic dataset, in the devkit's formats (docs/definitions.md#safety).

* **Road**: along each scene's ego path, from :data:`ROAD_RIGHT` (the ego lane's right edge) to
  :data:`ROAD_LEFT` (the far edge of the opposite lane) metres to the side — the drivable area;
  with the sidewalks (:data:`SIDEWALK` wide on each side) it is the *semantic prior* of the base
  map mask, as in nuScenes' ``maps/*.png`` (drivable surface and sidewalks).
* **Map expansion** ``maps/expansion/<location>.json`` (version 1.3, every layer present): per scene one
  ``drivable_area`` polygon (the road above), and the road cut into *pieces* at the path's curvature changes
  (:func:`road_pieces`), the first :data:`CARPARK_LENGTH` metres of the road excepted:

  - ``lane`` (straight pieces) and ``lane_connector`` (curved pieces): per piece the **ego lane** (lateral
    −:data:`LANE_WIDTH`/2 … +:data:`LANE_WIDTH`/2, centreline = the ego path, driven along it) and the **oncoming
    lane** (+:data:`LANE_WIDTH`/2 … :data:`ROAD_LEFT`, centreline :data:`LANE_WIDTH` to the left, driven the other
    way); lanes carry ``from_edge_line_token`` / ``to_edge_line_token`` (``line`` records across the lane at its
    start and end in its driving direction); ``arcline_path_3`` holds each lane's and connector's centreline as
    arcline paths in the devkit's format (``start_pose``, ``end_pose`` [x, y, yaw], ``shape``, ``radius``,
    ``segment_length`` [a, b, c]): a straight piece is ``LSR`` with lengths [0, L, 0] and radius
    :data:`STRAIGHT_RADIUS`, a curve ``LSL`` / ``RSR`` with lengths [L, 0, 0] and its radius; ``connectivity``
    links each direction's chain (``incoming`` / ``outgoing``);
  - ``road_segment``: per piece the whole road width, ``is_intersection`` true on curved pieces (where the
    scenario turns: left-turn, right-turn, straight-after-turn), ``drivable_area_token`` the scene's drivable area;
  - ``carpark_area``: the first :data:`CARPARK_LENGTH` m of the road (behind the ego's start, inside the drivable
    area), ``orientation`` the road's heading there, no road block (``road_block_token`` "").

  Lane and road-segment polygons lie inside the drivable-area polygon (same lateral edges), so the
  drivable area — and every number computed from it — is what it was before the lanes were added.
* **Base map mask** ``maps/<token>.png``, one per location (the ``map`` table lists its logs), at
  0.1 m/px with the devkit's ``MapMask`` transform: global (x, y) → pixel (x / 0.1, H − y / 0.1);
  255 drivable-or-sidewalk, 0 elsewhere.
* **Placement**: scenes of one location lie side by side along +x from the origin, their roads
  :data:`GAP` metres apart, so that one scene's road never serves as another's and the mask stays small.
* **Agents** (:class:`Agent`): parked cars at the right kerb, oncoming cars in the opposite lane,
  pedestrians on the sidewalk, at known arc lengths and lateral offsets along the ego path.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from lightemma.errors import InputError
from lightemma.synth.motion import Path
from lightemma.synth.situations import LANE_WIDTH, Scenario, build_scenario

ROAD_RIGHT = -LANE_WIDTH / 2  # m, lateral (left positive) of the ego lane's right edge
ROAD_LEFT = LANE_WIDTH * 1.5  # m, the opposite lane's far edge
SIDEWALK = 2.5  # m, on either side (on the mask, off the drivable polygons)
ROAD_BEFORE, ROAD_AFTER = 40.0, 60.0  # m of road before the first and after the last ego position
GAP = 40.0  # m between the roads of two scenes
MARGIN = 20.0  # m from the origin to the first road
STEP = 1.0  # m between sampled road outline points
RESOLUTION = 0.1  # m per mask pixel (the devkit's MapMask)
MAX_MASK_PIXELS = 64_000_000  # larger masks are not written (the expansion still is)


@dataclass(frozen=True)
class Agent:
    """An annotated agent moving along the ego path: arc length ``s0`` (m, ahead of the ego's start)
    and ``lateral`` offset (m, left positive) at t = 0, speed ``v`` (m/s along the path; negative:
    oncoming), heading ``yaw_offset`` (rad) relative to the path."""

    name: str
    category: str
    s0: float
    lateral: float
    v: float = 0.0
    yaw_offset: float = 0.0
    length: float = 4.5
    width: float = 1.9
    height: float = 1.6

    def pose(self, path: Path, s_start: float, t) -> np.ndarray:
        """Global (x, y, yaw) at scene time(s) ``t``: shape (..., 3)."""
        t = np.asarray(t, dtype=np.float64)
        p = path.pose(s_start + self.s0 + self.v * t)
        x = p[..., 0] - self.lateral * np.sin(p[..., 2])
        y = p[..., 1] + self.lateral * np.cos(p[..., 2])
        return np.stack([x, y, p[..., 2] + self.yaw_offset], axis=-1)


def scene_agents(scn: Scenario) -> tuple[Agent, ...]:
    """The agents of a scene besides its lead vehicle (deterministic per kind).

    * ``cruise``: an oncoming car in the opposite lane;
    * ``accelerate`` and ``straight-after-turn``: two cars parked at the right kerb;
    * ``left-turn`` / ``right-turn``: a pedestrian on the right sidewalk and one crossing the far lane;
    * ``brake-red-light``: a parked car at the right kerb just before the stop.
    """
    kerb = ROAD_RIGHT - 0.2 - 0.95  # a 1.9 m wide car 0.2 m outside the lane edge
    if scn.kind == "cruise":
        v = float(scn.params.get("speed", 10.0))
        return (Agent("oncoming", "vehicle.car", s0=120.0, lateral=LANE_WIDTH, v=-v, yaw_offset=math.pi),)
    if scn.kind in ("accelerate", "straight-after-turn"):
        return (
            Agent("parked-1", "vehicle.car", s0=25.0, lateral=kerb),
            Agent("parked-2", "vehicle.car", s0=60.0, lateral=kerb),
        )
    if scn.kind in ("left-turn", "right-turn"):
        return (
            Agent(
                "pedestrian-kerb",
                "human.pedestrian.adult",
                s0=15.0,
                lateral=ROAD_RIGHT - 1.0,
                length=0.7,
                width=0.7,
                height=1.75,
            ),
            Agent(
                "pedestrian-far",
                "human.pedestrian.adult",
                s0=40.0,
                lateral=ROAD_LEFT - 1.0,
                v=0.0,
                yaw_offset=math.pi / 2,
                length=0.7,
                width=0.7,
                height=1.75,
            ),
        )
    if scn.kind == "brake-red-light":
        return (Agent("parked", "vehicle.car", s0=20.0, lateral=kerb),)
    return ()


def _arc_range(scn: Scenario) -> tuple[float, float]:
    s = scn.profile.s(np.array([0.0, scn.duration]))
    return float(s[0]) - ROAD_BEFORE, float(s[1]) + ROAD_AFTER


def road_outline(scn: Scenario, right: float, left: float) -> np.ndarray:
    """(M, 2) global polygon (counter-clockwise) of the strip from ``right`` to ``left`` metres beside the path."""
    a, b = _arc_range(scn)
    s = np.linspace(a, b, max(2, int(math.ceil((b - a) / STEP)) + 1))
    p = scn.path.pose(s)
    nx, ny = -np.sin(p[:, 2]), np.cos(p[:, 2])
    r = np.column_stack([p[:, 0] + right * nx, p[:, 1] + right * ny])
    lft = np.column_stack([p[:, 0] + left * nx, p[:, 1] + left * ny])
    return np.concatenate([r, lft[::-1]])


def place_scenarios(scenarios: list[Scenario]) -> list[Scenario]:
    """The scenarios moved (not turned) so that each location's roads lie side by side from the origin."""
    cursor: dict[str, float] = {}
    out = []
    for scn in scenarios:
        outline = road_outline(scn, ROAD_RIGHT - SIDEWALK, ROAD_LEFT + SIDEWALK)
        lo, hi = outline.min(axis=0), outline.max(axis=0)
        x_at = cursor.get(scn.location, MARGIN)
        dx, dy = x_at - lo[0], MARGIN - lo[1]
        path = dataclasses.replace(scn.path, x0=scn.path.x0 + dx, y0=scn.path.y0 + dy)
        out.append(dataclasses.replace(scn, path=path))
        cursor[scn.location] = x_at + (hi[0] - lo[0]) + GAP
    return out


def build_scenarios(scenes: int = 8, *, seed: int = 0, keyframes: int = 40) -> list[Scenario]:
    """Scenarios of scenes ``0 … scenes−1`` for ``seed`` (kinds cycle through :data:`KINDS`), placed so that
    each location's roads lie side by side near the map origin (:func:`place_scenarios`)."""
    if scenes < 1:
        raise InputError(f"need at least one scene, got {scenes}")
    return place_scenarios([build_scenario(i, seed=seed, keyframes=keyframes) for i in range(scenes)])


#: metres of each road, from its start, that are a car park instead of lanes (behind every ego position)
CARPARK_LENGTH = 10.0
#: radius (m) written for straight arcline paths (their arcs have length 0: the value only avoids a division by 0)
STRAIGHT_RADIUS = 1000.0
#: lateral offsets (m, left of the ego path) of the lane edges: ego lane right edge, the centre line between the
#: two lanes, the oncoming lane's far edge
_EDGES = {"r": ROAD_RIGHT, "m": LANE_WIDTH / 2, "l": ROAD_LEFT}


@dataclass(frozen=True)
class Piece:
    """A stretch of a scene's road between arc lengths ``s_from`` < ``s_to`` (m, along the ego path) of constant
    ``curvature`` (1/m, left positive): a lane per direction, or a lane connector in an intersection when curved."""

    s_from: float
    s_to: float
    curvature: float

    @property
    def curved(self) -> bool:
        return self.curvature != 0.0


def road_pieces(scn: Scenario) -> list[Piece]:
    """The road of ``scn`` after its car park (:data:`CARPARK_LENGTH`), cut where the path's curvature changes."""
    a, b = _arc_range(scn)
    a += CARPARK_LENGTH
    cuts = np.cumsum([0.0] + [length for length, _ in scn.path.segments])
    edges = [a, *sorted(float(c) for c in cuts if a < c < b), b]
    pieces: list[Piece] = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        k = float(scn.path.curvature(0.5 * (lo + hi)))
        if pieces and pieces[-1].curvature == k:
            pieces[-1] = Piece(pieces[-1].s_from, hi, k)
        else:
            pieces.append(Piece(lo, hi, k))
    return pieces


def _samples(lo: float, hi: float) -> np.ndarray:
    return np.linspace(lo, hi, max(2, int(math.ceil((hi - lo) / STEP)) + 1))


def _beside(scn: Scenario, s: np.ndarray, lateral: float) -> np.ndarray:
    """(M, 3) poses ``lateral`` metres left of the ego path at arc lengths ``s`` (heading of the path)."""
    p = scn.path.pose(s)
    return np.column_stack([p[:, 0] - lateral * np.sin(p[:, 2]), p[:, 1] + lateral * np.cos(p[:, 2]), p[:, 2]])


def lane_centreline(scn: Scenario, piece: Piece, oncoming: bool, step: float = 0.1) -> np.ndarray:
    """(M, 3) exact centreline poses (x, y, yaw in [−π, π)) of a piece's ego (``oncoming`` False) or oncoming lane,
    in its driving direction, every ``step`` m or less of the ego path."""
    s = np.linspace(piece.s_from, piece.s_to, max(2, int(math.ceil((piece.s_to - piece.s_from) / step)) + 1))
    if oncoming:
        pts = _beside(scn, s[::-1], LANE_WIDTH)
        pts[:, 2] += math.pi
    else:
        pts = _beside(scn, s, 0.0)
    pts[:, 2] = (pts[:, 2] + math.pi) % (2 * math.pi) - math.pi
    return pts


def arcline_path(scn: Scenario, piece: Piece, oncoming: bool) -> dict:
    """The arcline path (devkit ``arcline_path_3`` format) of a piece's ego or oncoming lane centreline.

    Ego lane: the path itself. Oncoming lane: :data:`LANE_WIDTH` to the left, driven backwards, so its curvature is
    −κ / (1 − κ·LANE_WIDTH) (a left turn of the ego path is a right turn of radius R − LANE_WIDTH for it)."""
    line = lane_centreline(scn, piece, oncoming, step=piece.s_to - piece.s_from)
    start, end = [float(v) for v in line[0]], [float(v) for v in line[-1]]
    ds = piece.s_to - piece.s_from
    if not piece.curved:
        return {
            "start_pose": start,
            "end_pose": end,
            "shape": "LSR",
            "radius": STRAIGHT_RADIUS,
            "segment_length": [0.0, float(ds), 0.0],
        }
    k = piece.curvature
    if oncoming:
        k = -k / (1.0 - k * LANE_WIDTH)
    length = abs(piece.curvature * ds / k)  # the same turn angle on the offset curve
    return {
        "start_pose": start,
        "end_pose": end,
        "shape": "LSL" if k > 0 else "RSR",
        "radius": float(1.0 / abs(k)),
        "segment_length": [float(length), 0.0, 0.0],
    }


def expansion_json(scenarios: list[Scenario], location: str, token) -> dict:
    """The map expansion of ``location`` (devkit ``NuScenesMap`` format, version 1.3; the layers are described in
    this module's docstring). ``token(*parts)`` makes a record token; same scenarios, same document."""
    nodes, polygons, areas = [], [], []
    for scn in scenarios:
        outline = road_outline(scn, ROAD_RIGHT, ROAD_LEFT)
        node_tokens = []
        for j, (x, y) in enumerate(outline):
            t = token("node", location, scn.index, j)
            nodes.append({"token": t, "x": float(x), "y": float(y)})
            node_tokens.append(t)
        ptok = token("polygon", location, scn.index)
        polygons.append({"token": ptok, "exterior_node_tokens": node_tokens, "holes": []})
        areas.append({"token": token("drivable_area", location, scn.index), "polygon_tokens": [ptok]})
    xs = [n["x"] for n in nodes] or [0.0]
    ys = [n["y"] for n in nodes] or [0.0]
    layers = (
        "line",
        "road_segment",
        "road_block",
        "lane",
        "ped_crossing",
        "walkway",
        "stop_line",
        "carpark_area",
        "road_divider",
        "lane_divider",
        "traffic_light",
        "lane_connector",
    )
    doc: dict = {
        "version": "1.3",
        "canvas_edge": [max(xs) + MARGIN, max(ys) + MARGIN],
        "node": nodes,
        "polygon": polygons,
        "drivable_area": areas,
        "arcline_path_3": {},
        "connectivity": {},
    }
    doc.update({name: [] for name in layers})
    for scn in scenarios:
        _road_layers(doc, scn, location, token)
    return doc


def _road_layers(doc: dict, scn: Scenario, location: str, token) -> None:
    """Add the lanes, lane connectors, road segments and car park of one scene to ``doc`` (nodes on the lane edges
    are shared: a node's token names its scene, edge and arc length)."""
    known = {n["token"] for n in doc["node"]}

    def node(edge: str, s: float) -> str:
        key = f"{s:.6f}"
        t = token("node", location, scn.index, "edge", edge, key)
        if t not in known:
            x, y, _ = _beside(scn, np.array([float(key)]), _EDGES[edge])[0]
            doc["node"].append({"token": t, "x": float(x), "y": float(y)})
            known.add(t)
        return t

    def polygon(name: str, lo: float, hi: float, right: str, left: str) -> str:
        s = _samples(lo, hi)
        ring = [node(right, v) for v in s] + [node(left, v) for v in s[::-1]]
        t = token("polygon", location, scn.index, name)
        doc["polygon"].append({"token": t, "exterior_node_tokens": ring, "holes": []})
        return t

    def line(name: str, s: float, a: str, b: str) -> str:
        t = token("line", location, scn.index, name)
        doc["line"].append({"token": t, "node_tokens": [node(a, s), node(b, s)]})
        return t

    a, _ = _arc_range(scn)
    area = token("drivable_area", location, scn.index)
    yaw = float(scn.path.pose(a)[2])
    doc["carpark_area"].append(
        {
            "token": token("carpark_area", location, scn.index),
            "polygon_token": polygon("carpark", a, a + CARPARK_LENGTH, "r", "l"),
            "orientation": float((yaw + math.pi) % (2 * math.pi) - math.pi),
            "road_block_token": "",
        }
    )
    chains: dict[bool, list[str]] = {False: [], True: []}
    for i, piece in enumerate(road_pieces(scn)):
        doc["road_segment"].append(
            {
                "token": token("road_segment", location, scn.index, i),
                "polygon_token": polygon(f"road_segment-{i}", piece.s_from, piece.s_to, "r", "l"),
                "is_intersection": piece.curved,
                "drivable_area_token": area,
            }
        )
        for oncoming in (False, True):
            name = f"{'oncoming' if oncoming else 'ego'}-{i}"
            t = token("lane", location, scn.index, name)
            right, left = ("l", "m") if oncoming else ("r", "m")  # the lane's edges, in its driving direction
            ptok = polygon(name, piece.s_from, piece.s_to, *(("m", "l") if oncoming else ("r", "m")))
            if piece.curved:
                doc["lane_connector"].append({"token": t, "polygon_token": ptok})
            else:
                start, end = (piece.s_to, piece.s_from) if oncoming else (piece.s_from, piece.s_to)
                doc["lane"].append(
                    {
                        "token": t,
                        "polygon_token": ptok,
                        "lane_type": "CAR",
                        "from_edge_line_token": line(f"{name}-from", start, right, left),
                        "to_edge_line_token": line(f"{name}-to", end, right, left),
                        "left_lane_divider_segments": [],
                        "right_lane_divider_segments": [],
                    }
                )
            doc["arcline_path_3"][t] = [arcline_path(scn, piece, oncoming)]
            chains[oncoming].append(t)
    chains[True].reverse()  # the oncoming lane is driven from the road's far end
    for chain in chains.values():
        for j, t in enumerate(chain):
            doc["connectivity"][t] = {"incoming": chain[j - 1 : j] if j else [], "outgoing": chain[j + 1 : j + 2]}


def mask_image(scenarios: list[Scenario]) -> np.ndarray | None:
    """(H, W) uint8 semantic prior of the scenes' roads and sidewalks, or None when larger than :data:`MAX_MASK_PIXELS`."""
    from PIL import Image, ImageDraw

    outlines = [road_outline(s, ROAD_RIGHT - SIDEWALK, ROAD_LEFT + SIDEWALK) for s in scenarios]
    top = max(o.max(axis=0)[0] for o in outlines), max(o.max(axis=0)[1] for o in outlines)
    width, height = int(math.ceil((top[0] + MARGIN) / RESOLUTION)), int(math.ceil((top[1] + MARGIN) / RESOLUTION))
    if width * height > MAX_MASK_PIXELS:
        return None
    img = Image.new("L", (width, height), 0)
    draw = ImageDraw.Draw(img)
    for o in outlines:
        draw.polygon([(x / RESOLUTION, height - y / RESOLUTION) for x, y in o], fill=255)
    return np.array(img)
