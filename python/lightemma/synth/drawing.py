"""Draw the CAM_FRONT image of a synthetic scene with Pillow.

The picture is a true pinhole projection through the same calibration that
the tables record (see :mod:`lightemma.synth.camera`): sky and ground, the
road following the ego's path with its lane markings, a stop line and a
crossing road at intersections, the lead vehicle as a shaded box with brake
lights, and the traffic light with its lit colour (drawn no smaller than a
few pixels so that a vision-language model can read it).
"""

from __future__ import annotations

import functools
import math

import numpy as np
from PIL import Image, ImageDraw

from lightemma.synth.camera import Camera
from lightemma.synth.situations import LANE_WIDTH, Scenario

NEAR = 0.5  # m: camera-space near plane for clipping
ASPHALT = (88, 88, 92)
GRASS = (96, 122, 78)
WHITE = (235, 235, 235)
YELLOW = (230, 190, 40)
LAMP_ON = {"red": (255, 40, 30), "yellow": (255, 200, 0), "green": (40, 255, 90)}
LAMP_OFF = (55, 55, 55)
LAMP_ORDER = ("red", "yellow", "green")

RIGHT_EDGE = -LANE_WIDTH / 2  # ego lane right boundary (solid white)
CENTRE = LANE_WIDTH / 2  # double yellow between ego lane and the opposite lane
LEFT_EDGE = LANE_WIDTH * 1.5  # far edge of the opposite lane (solid white)
SHOULDER = 0.6


class _View:
    """World → ego → camera → pixel for one image."""

    def __init__(self, camera: Camera, ego_pose: np.ndarray):
        self.camera = camera
        self.x, self.y, self.yaw = (float(v) for v in ego_pose)
        self.c, self.s = math.cos(self.yaw), math.sin(self.yaw)

    def to_cam(self, pts: np.ndarray) -> np.ndarray:
        """World points ``(N, 3)`` to camera coordinates ``(N, 3)``."""
        dx = pts[:, 0] - self.x
        dy = pts[:, 1] - self.y
        ego = np.stack([self.c * dx + self.s * dy, -self.s * dx + self.c * dy, pts[:, 2]], axis=-1)
        return self.camera.ego_to_cam(ego)

    def polygon(self, draw: ImageDraw.ImageDraw, pts_world: np.ndarray, fill) -> None:
        """Fill a planar world polygon, clipped at the near plane."""
        cam = _clip_near(self.to_cam(pts_world))
        if len(cam) >= 3:
            uv = self.camera.project(cam)
            draw.polygon([tuple(p) for p in uv.tolist()], fill=fill)

    def polygons(self, draw: ImageDraw.ImageDraw, quads: np.ndarray, fill) -> None:
        """Fill many world quads ``(Q, 4, 3)`` at once (vectorised; clips only those crossing the near plane)."""
        if len(quads) == 0:
            return
        cam = self.to_cam(quads.reshape(-1, 3)).reshape(quads.shape)
        inside = cam[..., 2] >= NEAR
        whole = inside.all(axis=1)
        if whole.any():
            uv = self.camera.project(cam[whole].reshape(-1, 3)).reshape(-1, 4, 2)
            w, h = self.camera.width, self.camera.height
            lo, hi = uv.min(axis=1), uv.max(axis=1)
            visible = (hi[:, 0] >= 0) & (lo[:, 0] <= w) & (hi[:, 1] >= 0) & (lo[:, 1] <= h)
            for quad in uv[visible].tolist():
                draw.polygon([tuple(p) for p in quad], fill=fill)
        for q in cam[inside.any(axis=1) & ~whole]:
            clipped = _clip_near(q)
            if len(clipped) >= 3:
                draw.polygon([tuple(p) for p in self.camera.project(clipped).tolist()], fill=fill)


def _clip_near(poly: np.ndarray) -> np.ndarray:
    """Sutherland–Hodgman clip of a camera-space polygon to Z ≥ NEAR."""
    out = []
    n = len(poly)
    for i in range(n):
        a, b = poly[i], poly[(i + 1) % n]
        a_in, b_in = a[2] >= NEAR, b[2] >= NEAR
        if a_in:
            out.append(a)
        if a_in != b_in:
            f = (NEAR - a[2]) / (b[2] - a[2])
            out.append(a + f * (b - a))
    return np.array(out).reshape(-1, 3)


