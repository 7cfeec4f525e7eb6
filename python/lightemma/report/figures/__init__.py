"""Figures (matplotlib, PNG at 150 dpi and SVG): the bubble chart, per-frame pictures, model
grids, the history-bias plot, the paired-comparison matrix and the input-ablation intervals. Matplotlib is imported only when a figure is drawn."""

from lightemma.report.figures._mpl import model_colors, save_figure
from lightemma.report.figures.ablation_deltas import ablation_figure
from lightemma.report.figures.bubble import bubble_chart, bubble_points
from lightemma.report.figures.frame_view import Camera, camera_from_frame, frame_figure, load_image, model_grid
from lightemma.report.figures.history_bias import history_bias_figure
from lightemma.report.figures.pairwise import pairwise_figure
from lightemma.report.figures.projection import project

__all__ = [
    "Camera",
    "ablation_figure",
    "bubble_chart",
    "bubble_points",
    "camera_from_frame",
    "frame_figure",
    "history_bias_figure",
    "load_image",
    "model_colors",
    "model_grid",
    "pairwise_figure",
    "project",
    "save_figure",
]
