"""Issue 32.14: the bird's-eye view and the camera view agree on the lateral axis (nuScenes ego frame: x forward,
y left; the camera image shows left on the left)."""

from __future__ import annotations

import os

os.environ.setdefault("MPLBACKEND", "Agg")

import numpy as np

from lightemma.report.figures import camera_from_frame, frame_figure
from lightemma.report.figures.projection import project


def test_a_path_on_the_left_is_left_in_both_views_and_its_ticks_read_plus_y(synth_root):
    import lightemma

    frame = lightemma.load_frames(synth_root, "v1.0-mini")[0]
    camera = camera_from_frame(frame)
    left = np.array([[4.0 * k, 0.4 * k * k] for k in range(1, 7)])  # y > 0: to the left of the ego
    fig = frame_figure(frame.gt_positions, {"left": left}, camera=camera, colors={"left": "#1f77b4"})
    cam_ax, bev_ax = fig.axes[0], fig.axes[1]
    # the camera: the path projects into the image's left half
    uv, visible = project(left, camera.intrinsic, camera.extrinsic)
    assert visible.all() and (uv[:, 0] < camera.intrinsic[0, 2]).all()
    # the bird's-eye view: drawn left of the ego, and the lateral tick under it reads its y (positive), not −y
    line = next(ln for ln in bev_ax.lines if ln.get_label() == "left")
    xs = np.asarray(line.get_xdata())[1:]
    assert (xs < 0).all()
    fig.canvas.draw()
    ticks = {
        round(float(t.get_position()[0]), 6): t.get_text().replace("\u2212", "-")
        for t in bev_ax.get_xticklabels()
        if t.get_text()
    }
    under = min((v for v in ticks if v < 0), key=lambda v: abs(v - xs[-1]))
    assert float(ticks[under]) == -under > 0
    assert "left" in bev_ax.get_xlabel() and "y" in bev_ax.get_xlabel()
    assert cam_ax is not bev_ax


def test_the_safety_view_is_drawn_in_the_ego_frame_as_the_camera_sees_it(synth_root):
    """The parked car of the accelerate scene stands right of the ego (y < 0): the safety view draws it right of
    the origin, and a path to the left (y > 0) left of it, whatever the ego's global heading."""
    import lightemma
    from lightemma.evaluation import safety as S
    from lightemma.report.figures.bev import bev_figure

    frames = lightemma.load_frames(synth_root, "v1.0-mini")
    frame = next(f for f in frames if f.frame_id.startswith("synth-0001-accelerate/"))
    data = S.load_safety_data(synth_root, "v1.0-mini")
    token = S.sample_token_of(frame.frame_id)
    pose = data.poses[token]
    c, s = np.cos(pose[2]), np.sin(pose[2])
    boxes = np.concatenate([data.boxes[t] for t in data.future[token]])
    d = boxes[:, :2] - np.asarray(pose[:2])
    y_ego = -s * d[:, 0] + c * d[:, 1]
    ahead = c * d[:, 0] + s * d[:, 1]
    near = (np.abs(y_ego) < 20) & (ahead > 0) & (ahead < 50)
    assert near.any() and (y_ego[near] < 0).all()  # the parked car: on the right
    left = np.array([[4.0 * k, 0.3 * k * k] for k in range(1, 7)])
    fig = bev_figure(frame.frame_id, [("left", left, "#1f77b4")], np.asarray(frame.gt_positions), data)
    ax = fig.axes[0]
    fig.canvas.draw()
    to_view = ax.transData.inverted()
    agents = [
        p
        for p in ax.patches
        if not p.get_fill()
        and p.get_edgecolor()[0] == p.get_edgecolor()[1] == p.get_edgecolor()[2]
        and p.get_edgecolor()[0] < 0.7
    ]
    centres = np.array([to_view.transform(p.get_verts()).mean(axis=0) for p in agents])
    in_view = (np.abs(centres[:, 0]) < 20) & (centres[:, 1] > 0) & (centres[:, 1] < 50)
    assert in_view.any() and (centres[in_view, 0] > 0).all()  # right of the ego, as in the camera image
    line = next(ln for ln in ax.lines if ln.get_label() == "left")
    path = to_view.transform(line.get_transform().transform(np.c_[line.get_xdata(), line.get_ydata()]))
    assert (path[1:, 0] < 0).all() and (path[1:, 1] > 0).all()  # the left path: left of the ego, ahead of it
    assert "left" in ax.get_xlabel() and "forward" in ax.get_ylabel()
