"""Bird's-eye view of one frame's safety (docs/definitions.md#safety): the map patch around the ego, the
annotated agents' boxes over the next 3 s, every model's ego footprints along its trajectory and the ground
truth's, collisions and off-road steps marked.

Drawn in the ego frame of the keyframe, as the camera sees it and as the frame pictures' bird's-eye views are
(nuScenes: x forward, y left): forward up, left on the left (:func:`bev_transform`). The global frame's map view
turned each frame by its heading, so that a car heading south showed its left on the right of the picture."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from lightemma.evaluation import safety as S
from lightemma.nuscenes.map_files import MASK_RESOLUTION
from lightemma.report.figures._mpl import COLLISION_RED, GT_COLOR, pyplot

COLLISION_COLOR = COLLISION_RED
# drawing order (matplotlib zorder): map < model footprints < agent boxes < model paths < truth footprints < truth path
Z_MODEL, Z_AGENT, Z_MODEL_PATH, Z_TRUTH, Z_TRUTH_PATH, Z_EGO = 3, 3.5, 4, 5, 6, 7


def box_corners(boxes: np.ndarray) -> np.ndarray:
    """(K, 4, 2) corners of boxes (K, 5) = centre x, y, yaw, length, width (front-left, front-right, rear-right, rear-left)."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 5)
    c, s = np.cos(b[:, 2]), np.sin(b[:, 2])
    a = np.stack([c, s], axis=1) * (b[:, 3:4] / 2)
    n = np.stack([-s, c], axis=1) * (b[:, 4:5] / 2)
    ctr = b[:, :2]
    return np.stack([ctr + a + n, ctr + a - n, ctr - a - n, ctr - a + n], axis=1)


def bev_transform(pose: Any) -> Any:
    """The matplotlib :class:`~matplotlib.transforms.Affine2D` from global (x, y) in metres to the view's
    (−y_ego, x_ego) in metres: the ego at the origin, its heading up, its left to the left. ``pose``: the
    keyframe's global (x, y, yaw) (m, m, rad). A rotation (no mirror): global geometry keeps its handedness."""
    from matplotlib.transforms import Affine2D

    return Affine2D().translate(-float(pose[0]), -float(pose[1])).rotate(np.pi / 2 - float(pose[2]))


def _map_patch(ax: Any, area: Any, centre: np.ndarray, radius: float, transform: Any) -> None:
    from matplotlib.patches import Polygon as MplPolygon

    if area is None:
        return
    if area.kind == "mask":
        r = MASK_RESOLUTION
        h, w = area.mask.shape
        px0, px1 = int(max(0, (centre[0] - radius) / r)), int(min(w - 1, (centre[0] + radius) / r))
        py0, py1 = int(max(0, h - (centre[1] + radius) / r)), int(min(h - 1, h - (centre[1] - radius) / r))
        if px1 > px0 and py1 > py0:
            crop = area.mask[py0 : py1 + 1, px0 : px1 + 1] == 255
            ax.imshow(
                np.where(crop, 0.85, 1.0),
                cmap="gray",
                vmin=0,
                vmax=1,
                origin="upper",
                interpolation="nearest",
                extent=((px0 - 0.5) * r, (px1 + 0.5) * r, (h - py1 - 0.5) * r, (h - py0 + 0.5) * r),
                zorder=0,
                transform=transform,
            )
        return
    for p in range(len(area.polygons) - 1):
        r0, r1 = area.polygons[p], area.polygons[p + 1]
        for k, ring in enumerate(range(r0, r1)):
            pts = area.xy[area.rings[ring] : area.rings[ring + 1]]
            if len(pts) < 3 or (np.abs(pts - centre).min(axis=0) > radius * 4).any():
                continue
            ax.add_patch(
                MplPolygon(
                    pts,
                    closed=True,
                    facecolor="#d9d9d9" if k == 0 else "white",
                    edgecolor="#9a9a9a",
                    lw=0.6,
                    zorder=0 if k == 0 else 0.5,
                    transform=transform,
                )
            )


