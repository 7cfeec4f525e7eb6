"""Per-frame pictures (the paper's Fig. 3): the CAM_FRONT image with ground-truth and
predicted trajectories projected through the calibration, a bird's-eye view beside it and the
three stage texts; and a grid comparing several models on one frame."""

from __future__ import annotations

import textwrap
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lightemma.report.figures._mpl import GT_COLOR, pred_color, pyplot
from lightemma.report.figures.projection import densify, project

STAGE_LABELS = (("scene", "1 · Scene"), ("intent", "2 · Intent"), ("answer", "3 · Actions"))


MAX_IMAGE_PIXELS = 40_000_000  # an image larger than this (nuScenes CAM_FRONT: 1.44 M) is not decoded


@dataclass
class Camera:
    """What a picture needs from a frame: the image (H, W, 3) or None, and the calibration.

    ``path`` is where the image lies (read later, e.g. for a thumbnail, when ``image`` was not loaded).
    """

    image: np.ndarray | None
    intrinsic: np.ndarray  # (3, 3)
    extrinsic: np.ndarray  # (4, 4) ego-from-camera
    path: Path | None = None

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the image, or guessed from the principal point when there is none."""
        if self.image is not None:
            return self.image.shape[1], self.image.shape[0]
        return int(round(2 * self.intrinsic[0, 2])), int(round(2 * self.intrinsic[1, 2]))


def open_image(path: str | Path | None, *, max_pixels: int = MAX_IMAGE_PIXELS) -> Any:
    """The PIL image at ``path`` (header read, pixels not yet decoded), or None when there is none,
    it is unreadable, or it has more than ``max_pixels`` pixels (a decompression bomb is never decoded)."""
    if not path or not Path(path).is_file():
        return None
    from PIL import Image

    try:
        img = Image.open(path)
    except (OSError, ValueError, Image.DecompressionBombError):
        return None
    width, height = img.size
    if width * height > max_pixels or width <= 0 or height <= 0:
        img.close()
        return None
    return img


def load_image(
    path: str | Path | None, *, max_pixels: int = MAX_IMAGE_PIXELS, width: int | None = None
) -> np.ndarray | None:
    """The RGB image at ``path`` as an array (H, W, 3) uint8, or None when there is none, it is
    unreadable or larger than ``max_pixels``; with ``width``, scaled down to about that width
    (JPEGs are decoded at a reduced size directly)."""
    img = open_image(path, max_pixels=max_pixels)
    if img is None:
        return None
    from PIL import Image

    try:
        with img:
            if width and img.width > width:
                height = max(1, round(img.height * width / img.width))
                img.draft("RGB", (width, height))
                return np.asarray(img.convert("RGB").resize((width, height), Image.Resampling.BILINEAR))
            return np.asarray(img.convert("RGB"))
    except (OSError, ValueError, Image.DecompressionBombError):
        return None


def camera_from_frame(frame: Any, *, load: bool = True) -> Camera:
    """A :class:`Camera` from a :class:`lightemma.Frame` (image_path, camera_intrinsic, camera_extrinsic);
    with ``load=False`` the image is left on disk (``path`` set)."""
    path = getattr(frame, "image_path", None)
    return Camera(
        image=load_image(path) if load else None,
        intrinsic=np.asarray(frame.camera_intrinsic, dtype=np.float64),
        extrinsic=np.asarray(frame.camera_extrinsic, dtype=np.float64),
        path=Path(path) if path else None,
    )


GT_WIDTH = 1.4  # ground truth: a thin dashed line drawn on top, so that a prediction under it shows through the gaps
GT_DASHES = (3.0, 3.0)
PRED_WIDTH = 2.6


def _draw_projected(
    ax: Any, camera: Camera, trajectory: np.ndarray, color: str, label: str, width: float, *, truth: bool = False
) -> None:
    line, _ = project(densify(trajectory), camera.intrinsic, camera.extrinsic)
    style = {"dashes": GT_DASHES, "zorder": 6} if truth else {"zorder": 4}
    ax.plot(line[:, 0], line[:, 1], color=color, linewidth=width, label=label, solid_capstyle="round", **style)
    points, visible = project(trajectory, camera.intrinsic, camera.extrinsic)
    ax.scatter(
        points[visible, 0],
        points[visible, 1],
        s=9 if truth else 14,
        color=color,
        edgecolors="white",
        linewidths=0.6,
        zorder=7 if truth else 5,
    )


def draw_camera(
    ax: Any,
    camera: Camera,
    gt: np.ndarray,
    predictions: Mapping[str, np.ndarray],
    *,
    colors: Mapping[str, str] | None = None,
) -> None:
    """The camera view with the trajectories drawn on the ground; a plain grey background (no
    image drawn: it costs nothing) when there is no image."""
    width, height = camera.size
    if camera.image is not None:
        ax.imshow(camera.image)
    else:
        ax.add_patch(pyplot().Rectangle((0, 0), width, height, facecolor="#c8c8c8", edgecolor="none", zorder=0))
        ax.text(0.02, 0.96, "image not available", transform=ax.transAxes, color="0.3", va="top", fontsize=8)
    for i, (label, trajectory) in enumerate(predictions.items()):
        if np.isfinite(trajectory).all():
            _draw_projected(ax, camera, trajectory, (colors or {}).get(label, pred_color(i)), label, PRED_WIDTH)
    _draw_projected(ax, camera, gt, GT_COLOR, "ground truth", GT_WIDTH, truth=True)
    ax.set_xlim(0, width)
    ax.set_ylim(height, 0)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    for spine in ax.spines.values():
        spine.set_visible(False)


def bev_limits(
    trajectories: list[np.ndarray], *, min_extent: float = 5.0, margin: float = 0.12
) -> tuple[tuple[float, float], tuple[float, float]]:
    """Square (horizontal, vertical) limits of a bird's-eye view holding the origin and every point.

    The view plots lateral −y to the right and forward x upward; the box is
    centred on the points and padded by ``margin`` of its size.
    """
    points = np.concatenate([np.zeros((1, 2))] + [t for t in trajectories if np.isfinite(t).all()])
    horizontal, vertical = -points[:, 1], points[:, 0]
    half = max(min_extent, float(np.ptp(horizontal)), float(np.ptp(vertical))) * (0.5 + margin)
    cx, cy = (horizontal.max() + horizontal.min()) / 2, (vertical.max() + vertical.min()) / 2
    return (cx - half, cx + half), (cy - half, cy + half)


def draw_bev(
    ax: Any,
    gt: np.ndarray,
    predictions: Mapping[str, np.ndarray],
    *,
    colors: Mapping[str, str] | None = None,
    units: bool = True,
) -> None:
    """Bird's-eye view, x (forward) upward, y (left) to the left; origin = the ego now; axes in metres.

    As the camera image shows it (nuScenes ego frame: x forward, y left): a point on the left is left of the
    origin, and the lateral ticks read its y (positive on the left, as the HTML frame view's). The view is sized
    to hold the ground truth and every prediction; the ground truth is a thin dashed line on top (a prediction
    under it shows through).
    """
    from matplotlib.ticker import FuncFormatter

    def plot(traj: np.ndarray, color: str, width: float, label: str, z: float, **style: Any) -> None:
        pts = np.concatenate([np.zeros((1, 2)), traj])
        ax.plot(
            -pts[:, 1],
            pts[:, 0],
            "-",
            color=color,
            linewidth=width,
            marker="o",
            markersize=2.5,
            label=label,
            zorder=z,
            **style,
        )

    shown = {label: t for label, t in predictions.items() if np.isfinite(t).all()}
    for i, (label, trajectory) in enumerate(shown.items()):
        plot(trajectory, (colors or {}).get(label, pred_color(i)), 1.8, label, 4)
    plot(gt, GT_COLOR, GT_WIDTH, "ground truth", 6, dashes=GT_DASHES)
    (x0, x1), (y0, y1) = bev_limits([gt, *shown.values()])
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal", adjustable="box")
    ax.plot([0], [0], marker="^", color="black", markersize=6, zorder=5)
    ax.set_facecolor("#f4f4f4")
    ax.tick_params(labelsize=6)
    ax.xaxis.set_major_formatter(
        FuncFormatter(lambda h, _: f"{-h + 0.0:g}")
    )  # drawn at −y, labelled y (+ 0.0: no "-0")
    if units:
        ax.set_xlabel("y, left ← lateral (m) → right", fontsize=6, labelpad=1)
        ax.set_ylabel("forward x (m)", fontsize=6, labelpad=1)
    ax.set_title("bird's-eye (m)", fontsize=7)


def _stage_text(texts: Mapping[str, Any], limit: int) -> str:
    blocks = []
    for key, title in STAGE_LABELS:
        value = " ".join(str(texts.get(key) or "—").split())
        if len(value) > limit:
            value = value[: limit - 1] + "…"
        blocks.append(textwrap.fill(f"{title}: {value}", width=130))
    return "\n\n".join(blocks)


def frame_figure(
    gt: np.ndarray,
    predictions: Mapping[str, np.ndarray],
    *,
    camera: Camera | None = None,
    texts: Mapping[str, Any] | None = None,
    title: str | None = None,
    text_limit: int = 420,
    colors: Mapping[str, str] | None = None,
) -> Any:
    """One frame: camera view with trajectories, the bird's-eye view beside it, and (if given) the stage texts.

    ``predictions`` maps a label to a (6, 2) trajectory in the ego frame;
    ``texts`` holds ``scene``, ``intent`` and ``answer`` (the stage-3 answer);
    ``colors`` maps a label to its colour (the report's one colour per model).
    Returns the matplotlib Figure (the first axes is the camera view).
    """
    plt = pyplot()
    gt = np.asarray(gt, dtype=np.float64)
    preds = {k: np.asarray(v, dtype=np.float64) for k, v in predictions.items()}
    fig = plt.figure(figsize=(11, 7.4 if texts else 4.6))
    grid = fig.add_gridspec(
        2 if texts else 1,
        1,
        height_ratios=[3, 1.6] if texts else [1],
        hspace=0.08,
        left=0.03,
        right=0.98,
        top=0.93,
        bottom=0.02 if texts else 0.08,
    )
    if camera is not None:
        # camera view and bird's-eye view side by side: the BEV never covers the image
        top = grid[0].subgridspec(1, 2, width_ratios=[1.9, 1], wspace=0.12)
        ax, bev = fig.add_subplot(top[0]), fig.add_subplot(top[1])
        draw_camera(ax, camera, gt, preds, colors=colors)
    else:
        ax = bev = fig.add_subplot(grid[0])
    draw_bev(bev, gt, preds, colors=colors)
    _legend(ax, preds, colors, loc="lower left")
    if texts:
        text_ax = fig.add_subplot(grid[1])
        text_ax.axis("off")
        text_ax.text(
            0.0,
            1.0,
            _stage_text(texts, text_limit),
            va="top",
            ha="left",
            fontsize=7.5,
            family="monospace",
            transform=text_ax.transAxes,
        )
    if title:
        fig.suptitle(title, fontsize=10)
    return fig


def model_grid(
    gt: np.ndarray,
    predictions: Mapping[str, np.ndarray],
    *,
    camera: Camera | None = None,
    title: str | None = None,
    ncols: int = 3,
    errors: Mapping[str, float] | None = None,
    colors: Mapping[str, str] | None = None,
) -> Any:
    """Several models on one frame: one panel per model (ground truth in each) — the camera view
    with the bird's-eye view (axes in metres) beside it, never over it — and a legend (ground
    truth, each model in its colour)."""
    plt = pyplot()
    gt = np.asarray(gt, dtype=np.float64)
    labels = list(predictions)
    ncols = max(1, min(ncols, len(labels)))
    nrows = max(1, -(-len(labels) // ncols))
    with_camera = camera is not None
    panel_w = 6.4 if with_camera else 3.2
    fig = plt.figure(figsize=(panel_w * ncols, 3.0 * nrows + 0.9))
    outer = fig.add_gridspec(
        nrows,
        ncols,
        left=0.03,
        right=0.99,
        top=0.93 if title else 0.97,
        bottom=0.1 if nrows == 1 else 0.06,
        wspace=0.12,
        hspace=0.35,
    )
    palette = {label: (colors or {}).get(label, pred_color(i)) for i, label in enumerate(labels)}
    for k, label in enumerate(labels):
        cell = outer[k // ncols, k % ncols]
        pred = {label: np.asarray(predictions[label], dtype=np.float64)}
        if camera is not None:  # with_camera
            # the camera view and the bird's-eye view beside it: the BEV never covers the image
            inner = cell.subgridspec(1, 2, width_ratios=[1.78, 1], wspace=0.28)
            cam_ax, bev_ax = fig.add_subplot(inner[0]), fig.add_subplot(inner[1])
            draw_camera(cam_ax, camera, gt, pred, colors=palette)
        else:
            cam_ax = bev_ax = fig.add_subplot(cell)
        draw_bev(bev_ax, gt, pred, colors=palette)
        bev_ax.set_title("bird's-eye (m)" if with_camera else "", fontsize=6)
        error = (errors or {}).get(label)
        cam_ax.set_title(
            label + (f" — ADE {error:.2f} m" if error is not None and np.isfinite(error) else ""),
            fontsize=9,
            color=palette[label],
        )
    if title:
        fig.suptitle(title, fontsize=10)
    handles = [plt.Line2D([], [], color=GT_COLOR, linewidth=2.0, dashes=GT_DASHES, label="ground truth")]
    handles += [plt.Line2D([], [], color=palette[label], linewidth=2.0, label=label) for label in labels]
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 7), fontsize=8, frameon=False)
    return fig


def _legend(ax: Any, preds: Mapping[str, np.ndarray], colors: Mapping[str, str] | None, *, loc: str) -> None:
    """Ground truth and each model in its colour (whether or not its line is in view)."""
    plt = pyplot()
    handles = [plt.Line2D([], [], color=GT_COLOR, linewidth=2.0, dashes=GT_DASHES, label="ground truth")]
    handles += [
        plt.Line2D([], [], color=(colors or {}).get(label, pred_color(i)), linewidth=2.2, label=label)
        for i, label in enumerate(preds)
    ]
    ax.legend(handles=handles, loc=loc, fontsize=8, framealpha=0.8)
