"""``lightemma report``: tables, figures and the scenario analysis of runs in one folder.

Layout of ``OUT``::

    index.md                      links everything below, tables inline
    tables/efficiency.{md,csv,tex}, tables/accuracy_<convention>.{md,csv,tex}
    tables/pairwise_ade.{md,csv,tex}, tables/generations.{md,csv,tex}   (paired comparisons)
    tables/scenarios.{md,csv}, tables/history_bias.{md,csv}, tables/evaluation.json
    figures/bubble.{png,svg}, figures/pairwise.{png,svg}, figures/history_bias.{png,svg}
    figures/frames/<kind>_<frame>.{png,svg}     model grids and single-model pictures

Every model keeps one colour in every figure; only scored frames enter a mean,
a figure or the frame picker (docs/statistics.md).
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lightemma.evaluation import Evaluation, RunData, common_frames, evaluate_loaded, evaluation_tables, expand_run_dirs, load_run, read_frame_records
from lightemma.evaluation.core import unique_labels
from lightemma.errors import UserError
from lightemma.stats import Resampling
from lightemma.tables import Column, Table, fixed, to_csv, to_latex, to_markdown


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("_") or "frame"


class _Writer:
    """Writes files under the report folder and collects the index's Markdown."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.lines: list[str] = []

    def rel(self, path: Path) -> str:
        return path.relative_to(self.out).as_posix()

    def table(self, table: Table, *, latex: bool = True) -> None:
        base = self.out / "tables" / table.name
        base.parent.mkdir(parents=True, exist_ok=True)
        base.with_suffix(".md").write_text(to_markdown(table), encoding="utf-8")
        base.with_suffix(".csv").write_text(to_csv(table), encoding="utf-8")
        links = [f"[csv]({self.rel(base.with_suffix('.csv'))})"]
        if latex:
            base.with_suffix(".tex").write_text(to_latex(table), encoding="utf-8")
            links.append(f"[LaTeX]({self.rel(base.with_suffix('.tex'))})")
        self.lines += [to_markdown(table), " · ".join(links), ""]

    def figure(self, fig: Any, stem: str, caption: str) -> Path:
        from lightemma.figures import save_figure

        png, svg = save_figure(fig, self.out / "figures" / stem)
        self.lines += [f"![{caption}]({self.rel(png)})", f"*{caption}* ([svg]({self.rel(svg)}))", ""]
        return png


def _scenario_table(rows: list[dict[str, Any]], labels: Sequence[str], flags: dict[str, str]) -> Table:
    def cell(value: Any) -> str:
        return "-" if not value else f"{value['ade_avg']:.2f}"

    columns = [Column("tag", "Tag"), Column("frames", "Frames")] + [Column(label, label, cell) for label in labels]
    return Table("ADE avg by scenario tag", columns, rows, name="scenarios", flags=flags)


def _share(value: Any) -> str:
    return "-" if value is None else f"{100 * value:.0f} %"


def _bias_table(rows: list[dict[str, Any]], flags: dict[str, str]) -> Table:
    columns = [
        Column("model", "Model"),
        Column("frames", "Frames (paths ≥ 2 m)"),
        Column("short_path_frames", "Left out (path < 2 m)"),
        Column("slope_pred", "Slope pred/hist [95% CI]", fixed(2), ci="slope_pred_ci95"),
        Column("slope_true", "Slope true/hist [95% CI]", fixed(2), ci="slope_true_ci95"),
        Column("turn_frames", "Turning frames"),
        Column("sign_agree_pred", "Turn goes on (pred)", _share),
        Column("sign_agree_true", "Turn goes on (truth)", _share),
        Column("after_turn_frames", "Straight-after-turn frames"),
        Column("carry_pred", "Carried over (pred)", fixed(2)),
        Column("carry_true", "Carried over (truth)", fixed(2)),
    ]
    notes = [
        "Slopes: Theil–Sen (median of pairwise slopes) of the mean future curvature on the last history curvature, scored frames "
        "moving at ≥ 1 m/s whose true and predicted 3 s paths are ≥ 2 m (shorter paths define no curvature). Turn goes on: share of "
        "turning frames (|last history curvature| ≥ 0.03 1/m) whose future curvature has the history's sign."
    ]
    return Table("History bias: predicted vs true curvature against the last history curvature", columns, rows, name="history_bias", flags=flags, notes=notes)


