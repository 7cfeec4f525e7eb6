"""Figures (matplotlib, PNG and SVG): the bubble chart, per-frame pictures, model grids and
the history-bias plot. Matplotlib is imported only when a figure is drawn."""

from lightemma.figures._mpl import save_figure
from lightemma.figures.bubble import bubble_chart, bubble_points
from lightemma.figures.frame_view import Camera, camera_from_frame, frame_figure, load_image, model_grid
from lightemma.figures.history_bias import history_bias_figure
from lightemma.figures.projection import project

__all__ = [
    "Camera",
    "bubble_chart",
    "bubble_points",
    "camera_from_frame",
    "frame_figure",
    "history_bias_figure",
    "load_image",
    "model_grid",
    "project",
    "save_figure",
]