def bev_figure(
    frame_id: str,
    trajectories: Sequence[tuple[str, np.ndarray, str]],
    gt: np.ndarray | None,
    data: Any,
    *,
    ego: Any = None,
    radius: float = 35.0,
) -> Any:
    """A top view of frame ``frame_id`` (``scene/sample_token``) in its ego frame (:func:`bev_transform`: forward up, left
    on the left; axes in metres, the lateral ticks reading y), ``radius`` metres to each side, 1.6 ``radius`` ahead and
    0.4 ``radius`` behind.

    ``trajectories``: (label, (6, 2) ego-frame positions, colour) per model; ``gt``: the ground truth (6, 2);
    ``data``: the :class:`~lightemma.evaluation.safety.SafetyData` of the frame's dataset. Grey: the drivable
    area (expansion polygons, or the base mask's drivable-and-sidewalk pixels); thin black boxes: the agents at the
    six future keyframes (darker = later), drawn over the models' footprints so that an agent hit stays visible;
    coloured outlines: the footprints, filled red where they overlap an agent, dashed red where a corner is off the
    drivable area. The ground truth is drawn last, over every model (zorder :data:`Z_TRUTH`, :data:`Z_TRUTH_PATH`).
    """
    from matplotlib.patches import Polygon as MplPolygon
    from matplotlib.ticker import FuncFormatter

    ego = ego or S.EGO
    plt = pyplot()
    token = S.sample_token_of(frame_id)
    fig, ax = plt.subplots(figsize=(6.4, 6.4))
    pose = data.poses.get(token)
    if pose is None:
        ax.text(0.5, 0.5, f"no ego pose for {token}", ha="center", transform=ax.transAxes)
        return fig
    centre = np.asarray(pose[:2])
    tr = bev_transform(pose) + ax.transData
    key = data.map_of.get(token)
    area = data.areas.get(key) if key else None
    _map_patch(
        ax, area if isinstance(area, S.DrivableArea) else None, centre, radius * 2.0, tr
    )  # > |(1, 1.6)|: the view's far corners
    future = data.future.get(token, [])
    for k, ft in enumerate(future):
        for corners in box_corners(data.boxes.get(ft, np.zeros((0, 5)))):
            ax.add_patch(
                MplPolygon(
                    corners,
                    closed=True,
                    fill=False,
                    edgecolor=str(0.65 - 0.1 * k),
                    lw=0.8,
                    zorder=Z_AGENT,
                    transform=tr,
                )
            )
    series = [(label, traj, color, False) for label, traj, color in trajectories]
    if gt is not None:
        series.append(("ground truth", gt, GT_COLOR, True))  # last: over every model
    for label, traj, color, truth in series:
        traj = np.asarray(traj, dtype=np.float64).reshape(1, -1, 2)
        if not np.isfinite(traj).all():
            continue
        fs = S.frame_safety(traj, [token], data, ego) if traj.shape[1] == S.STEPS else None
        corners = S.footprints(traj, np.asarray([pose]), ego)[0]
        for k, c in enumerate(corners):
            hit = fs is not None and fs.coll_ok[0] and fs.collide[0, k].any()
            off = fs is not None and fs.area_ok[0] and fs.off_steps[0, k]
            ax.add_patch(
                MplPolygon(
                    c,
                    closed=True,
                    fill=hit,
                    facecolor=COLLISION_COLOR if hit else "none",
                    alpha=0.5 if hit else 1.0,
                    edgecolor=COLLISION_COLOR if off else color,
                    linestyle="--" if off else "-",
                    lw=1.4 if truth else 1.1,
                    zorder=Z_TRUTH if truth else Z_MODEL,
                    transform=tr,
                )
            )
        g = S.ego_poses(traj, np.asarray([pose]), ego)[0]
        ax.plot(
            np.r_[pose[0], g[:, 0]],
            np.r_[pose[1], g[:, 1]],
            "-o",
            color=color,
            ms=2.5,
            lw=1.2,
            label=label,
            zorder=Z_TRUTH_PATH if truth else Z_MODEL_PATH,
            transform=tr,
        )
    ax.plot(*centre, marker="*", color="black", ms=9, zorder=Z_EGO, transform=tr)
    ax.set_xlim(-radius, radius)
    ax.set_ylim(-0.4 * radius, 1.6 * radius)  # the 3 s ahead: most of the view in front of the ego
    ax.set_aspect("equal")
    ax.xaxis.set_major_formatter(FuncFormatter(lambda h, _: f"{-h + 0.0:g}"))  # drawn at −y, labelled y
    ax.set_xlabel("y, left ← lateral (m) → right")
    ax.set_ylabel("x, forward (m)")
    kind = area.kind if isinstance(area, S.DrivableArea) else "no map"
    ax.set_title(frame_id.split("/")[0] + f" — {kind}; ego frame, forward up", fontsize=9)
    ax.legend(loc="upper right", fontsize=7)
    return fig