def _strip(pose: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Quads ``(Q, 4, 3)`` of a band between lateral offsets ``lo`` and ``hi`` along path poses ``(Q+1, 3)``."""
    nx, ny = -np.sin(pose[:, 2]), np.cos(pose[:, 2])
    zeros = np.zeros(len(pose))
    left = np.stack([pose[:, 0] + hi * nx, pose[:, 1] + hi * ny, zeros], axis=-1)
    right = np.stack([pose[:, 0] + lo * nx, pose[:, 1] + lo * ny, zeros], axis=-1)
    return np.stack([right[:-1], right[1:], left[1:], left[:-1]], axis=1)


def _axes(yaw: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit heading ``h`` and left normal ``n`` (in the ground plane) of a pose with ``yaw``."""
    return np.array([math.cos(yaw), math.sin(yaw), 0.0]), np.array([-math.sin(yaw), math.cos(yaw), 0.0])


@functools.lru_cache(maxsize=8)
def _sky(width: int, rows: int) -> Image.Image:
    """The sky gradient above the horizon: the same for every image of a camera, so built once (read-only)."""
    f = np.linspace(0.0, 1.0, rows)[:, None]
    sky = np.stack([120 + 70 * f, 160 + 55 * f, 215 + 25 * f], axis=-1).astype(np.uint8)
    return Image.fromarray(np.repeat(sky, width, axis=1))


def _background(img: Image.Image, horizon: float) -> None:
    w, h = img.size
    hz = int(max(0, min(h, round(horizon))))
    if hz > 0:
        img.paste(_sky(w, hz), (0, 0))
    ImageDraw.Draw(img).rectangle([0, hz, w, h], fill=GRASS)


def _road(draw: ImageDraw.ImageDraw, view: _View, scn: Scenario, s_ego: float) -> None:
    # fine steps near the camera, coarser far away
    s = np.concatenate([np.arange(-6.0, 40.0, 1.0), np.arange(40.0, 150.0, 2.5)]) + s_ego
    pose = scn.path.pose(s)
    view.polygons(draw, _strip(pose, RIGHT_EDGE - SHOULDER, LEFT_EDGE + SHOULDER), ASPHALT)
    lines = [
        (RIGHT_EDGE - 0.075, RIGHT_EDGE + 0.075, WHITE),
        (LEFT_EDGE - 0.075, LEFT_EDGE + 0.075, WHITE),
        (CENTRE - 0.2, CENTRE - 0.08, YELLOW),
        (CENTRE + 0.08, CENTRE + 0.2, YELLOW),
    ]
    for lo, hi, colour in lines:
        view.polygons(draw, _strip(pose, lo, hi), colour)


def _intersection(draw: ImageDraw.ImageDraw, view: _View, scn: Scenario) -> None:
    """Crossing road beyond the stop line (the stop line is drawn over the road, see render_frame)."""
    assert scn.light is not None
    x, y, yaw = scn.path.pose(scn.light.stop_s)
    h, n = _axes(yaw)
    base = np.array([x, y, 0.0])
    centre = base + scn.light.crossing * h
    half_w, half_l = 6.0, 60.0
    quad = np.stack(
        [
            centre - half_w * h - half_l * n,
            centre + half_w * h - half_l * n,
            centre + half_w * h + half_l * n,
            centre - half_w * h + half_l * n,
        ]
    )
    view.polygon(draw, quad, ASPHALT)


def _traffic_light(draw: ImageDraw.ImageDraw, view: _View, scn: Scenario, t: float, width: int) -> None:
    assert scn.light is not None
    colour = scn.light_colour(t)
    x, y, yaw = scn.path.pose(scn.light.stop_s)
    h, n = _axes(yaw)
    far = np.array([x, y, 0.0]) + (scn.light.crossing + 7.5) * h  # on the far side of the crossing
    pole_base = far + (RIGHT_EDGE - 2.5) * n
    pole_top = pole_base + np.array([0, 0, 6.0])
    arm_end = far + 0.0 * n + np.array([0, 0, 6.0])
    cam = view.to_cam(np.stack([pole_base, pole_top, arm_end]))
    if np.any(cam[:, 2] < NEAR):
        return
    uv = view.camera.project(cam)
    f = view.camera.intrinsic[0, 0]
    pole_px = max(2, int(round(0.2 * f / cam[0, 2])))
    draw.line([tuple(uv[0]), tuple(uv[1])], fill=(70, 70, 70), width=pole_px)
    draw.line([tuple(uv[1]), tuple(uv[2])], fill=(70, 70, 70), width=max(2, pole_px - 1))
    # two signal heads: over the lane (hanging from the arm) and on the pole
    min_lamp = max(3.0, width / 220.0)
    for anchor in (arm_end - np.array([0, 0, 0.7]), pole_base + np.array([0, 0, 3.6])):
        c = view.to_cam(anchor[None])[0]
        if c[2] < NEAR:
            continue
        u, v = view.camera.project(c[None])[0]
        r = max(min_lamp, 0.15 * f / c[2])
        hw, hh = 1.6 * r, 4.9 * r
        draw.rectangle([u - hw, v - hh, u + hw, v + hh], fill=(25, 25, 25), outline=(10, 10, 10))
        for k, name in enumerate(LAMP_ORDER):
            cy = v + (k - 1) * 3.2 * r
            fill = LAMP_ON[name] if name == colour else LAMP_OFF
            draw.ellipse([u - r, cy - r, u + r, cy + r], fill=fill)


def _lead(draw: ImageDraw.ImageDraw, view: _View, scn: Scenario, t: float) -> None:
    lead = scn.lead
    assert lead is not None
    pose = scn.lead_pose(t)
    assert pose is not None  # scn has a lead
    x, y, yaw = pose
    h, n = _axes(yaw)
    c = np.array([x, y, 0.0])
    up = np.array([0.0, 0.0, 1.0])
    hl, hw = lead.length / 2, lead.width / 2
    z0, z1 = 0.3, lead.height

    def corner(a, b, z):
        return c + a * hl * h + b * hw * n + z * up

    faces = {
        "rear": [corner(-1, -1, z0), corner(-1, 1, z0), corner(-1, 1, z1), corner(-1, -1, z1)],
        "front": [corner(1, -1, z0), corner(1, 1, z0), corner(1, 1, z1), corner(1, -1, z1)],
        "left": [corner(-1, 1, z0), corner(1, 1, z0), corner(1, 1, z1), corner(-1, 1, z1)],
        "right": [corner(-1, -1, z0), corner(1, -1, z0), corner(1, -1, z1), corner(-1, -1, z1)],
        "top": [corner(-1, -1, z1), corner(1, -1, z1), corner(1, 1, z1), corner(-1, 1, z1)],
    }
    shade = {"rear": 0.85, "front": 0.85, "left": 0.65, "right": 0.65, "top": 1.1}
    order = sorted(faces, key=lambda k: -float(np.mean(view.to_cam(np.array(faces[k]))[:, 2])))
    for name in order:
        col = tuple(int(min(255, ch * shade[name])) for ch in lead.color)
        view.polygon(draw, np.array(faces[name]), col)
    # shadow-dark bumper band, rear window and brake lights on the rear face
    braking = float(lead.profile.a(t)) < 0 or float(lead.profile.v(t)) < 0.1  # v: scn.lead_speed
    lamp = (255, 30, 30) if braking else (140, 25, 25)
    view.polygon(
        draw,
        np.array([corner(-1, -0.85, 0.95), corner(-1, 0.85, 0.95), corner(-1, 0.85, 1.4), corner(-1, -0.85, 1.4)]),
        (30, 35, 45),
    )
    for b0, b1 in ((-0.95, -0.65), (0.65, 0.95)):
        view.polygon(
            draw, np.array([corner(-1, b0, 0.7), corner(-1, b1, 0.7), corner(-1, b1, 0.88), corner(-1, b0, 0.88)]), lamp
        )


def render_frame(scn: Scenario, t: float, camera: Camera) -> Image.Image:
    """The CAM_FRONT image of ``scn`` at scene time ``t`` (s)."""
    w, h = camera.width, camera.height
    img = Image.new("RGB", (w, h))
    view = _View(camera, scn.pose(t))
    horizon = camera.project(camera.ego_to_cam(np.array([[1e4, 0.0, 0.0]])))[0, 1]
    _background(img, horizon)
    draw = ImageDraw.Draw(img)
    if scn.light is not None:
        _intersection(draw, view, scn)
    s_ego = float(scn.profile.s(t))
    _road(draw, view, scn, s_ego)
    if scn.light is not None and scn.light.stop_s - s_ego > 1.0:
        _stop_line(draw, view, scn)
    if scn.lead is not None:
        _lead(draw, view, scn, t)
    if scn.light is not None:
        _traffic_light(draw, view, scn, t, w)
    return img


def _stop_line(draw: ImageDraw.ImageDraw, view: _View, scn: Scenario) -> None:
    """The stop line across the ego lane, drawn over the road surface."""
    assert scn.light is not None
    x, y, yaw = scn.path.pose(scn.light.stop_s)
    h, n = _axes(yaw)
    base = np.array([x, y, 0.0])
    stop = np.stack(
        [base + RIGHT_EDGE * n, base + RIGHT_EDGE * n - 0.5 * h, base + CENTRE * n - 0.5 * h, base + CENTRE * n]
    )
    view.polygon(draw, stop, WHITE)