def _generation_lines(rows: list[dict[str, Any]]) -> list[str]:
    """One sentence per family: each generation better, worse or not distinguishable from its predecessor."""
    by_family: dict[str, list[str]] = {}
    for r in rows:
        ci = r["ci95"]
        p = r["p_holm"]
        detail = f"{r['change']:+.3f} m" + (f" [{ci[0]:+.3f}, {ci[1]:+.3f}]" if ci else "") + ("" if p is None else f", p (Holm) {p:.3f}" if p >= 0.001 else ", p (Holm) < 0.001")
        by_family.setdefault(r["family"], []).append(f"{r['model']} is **{r['verdict']}** than {r['predecessor']} ({detail})" if r["verdict"] != "not distinguishable" else f"{r['model']} is **not distinguishable** from {r['predecessor']} ({detail})")
    return [f"- **{family}**: " + "; ".join(parts) + "." for family, parts in by_family.items()]


def _frame_pictures(w: _Writer, runs: Sequence[RunData], labels: Sequence[str], picks: list[tuple[str, str, str]], cameras: dict[str, Any], colors: dict[str, str]) -> None:
    """For each (kind, frame_id, caption): a grid of all models, and the worst model's picture with its texts."""
    from lightemma.figures import frame_figure, model_grid
    from lightemma.pictures import stage_texts

    from lightemma import displacement_errors

    records = {id(run): read_frame_records(run.info.run_dir, [fid for _, fid, _ in picks]) for run in runs}
    indices = [run.index() for run in runs]
    valid = [run.valid for run in runs]
    for kind, fid, caption in picks:
        preds, errors, gt = {}, {}, None
        for run, label, index, ok in zip(runs, labels, indices, valid):
            row = index.get(fid)
            if row is None or not ok[row]:
                continue
            gt = run.gt_positions[row]
            preds[label] = run.trajectory[row]
            errors[label] = float(displacement_errors(run.trajectory[row], gt).mean())
        if gt is None:
            continue
        w.lines.append(f"**{caption}** — frame `{fid}`")
        w.lines.append("")
        w.figure(model_grid(gt, preds, camera=cameras.get(fid), title=f"{fid}: {caption}", errors=errors, colors=colors), f"frames/{kind}_{_slug(fid)}_grid", f"all models on {fid}")
        models = [lab for lab, run in zip(labels, runs) if lab in errors and run.info.family != "Baseline"] or list(errors)
        worst = max(models, key=errors.get)  # stage texts of a baseline say nothing
        run = runs[list(labels).index(worst)]
        texts = stage_texts(records[id(run)].get(fid))
        fig = frame_figure(gt, {worst: preds[worst]}, camera=cameras.get(fid), texts=texts, title=f"{fid}: {worst} (ADE {errors[worst]:.2f} m)", colors=colors)
        w.figure(fig, f"frames/{kind}_{_slug(fid)}_{_slug(worst)}", f"{worst} on {fid}, with its stage texts")


def _safety_views(w: _Writer, runs: Sequence[RunData], labels: Sequence[str], safety: Any, colors: dict[str, str], per_model: int = 1) -> None:
    """Bird's-eye views of each model's first colliding and first off-road frames (figures/bev.py)."""
    from lightemma.evaluation.safety import frame_tags
    from lightemma.figures.bev import bev_figure

    picks: dict[str, str] = {}
    for label in labels:
        rs = safety.runs.get(label)
        if rs is None or rs.data is None:
            continue
        tags = frame_tags(rs)
        for tag, why in (("collides", "collides"), ("off_road", "leaves the drivable area")):
            for i in np.flatnonzero(tags[tag])[:per_model]:
                picks.setdefault(rs.frame_ids[i], f"{label} {why}")
    if not picks:
        return
    w.lines += ["## Safety — bird's-eye views", "",
                "Grey: drivable area; black boxes: annotated agents over the next 3 s (darker = later); outlines: ego footprints "
                "(green: ground truth), filled red where they overlap an agent, dashed red where a corner is off the drivable area.", ""]
    by_label = {label: run for label, run in zip(labels, runs)}
    for k, (fid, why) in enumerate(picks.items()):
        trajectories, gt, data = [], None, None
        for label in labels:
            rs, run = safety.runs.get(label), by_label[label]
            if rs is None or rs.data is None or fid not in rs.frame_ids:
                continue
            i = rs.rows[rs.frame_ids.index(fid)]
            trajectories.append((label, run.trajectory[i], colors.get(label, "#1f77b4")))
            gt, data = run.gt_positions[i], rs.data
        w.figure(bev_figure(fid, trajectories, gt, data), f"bev_{k:02d}_{_slug(fid)}", f"{fid}: {why}")


