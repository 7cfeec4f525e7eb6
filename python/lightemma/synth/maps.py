"""Maps and agents of the synthetic dataset, in the devkit's formats (docs/definitions.md#safety).

* **Road**: along each scene's ego path, from :data:`ROAD_RIGHT` (the ego lane's right edge) to
  :data:`ROAD_LEFT` (the far edge of the opposite lane) metres to the side — the drivable area;
  with the sidewalks (:data:`SIDEWALK` wide on each side) it is the *semantic prior* of the base
  map mask, as in nuScenes' ``maps/*.png`` (drivable surface and sidewalks).
* **Map expansion** ``maps/expansion/<location>.json`` (version 1.3, every layer present, only
  ``drivable_area`` / ``polygon`` / ``node`` filled): one polygon per scene.
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

from lightemma.synth.kinematics import Path
from lightemma.synth.scenarios import LANE_WIDTH, Scenario

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
        return (Agent("parked-1", "vehicle.car", s0=25.0, lateral=kerb), Agent("parked-2", "vehicle.car", s0=60.0, lateral=kerb))
    if scn.kind in ("left-turn", "right-turn"):
        return (
            Agent("pedestrian-kerb", "human.pedestrian.adult", s0=15.0, lateral=ROAD_RIGHT - 1.0, length=0.7, width=0.7, height=1.75),
            Agent("pedestrian-far", "human.pedestrian.adult", s0=40.0, lateral=ROAD_LEFT - 1.0, v=0.0, yaw_offset=math.pi / 2,
                  length=0.7, width=0.7, height=1.75),
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


def expansion_json(scenarios: list[Scenario], location: str, token) -> dict:
    """The map expansion of ``location``: one drivable_area polygon per scene (devkit ``NuScenesMap`` format)."""
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
    layers = ("line", "road_segment", "road_block", "lane", "ped_crossing", "walkway", "stop_line", "carpark_area",
              "road_divider", "lane_divider", "traffic_light", "lane_connector")
    doc: dict = {"version": "1.3", "canvas_edge": [max(xs) + MARGIN, max(ys) + MARGIN], "node": nodes, "polygon": polygons,
                 "drivable_area": areas, "arcline_path_3": {}, "connectivity": {}}
    doc.update({name: [] for name in layers})
    return doc


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
