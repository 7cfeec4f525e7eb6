"""History-bias figure: does predicted curvature follow the last history curvature more than
the truth does? (the paper's Case 1, measured over all frames instead of one)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from lightemma.evaluation.ablations import comparison_key
from lightemma.evaluation.core import unique_labels
from lightemma.evaluation.scenarios import bias_row, curvature_samples, truth_over_runs
from lightemma.report.figures._mpl import GT_COLOR, pred_color, pyplot


def _limits(values: Sequence[np.ndarray], *, floor: float) -> tuple[float, float]:
    """A symmetric range holding the central 98 % of the values (outliers are clipped, not scaled to)."""
    pooled = np.concatenate([v for v in values if len(v)]) if any(len(v) for v in values) else np.zeros(1)
    reach = max(floor, float(np.quantile(np.abs(pooled), 0.98)) * 1.25)
    return -reach, reach


# marker per input ablation (lightemma.inputs): an ablated run is drawn hollow, in its full run's colour, just below it
INPUT_MARKERS = {"full": "o", "no-image": "s", "blank-image": "D", "no-history": "^"}


def _beside_full(runs: Sequence[Any]) -> tuple[list[int], dict[int, int]]:
    """Run order with each full run followed by its ablation runs (same model and variant), and ablated -> full index."""

    def key(run: Any) -> tuple[Any, ...]:
        return comparison_key(run.info)

    def inputs(run: Any) -> str:
        return getattr(getattr(run, "info", None), "inputs", "full")

    full: dict[tuple[Any, ...], list[int]] = {}
    for i, run in enumerate(runs):
        if inputs(run) == "full":
            full.setdefault(key(run), []).append(i)
    partner = {
        i: full[key(run)][0] for i, run in enumerate(runs) if inputs(run) != "full" and len(full.get(key(run), [])) == 1
    }
    order: list[int] = []
    for i in range(len(runs)):
        if i in partner:
            continue
        order.append(i)
        order += [j for j, f in partner.items() if f == i]
    return order, partner


def history_bias_figure(
    runs: Sequence[Any],
    *,
    colors: Mapping[str, str] | None = None,
    rows: Sequence[Mapping[str, Any]] | None = None,
    notes: Mapping[str, str] | None = None,
    max_points: int = 2500,
) -> Any:
    """Three panels (see :func:`lightemma.evaluation.scenarios.history_bias` for the definitions):

    * predicted (per model) and true mean future curvature against the last
      history curvature, with Theil–Sen lines, the identity line (the turn goes on
      unchanged) and zero; axes span the central 98 % of the points;
    * each model's Theil–Sen slope with its 95 % interval, against the truth's
      (green band);
    * on frames going straight just after a turn, the share of the last history
      curvature carried into the prediction, against the truth's (green line).

    ``rows``: the :func:`~lightemma.evaluation.scenarios.history_bias` rows of ``runs`` when
    already computed (the fits are the slow part); ``notes``: a flag after a
    model's name (e.g. fewer than half of its frames scored).

    Input-ablation runs (``--inputs``) are drawn beside their model's full run: just after it in
    every panel, in its colour, hollow, with a marker per ablation (:data:`INPUT_MARKERS`), and
    dashed lines / hatched bars.
    """
    plt = pyplot()
    labels = unique_labels(list(runs))
    palette = {label: (colors or {}).get(label, pred_color(i)) for i, label in enumerate(labels)}
    samples = [curvature_samples(run) for run in runs]
    stats = list(rows) if rows is not None else [bias_row(label, k) for label, k in zip(labels, samples)]
    order, partner = _beside_full(runs)
    ablated = {labels[i]: getattr(runs[i].info, "inputs", "full") for i in partner}
    for i, f in partner.items():
        palette[labels[i]] = palette[labels[f]]
    labels, samples, stats = [labels[i] for i in order], [samples[i] for i in order], [stats[i] for i in order]
    # the truth of every frame any run covers (not only the first run's): its line never depends on run order or coverage
    truth = truth_over_runs(runs)
    truth_fit = bias_row(
        "truth",
        {
            "history": truth["history"],
            "pred": truth["true"],
            "true": truth["true"],
            "after_turn": truth["after_turn"],
            "short_path": np.array(0),
        },
    )
    n = max(1, len(labels))
    height = max(4.6, 1.9 + 0.3 * n)  # every model gets a readable row in the two right panels
    fig, (scatter, slopes, bars) = plt.subplots(
        1, 3, figsize=(16, height), gridspec_kw={"width_ratios": [1.35, 1, 1]}, layout="constrained"
    )

    xlim = _limits([k["history"] for k in samples] + [truth["history"]], floor=0.05)
    ylim = _limits([k["pred"] for k in samples] + [truth["true"]], floor=0.05)
    rng = np.random.default_rng(0)
    for label, k in zip(labels, samples):
        keep = rng.permutation(len(k["history"]))[:max_points]
        if label in ablated:
            scatter.scatter(
                k["history"][keep],
                k["pred"][keep],
                s=9,
                marker=INPUT_MARKERS.get(ablated[label], "s"),
                facecolors="none",
                edgecolors=palette[label],
                alpha=0.35,
                linewidths=0.6,
                zorder=2,
            )
        else:
            scatter.scatter(
                k["history"][keep], k["pred"][keep], s=7, color=palette[label], alpha=0.3, linewidths=0, zorder=2
            )
    keep = rng.permutation(len(truth["history"]))[:max_points]
    scatter.scatter(
        truth["history"][keep], truth["true"][keep], s=7, color=GT_COLOR, alpha=0.45, linewidths=0, zorder=3
    )
    xs = np.array(xlim)
    scatter.plot(
        xs, xs, linestyle="--", color="0.35", linewidth=1.2, zorder=4, label="turn goes on unchanged (slope 1)"
    )
    few = len(labels) <= 4  # with many models the middle panel names them; the scatter shows their lines only
    for label, stat in zip(labels, stats):
        if stat["slope_pred"] is not None:
            scatter.plot(
                xs,
                stat["slope_pred"] * xs + stat["intercept_pred"],
                color=palette[label],
                linewidth=1.6,
                zorder=5,
                linestyle="--" if label in ablated else "-",
                label=f"{label}: slope {stat['slope_pred']:.2f}" if few else None,
            )
    if not few:
        scatter.plot([], [], color="0.3", linewidth=1.6, label="each model's fit (colours as in the middle panel)")
    if truth_fit["slope_true"] is not None:
        line = truth_fit["slope_true"] * xs + truth_fit["intercept_true"]
        scatter.plot(xs, line, color="white", linewidth=4.5, zorder=6)
        scatter.plot(
            xs, line, color=GT_COLOR, linewidth=2.6, zorder=7, label=f"truth: slope {truth_fit['slope_true']:.2f}"
        )
    scatter.axhline(0, color="0.75", linewidth=0.8, zorder=1)
    scatter.axvline(0, color="0.75", linewidth=0.8, zorder=1)
    scatter.set_xlim(xlim)
    scatter.set_ylim(ylim)
    scatter.set_xlabel("last history curvature (1/m)")
    scatter.set_ylabel("mean future curvature, 0–3 s (1/m)")
    scatter.set_title("future against last history curvature (paths ≥ 2 m)", fontsize=10)
    scatter.legend(fontsize=7, loc="upper left", framealpha=0.9).set_zorder(20)

    # every model has a row in both panels (a model without a value says why, in its row)
    y = np.arange(n)[::-1]
    names = [label + (notes or {}).get(label, "") for label in labels]
    if truth_fit["slope_true"] is not None:
        band = truth_fit["slope_true_ci95"]
        if band:
            slopes.axvspan(band[0], band[1], color=GT_COLOR, alpha=0.25, zorder=1)
        shown = f" [{band[0]:.2f}, {band[1]:.2f}]" if band else ""
        slopes.axvline(
            truth_fit["slope_true"],
            color=GT_COLOR,
            linewidth=2.2,
            zorder=2,
            label=f"truth {truth_fit['slope_true']:.2f}{shown}",
        )
    slopes.axvline(1.0, color="0.35", linestyle="--", linewidth=1.0, zorder=2, label="turn goes on unchanged (1)")
    slopes.axvline(0.0, color="0.75", linewidth=0.8, zorder=1)
    for yi, label, s in zip(y, labels, stats):
        if s["slope_pred"] is None:
            slopes.text(
                0.5,
                yi,
                "too few moving frames for a slope",
                transform=slopes.get_yaxis_transform(),
                ha="center",
                va="center",
                fontsize=7,
                color="0.45",
            )
            continue
        low, high = s["slope_pred_ci95"] or (s["slope_pred"], s["slope_pred"])
        slopes.errorbar(
            [s["slope_pred"]],
            [yi],
            xerr=[[s["slope_pred"] - low], [high - s["slope_pred"]]],
            fmt=INPUT_MARKERS.get(ablated.get(label, "full"), "o"),
            color=palette[label],
            capsize=3,
            zorder=3,
            markerfacecolor="white" if label in ablated else palette[label],
        )
    slopes.set_yticks(y)
    slopes.set_yticklabels(names, fontsize=7)
    slopes.set_ylim(-0.6, n - 0.4)
    slopes.set_xlabel("Theil–Sen slope, 95 % CI")
    slopes.set_title("how much of the history curvature goes on", fontsize=10)
    slopes.legend(fontsize=7, loc="lower center", bbox_to_anchor=(0.5, 1.07), ncol=2, framealpha=0.9, borderaxespad=0.0)

    carried = truth_fit["carry_true"]  # on the frames going straight just after a turn, over every frame shown
    values = [1.0, 0.0] + ([carried] if carried is not None else [])
    for yi, label, s in zip(y, labels, stats):
        if s["carry_pred"] is None:
            bars.text(
                0.02,
                yi,
                "no frame straight just after a turn",
                transform=bars.get_yaxis_transform(),
                ha="left",
                va="center",
                fontsize=7,
                color="0.45",
            )
            continue
        hollow = label in ablated
        bars.barh(
            [yi],
            [s["carry_pred"]],
            color="white" if hollow else palette[label],
            edgecolor=palette[label],
            hatch="//" if hollow else None,
            linewidth=1.0 if hollow else 0,
            height=0.6,
            zorder=2,
        )
        values.append(s["carry_pred"])
    if carried is not None:
        bars.axvline(carried, color="white", linewidth=4.5, zorder=3)
        bars.axvline(
            carried,
            color=GT_COLOR,
            linewidth=2.4,
            zorder=4,
            label=f"truth ({carried:.2f}, n={truth_fit['after_turn_frames']})",
        )
    bars.axvline(1.0, color="0.35", linestyle="--", linewidth=1.0, zorder=4, label="turn goes on unchanged (1)")
    bars.axvline(0.0, color="0.6", linewidth=0.8, zorder=1)
    bars.set_yticks(y)
    bars.set_yticklabels([f"{name} (n={s['after_turn_frames']})" for name, s in zip(names, stats)], fontsize=7)
    bars.set_ylim(-0.6, n - 0.4)
    bars.set_xlim(min(0.0, min(values)) - 0.08, max(values) + 0.08)
    bars.legend(fontsize=7, loc="lower center", bbox_to_anchor=(0.5, 1.07), ncol=2, framealpha=0.9, borderaxespad=0.0)
    bars.set_xlabel("history curvature carried over (share)")
    bars.set_title("straight just after a turn (Case 1)", fontsize=10)
    return fig