def _merge_picks(picks: list[tuple[str, str, str]]) -> list[tuple[str, str, str]]:
    """One entry per frame (the first kind), its captions joined: a frame is drawn once."""
    merged: dict[str, tuple[str, str, str]] = {}
    for kind, fid, caption in picks:
        if fid in merged:
            first_kind, _, captions = merged[fid]
            merged[fid] = (first_kind, fid, f"{captions}; {caption}")
        else:
            merged[fid] = (kind, fid, caption)
    return list(merged.values())


def write_report(
    run_dirs: Iterable[str | os.PathLike[str]],
    out: str | os.PathLike[str],
    *,
    convention: str = "all",
    common: bool = False,
    with_paper: bool = True,
    top: int = 5,
    dataroot: str | None = None,
    pictures: bool = True,
    frames: Sequence[str] = (),
    case_tags: Sequence[str] | None = None,
    pairwise: bool = True,
    resampling: Resampling = Resampling(),
    version: str | None = None,
    safety: bool = True,
) -> Path:
    """Evaluate runs and write tables, figures and the scenario analysis into ``out``; returns ``index.md``.

    ``frames`` adds pictures of chosen frame ids (e.g. to redraw the paper's Fig. 3 cases);
    ``case_tags`` are the scenario tags whose worst frame is drawn (default
    :data:`lightemma.scenarios.CASE_TAGS`; ``()`` for none); ``pairwise`` compares
    every pair of runs (table, matrix figure, per-family generation verdicts);
    ``resampling`` sets the scene bootstrap (resamples, seed, confidence). A ``dataroot``
    that is not a folder, or a negative ``top``, raises :class:`~lightemma.errors.UserError` before any work.
    With ``safety`` the tables carry off-road and collision columns (from ``dataroot``/``version`` when both
    are given, else each run's own dataset), the scenarios the ``collides`` / ``off_road`` tags, and a
    bird's-eye view is drawn of each model's first colliding and first off-road frame.
    """
    from lightemma.evaluation.tables import coverage_flags
    from lightemma.figures import bubble_chart, bubble_points, history_bias_figure, model_colors, pairwise_figure
    from lightemma.pictures import CameraSource
    from lightemma.scenarios import CASE_TAGS, disagreements, history_bias, per_tag_metrics, worst_frame_per_tag

    if isinstance(top, bool) or not isinstance(top, int) or top < 0:
        raise UserError(f"top must be a whole number of frames, 0 or more, got {top!r}", cli=f"--top must be 0 or more, got {top!r}")
    if dataroot is not None and not os.path.isdir(dataroot):
        what = "is not a folder" if os.path.exists(dataroot) else "does not exist"
        raise UserError(f"dataroot {dataroot} {what}", cli=f"--dataroot {dataroot} {what}")
    runs = [load_run(d, details=True) for d in expand_run_dirs(run_dirs)]
    known = set().union(*(r.frame_ids for r in runs)) if runs else set()
    missing = [fid for fid in frames if fid not in known]
    if missing:
        raise UserError(f"frame(s) not in any run: {', '.join(missing[:5])}{' …' if len(missing) > 5 else ''}")
    evaluation: Evaluation = evaluate_loaded(runs, convention=convention, common=common, resampling=resampling, pairwise=pairwise and len(runs) > 1,
                                             safety=safety, dataroot=dataroot if version else None, version=version)
    order = {m.run_dir: i for i, m in enumerate(evaluation.models)}
    runs.sort(key=lambda r: order[r.info.run_dir])
    labels = unique_labels(runs)
    colors = model_colors(evaluation.models)
    flags = coverage_flags(evaluation)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    w = _Writer(out)
    w.lines += ["# lightemma report", "", "| Model | Family | Run | Frames | Finished | Integrator | Chain | Answer format |",
                "|---|---|---|---:|---|---|---|---|"]
    w.lines += [f"| {m.label}{flags.get(m.label, '')} | {m.family} | `{m.run_dir}` | {m.frames_in_run} | {'yes' if m.complete else 'no'} | "
                f"{m.integrator} | {m.chain} | {m.answer_format} |" for m in evaluation.models]
    w.lines.append("")
    if evaluation.warnings:
        w.lines += ["**Warnings**", ""] + [f"- {x}" for x in evaluation.warnings] + [""]

    if flags:
        w.lines += [f"**Fewer than half of the frames scored** for {', '.join(flags)}: their numbers describe only the frames they managed; every table flags them.", ""]
    w.lines += ["## Tables I and II", ""]
    tables = evaluation_tables(evaluation, with_paper=with_paper)
    for table in tables:
        if table.name in ("pairwise_ade", "generations", "pairwise_safety"):
            continue
        w.table(table)
    (out / "tables" / "evaluation.json").write_text(json.dumps(evaluation.to_dict(), indent=2, default=str) + "\n", encoding="utf-8")
    w.lines += [f"All numbers as JSON: [tables/evaluation.json](tables/evaluation.json)", ""]

    w.lines += ["## Fig. 1 — ADE by family and generation", ""]
    main_convention = evaluation.main_convention
    points = bubble_points(evaluation, convention=main_convention, with_paper=with_paper)
    if any(p["ade_avg"] is not None for p in points):
        caption = "ADE avg per model (scored frames) with its 95 % scene-bootstrap interval; bubble area ∝ time per frame; colour = family, one shade per model" + ("; hollow = the paper's" if with_paper else "")
        w.figure(bubble_chart(points), "bubble", caption)
    else:
        w.lines += ["No model has a scored frame yet; no chart.", ""]

    if evaluation.pairwise is not None:
        w.lines += ["## Paired comparisons", ""]
        generations = evaluation.generations()
        if generations:
            w.lines += ["Is each generation better than its predecessor? (ADE avg change newer − older, 95 % scene-bootstrap interval, Holm-adjusted p over all pairs)", ""]
            w.lines += _generation_lines(generations) + [""]
        for table in tables:
            if table.name in ("pairwise_ade", "generations", "pairwise_safety"):
                w.table(table)
        labels_shown = [m.label for m in evaluation.models]
        w.figure(pairwise_figure(evaluation.pairwise, labels_shown, notes=flags), "pairwise", f"ADE avg of row − column model on their common frames ({main_convention}); * significant after Holm")

    shared = common_frames(runs) if len(runs) > 1 else None
    scope = f"the {len(shared)} frames scored in every run" if shared else "each run's scored frames"
    w.lines += ["## Scenarios", "", f"ADE avg (m) per scenario tag, on {scope}. Tag rules: docs/evaluate.md.", ""]
    w.table(_scenario_table(per_tag_metrics(runs, convention=main_convention, frame_ids=shared or None, safety=evaluation.safety), labels, flags), latex=False)
    w.lines += ["Case 1 of the paper (a finished turn carried into the prediction), measured over all frames:", ""]
    bias = history_bias(runs)
    w.table(_bias_table(bias, flags), latex=False)
    w.figure(history_bias_figure(runs, colors=colors, rows=bias, notes=flags), "history_bias", "predicted and true future curvature against the last history curvature: Theil–Sen slopes with 95 % intervals, and the carry-over just after a turn")

    picks = [("frame", fid, "requested frame") for fid in frames]
    picks += [("disagree", d["frame_id"], f"models disagree by {d['spread_m']:.1f} m at 3 s") for d in disagreements(runs, top=top)]
    picks += [("case", c["frame_id"], f"worst `{c['tag']}` frame (mean FDE {c['mean_fde']:.2f} m of {c['frames_with_tag']} tagged)") for c in worst_frame_per_tag(runs, CASE_TAGS if case_tags is None else case_tags)]
    picks = _merge_picks(picks)
    if pictures and picks:
        source = CameraSource(dataroot)
        cameras = source.cameras(runs, [fid for _, fid, _ in picks])
        w.lines += ["## Frames: requested, where models disagree most, and the worst of each failure case", ""]
        w.lines += [f"> {p}" for p in dict.fromkeys(source.problems)] + ([""] if source.problems else [])
        _frame_pictures(w, runs, labels, picks, cameras, colors)
    if pictures and evaluation.safety is not None:
        _safety_views(w, runs, labels, evaluation.safety, colors)
    index = out / "index.md"
    index.write_text("\n".join(w.lines) + "\n", encoding="utf-8")
    return index
