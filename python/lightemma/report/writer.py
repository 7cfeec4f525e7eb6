"""``lightemma report``: tables, figures and the scenario analysis of runs in one folder.

Layout of ``OUT``::

    index.md                      links everything below, tables inline
    tables/efficiency.{md,csv,tex}, tables/accuracy_<convention>.{md,csv,tex}
    tables/pairwise_ade.{md,csv,tex}, tables/generations.{md,csv,tex}   (paired comparisons)
    tables/input_ablations.{md,csv,tex}, tables/baseline_gains.{md,csv,tex}   (does the image matter?)
    tables/scenarios.{md,csv}, tables/history_bias.{md,csv}, tables/evaluation.json
    figures/bubble.{png,svg}, figures/pairwise.{png,svg}, figures/history_bias.{png,svg}, figures/input_ablations.{png,svg}
    figures/frames/<kind>_<frame>.{png,svg}     model grids and single-model pictures

Every run keeps one colour of its own in every figure that draws runs together (the bubble chart colours by
family); only scored frames enter a mean,
a figure or the frame picker (docs/statistics.md).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import sys
from collections.abc import Iterable, Sequence
from dataclasses import replace
from glob import escape as glob_escape
from pathlib import Path
from typing import Any

import numpy as np

from lightemma._text import printable
from lightemma.errors import UserError
from lightemma.evaluation import (
    Evaluation,
    RunData,
    common_frames,
    evaluate_loaded,
    expand_run_dirs,
    load_run,
    read_frame_records,
)
from lightemma.evaluation.core import unique_labels
from lightemma.evaluation.descriptors import footer_lines, provenance
from lightemma.evaluation.loading import discover_runs
from lightemma.evaluation.planning_score import GT_LABEL, KEYS
from lightemma.evaluation.safety import FLOOR_LABEL, frame_tags
from lightemma.evaluation.scenarios import CASE_TAGS, disagreements, history_bias, per_tag_metrics, worst_frame_per_tag
from lightemma.evaluation.stats import Resampling
from lightemma.frames.fingerprint import describe_fingerprint
from lightemma.metrics import displacement_errors
from lightemma.report.evaluation_tables import (
    coverage_flags,
    evaluation_tables,
    frame_set_groups,
    frame_set_tables,
    provenance_footer,
    provenance_table,
)
from lightemma.report.figures import (
    ablation_figure,
    bubble_chart,
    bubble_points,
    history_bias_figure,
    pairwise_figure,
    save_figure,
)
from lightemma.report.figures._mpl import RUN_PALETTE, run_colors
from lightemma.report.figures.bev import bev_figure
from lightemma.report.figures.consistency import explanations_figure
from lightemma.report.figures.subscores import planning_figure
from lightemma.report.pictures import CameraSource, stage_texts, visible_lines
from lightemma.report.robustness_tables import robustness_section
from lightemma.report.tables import (
    Column,
    Table,
    fixed,
    markdown_cell,
    markdown_code,
    markdown_text,
    to_csv,
    to_latex,
    to_markdown,
)
from lightemma.runs.store import MANIFEST_FILE, pid_alive, read_manifest

SLUG_MAX = 80  # characters of a name kept in a file name (a frame id from a reference file can be any length)


def _slug(text: str) -> str:
    """A part of a file name from a name from outside (frame id, model label): letters, digits, ``.``, ``_``, ``-``
    only, at most :data:`SLUG_MAX` of them, never starting with a dot (no ``..``, no hidden file), so the file stays in
    its folder whatever the name. Where that changed the name, 10 hex digits of its SHA-256 follow, so two names
    (``a/b``, ``a_b``) never share a file."""
    slug = re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("_.")[:SLUG_MAX].strip("_.")
    if slug and slug == text:
        return slug
    digest = hashlib.sha256(text.encode("utf-8", "surrogatepass")).hexdigest()[:10]
    return f"{slug}_{digest}" if slug else f"frame_{digest}"


class _Writer:
    """Writes files under the report folder and collects the index's Markdown."""

    def __init__(self, out: Path, *, svg: bool = False) -> None:
        self.out = out
        self.svg = svg
        self.lines: list[str] = []
        self.figures: list[tuple[str, str]] = []  # (PNG relative to out, caption), for the HTML page
        self.tables: list[Table] = []  # every table written, in order: the HTML page shows them all
        #: the provenance footer of every table file (lightemma.evaluation.descriptors.footer_lines); [] for none
        self.footer: list[str] = []

    def rel(self, path: Path) -> str:
        return path.relative_to(self.out).as_posix()

    def table(self, table: Table, *, latex: bool = True) -> None:
        """Write ``tables/<stem>.{md,csv,tex}`` (each file ending with the provenance footer, :attr:`footer`, as
        ``lightemma evaluate``'s output does) and add the table to index.md and the HTML page."""

        def footer(fmt: str) -> str:
            return provenance_footer(self.footer, fmt) if self.footer else ""

        base = self.out / "tables" / table.stem  # a table split by frame set: one file per frame set
        base.parent.mkdir(parents=True, exist_ok=True)
        base.with_suffix(".md").write_text(to_markdown(table) + footer("md"), encoding="utf-8")
        base.with_suffix(".csv").write_text(to_csv(table) + footer("csv"), encoding="utf-8")
        links = [f"[csv]({self.rel(base.with_suffix('.csv'))})"]
        if latex:
            base.with_suffix(".tex").write_text(to_latex(table) + footer("latex"), encoding="utf-8")
            links.append(f"[LaTeX]({self.rel(base.with_suffix('.tex'))})")
        self.lines += [to_markdown(table), " · ".join(links), ""]
        self.tables.append(table)

    def figure(self, fig: Any, stem: str, caption: str) -> Path:
        caption = printable(caption)  # it names frames and models: one line in index.md and index.html
        text = markdown_text(caption)  # inert in index.md: no raw HTML, no link
        alt = text.replace("[", "\\[").replace("]", "\\]")

        paths = save_figure(fig, self.out / "figures" / stem, formats=("png", "svg") if self.svg else ("png",))
        png = paths[0]
        self.lines += [
            f"![{alt}]({self.rel(png)})",
            f"*{text}*" + (f" ([svg]({self.rel(paths[1])}))" if self.svg else ""),
            "",
        ]
        self.figures.append((self.rel(png), caption))
        return png


def _scenario_table(rows: list[dict[str, Any]], labels: Sequence[str], flags: dict[str, str]) -> Table:
    """ADE avg per tag and model. "Frames" is each model's count of the tag's frames when it is the same for every
    model, else their range (``0–12``: the ``collides`` and ``off_road`` tags, or runs scored on their own frames); then
    each model's cell says its own count (``1.23 (n 12)``), so that no value stands beside a count it was not made on."""
    shown = []
    for row in rows:
        counts = [row.get(f"{label} frames", 0) for label in labels]
        same = len(set(counts)) <= 1
        out = {
            "tag": row["tag"],
            "frames": (counts[0] if counts else row.get("frames", 0)) if same else f"{min(counts)}–{max(counts)}",
        }
        for label, n in zip(labels, counts):
            value = row.get(label)
            out[label] = "-" if not value else f"{value['ade_avg']:.2f}" + ("" if same else f" (n {n})")
        shown.append(out)
    columns = [Column("tag", "Tag"), Column("frames", "Frames")] + [Column(label, label) for label in labels]
    notes = (
        []
        if all(isinstance(r["frames"], int) for r in shown)
        else [
            "Frames: the tag's frames per model where models differ in them (a range); each model's own count is in its cell (n)."
        ]
    )
    return Table("ADE avg by scenario tag", columns, shown, name="scenarios", flags=flags, notes=notes)


def _scenario_parts(
    evaluation: Evaluation, runs: Sequence[RunData], labels: Sequence[str], shared: Sequence[str] | None
) -> list[tuple[dict[str, Any], list[int]]]:
    """The scenario table's parts: ``({}, every run)`` when the runs share one frame set or are compared on their common
    frames (``shared``); else, runs on different frame sets with no frame in common, one part per frame set (title,
    ``frame_set``, ``frame_set_label`` for :class:`Table`, and the indices of its runs in ``runs``), so that no tag's
    row sets runs on other frames side by side (as :func:`~lightemma.report.evaluation_tables.frame_set_tables`)."""
    if shared is not None:
        return [({}, list(range(len(runs))))]
    by_label = {m.label: m for m in evaluation.models}
    parts: dict[str, tuple[dict[str, Any], list[int]]] = {}
    for i, label in enumerate(labels):
        fp = by_label[label].fingerprint if label in by_label else None
        key = fp["id"] if fp is not None else "unrecorded"
        text = describe_fingerprint(fp) if fp is not None else "unrecorded (no fingerprint)"
        part = {"title": f"ADE avg by scenario tag — frame set {text}", "frame_set": key, "frame_set_label": text}
        parts.setdefault(key, (part, []))[1].append(i)
    if len(parts) <= 1:
        return [({}, list(range(len(runs))))]
    return list(parts.values())


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
    return Table(
        "History bias: predicted vs true curvature against the last history curvature",
        columns,
        rows,
        name="history_bias",
        flags=flags,
        notes=notes,
    )


def _generation_lines(rows: list[dict[str, Any]]) -> list[str]:
    """One sentence per family: each generation better, worse or not distinguishable from its predecessor."""
    by_family: dict[str, list[str]] = {}
    for r in rows:
        ci = r["ci95"]
        p = r["p_holm"]
        detail = (
            f"{r['change']:+.3f} m"
            + (f" [{ci[0]:+.3f}, {ci[1]:+.3f}]" if ci else "")
            + ("" if p is None else f", p (Holm) {p:.3f}" if p >= 0.001 else ", p (Holm) < 0.001")
        )
        model, predecessor = (
            markdown_text(r["model"]),
            markdown_text(r["predecessor"]),
        )  # names from outside: inert Markdown
        by_family.setdefault(markdown_text(r["family"]), []).append(
            f"{model} is **{r['verdict']}** than {predecessor} ({detail})"
            if r["verdict"] != "not distinguishable"
            else f"{model} is **not distinguishable** from {predecessor} ({detail})"
        )
    return [f"- **{family}**: " + "; ".join(parts) + "." for family, parts in by_family.items()]


def _frame_pictures(
    w: _Writer,
    runs: Sequence[RunData],
    labels: Sequence[str],
    picks: list[tuple[str, str, str]],
    cameras: dict[str, Any],
    colors: dict[str, str],
    *,
    shown: dict[str, Sequence[str]] | None = None,
    progress: bool = False,
) -> None:
    """For each (kind, frame_id, caption): a grid of the models (those of ``shown[frame_id]`` when given — the
    models a caption's number was measured on — else all), and the worst model's picture with its texts."""
    from lightemma.report.figures import frame_figure, model_grid

    records = {id(run): read_frame_records(run.info.run_dir, [fid for _, fid, _ in picks]) for run in runs}
    indices = [run.index() for run in runs]
    valid = [run.valid for run in runs]
    if progress:
        from tqdm import tqdm

        picks = tqdm(picks, desc="frame pictures", unit="frame", leave=False)
    for kind, fid, caption in picks:
        preds, errors, gt = {}, {}, None
        for run, label, index, ok in zip(runs, labels, indices, valid):
            row = index.get(fid)
            if row is None or not ok[row] or (shown and fid in shown and label not in shown[fid]):
                continue
            gt = run.gt_positions[row]
            preds[label] = run.trajectory[row]
            errors[label] = float(displacement_errors(run.trajectory[row], gt).mean())
        if gt is None:
            continue
        w.lines.append(f"**{markdown_text(caption)}** — frame {markdown_code(fid)}")
        w.lines.append("")
        w.figure(
            model_grid(
                gt, preds, camera=cameras.get(fid), title=printable(f"{fid}: {caption}"), errors=errors, colors=colors
            ),
            f"frames/{kind}_{_slug(fid)}_grid",
            f"all models on {fid}",
        )
        models = [lab for lab, run in zip(labels, runs) if lab in errors and run.info.family != "Baseline"] or list(
            errors
        )
        worst = max(models, key=lambda m: errors[m])  # stage texts of a baseline say nothing
        run = runs[list(labels).index(worst)]
        texts = stage_texts(records[id(run)].get(fid))
        fig = frame_figure(
            gt,
            {worst: preds[worst]},
            camera=cameras.get(fid),
            texts=texts,
            title=printable(f"{fid}: {worst} (ADE {errors[worst]:.2f} m)"),
            colors=colors,
        )
        w.figure(fig, f"frames/{kind}_{_slug(fid)}_{_slug(worst)}", f"{worst} on {fid}, with its stage texts")


_ABLATION_TABLES = ("input_ablations", "baseline_gains")


def _ablation_section(w: _Writer, tables: Sequence[Table]) -> None:
    """ "Does the model look at the road?": the input ablations and the gains over the best baseline, where the runs hold them."""
    shown = [t for t in tables if t.name in _ABLATION_TABLES]
    if not shown:
        return
    w.lines += [
        "## Does the model look at the road?",
        "",
        "Each input ablation against its model's full run, and each model against the best of the constant, "
        "constant-velocity and ego-status baselines (the history alone), paired on common frames (docs/evaluate.md).",
        "",
    ]
    for table in shown:
        w.table(table)

    ablations = [r for t in shown if t.name == "input_ablations" for r in t.rows]  # every frame set's part
    gains = [r for t in shown if t.name == "baseline_gains" for r in t.rows]
    w.figure(
        ablation_figure(ablations, gains),
        "input_ablations",
        "full − ablated ADE avg per ablation run, and each model's gain over "
        "the best baseline, with 95 % scene-bootstrap intervals; filled: significant after Holm",
    )


def _safety_views(
    w: _Writer, runs: Sequence[RunData], labels: Sequence[str], safety: Any, colors: dict[str, str], per_model: int = 1
) -> None:
    """Bird's-eye views of each model's first colliding and first off-road frames (figures/bev.py)."""
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
    w.lines += [
        "## Safety — bird's-eye views",
        "",
        "Grey: drivable area; black boxes: annotated agents over the next 3 s (darker = later); outlines: ego footprints "
        "(green: ground truth), filled red where they overlap an agent, dashed red where a corner is off the drivable area.",
        "",
    ]
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


REPORT_MARKER = ".lightemma-report"  # in every report folder: a folder without it is not overwritten without force


def _is_report(folder: Path) -> bool:
    """True when ``folder`` holds a lightemma report (its marker, or an index.md that lightemma wrote)."""
    if (folder / REPORT_MARKER).is_file():
        return True
    index = folder / "index.md"
    try:
        with open(index, encoding="utf-8") as fh:
            return fh.readline().strip() == "# lightemma report"
    except (OSError, UnicodeDecodeError):
        return False


def _report_files(folder: Path) -> list[str]:
    """Every file (and link) under ``folder``, relative POSIX paths, sorted; the marker itself left out."""
    found = []
    for root, dirs, files in os.walk(folder):
        base = Path(root)
        links = [d for d in dirs if (base / d).is_symlink()]  # os.walk does not descend into them: list them as entries
        for name in [*files, *links]:
            rel = (base / name).relative_to(folder).as_posix()
            if rel != REPORT_MARKER:
                found.append(rel)
    return sorted(found)


def _marker_files(out: Path) -> list[str] | None:
    """The files the report ``out`` wrote, as its marker lists them; None when the marker is missing or has no list."""
    try:
        marker = json.loads((out / REPORT_MARKER).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    own = marker.get("files") if isinstance(marker, dict) else None
    if not isinstance(own, list) or not all(isinstance(f, str) for f in own):
        return None
    return own


def _foreign_files(out: Path) -> list[str] | None:
    """Files in the report ``out`` that its own report did not write (its marker's file list); None: no list to compare."""
    own = _marker_files(out)
    if own is None:
        return None
    own_set = set(own)
    return [f for f in _report_files(out) if f not in own_set]


def _holds_runs(folder: Path) -> Path | None:
    """The first lightemma run directory at or below ``folder`` (a ``manifest.json`` of the run store), else None."""
    for root, _dirs, files in os.walk(folder):
        if MANIFEST_FILE in files:
            return Path(root)
    return None


def _check_target(out: Path, force: bool) -> list[str]:
    """Refuse (UserError) an ``out`` the report may not replace; returns the files ``force`` keeps (relative paths).

    ``out`` may be missing, an empty folder, or a lightemma report whose marker lists the files it wrote. Refused
    whatever ``force``: a file, a non-empty folder that is no lightemma report, a folder holding a run, and a report
    whose marker has no file list (an older lightemma's: its own files cannot be told from others). A report holding
    files it did not write is refused unless ``force``, which replaces the report's own files and keeps those."""
    if not out.exists() and not out.is_symlink():
        return []
    if not out.is_dir():
        raise UserError(f"report folder {out} is a file, not a folder", cli=f"--out {out} is a file, not a folder")
    if not any(out.iterdir()):
        return []
    if not _is_report(out):
        why = "is not empty and holds no lightemma report: refusing to write over it; choose a new or empty folder"
        raise UserError(f"report folder {out} {why}", cli=f"--out {out} {why}")
    run = _holds_runs(out)
    if run is not None:
        why = f"holds the lightemma run {printable(run)}: the report would replace it; choose another folder"
        raise UserError(f"report folder {out} {why}", cli=f"--out {out} {why}")
    foreign = _foreign_files(out)
    if foreign is None:
        why = (
            "is a lightemma report without the list of its files (an older lightemma wrote it), so files added to it "
            "cannot be told apart: refusing to replace it; delete it yourself or choose another folder"
        )
        raise UserError(f"report folder {out} {why}", cli=f"--out {out} {why}")
    if foreign and not force:
        named = ", ".join(printable(f) for f in foreign[:3]) + (
            f" and {len(foreign) - 3} more" if len(foreign) > 3 else ""
        )
        why = f"holds {len(foreign)} file(s) its report did not write ({named}): refusing to replace it"
        raise UserError(
            f"report folder {out} {why} (force=True replaces only the report's own files and keeps these)",
            cli=f"--out {out} {why} (--force replaces only the report's own files and keeps these)",
        )
    return foreign


def _within(inner: Path, outer: Path) -> bool:
    return inner == outer or outer in inner.parents


def _recorded_dataroots(run_dirs: Sequence[Path]) -> list[tuple[Path, str]]:
    """Every dataroot a run's manifest records (``dataset.dataroot``, ``config.dataset.dataroot``), with the run's name.

    A manifest that cannot be read records nothing (evaluation skips its run with a warning)."""
    found: dict[str, tuple[Path, str]] = {}
    for run_dir in run_dirs:
        try:
            manifest = read_manifest(run_dir)
        except (UserError, OSError):
            continue
        config_value = manifest.get("config")
        config: dict[str, Any] = config_value if isinstance(config_value, dict) else {}
        for dataset in (manifest.get("dataset"), config.get("dataset")):
            root = dataset.get("dataroot") if isinstance(dataset, dict) else None
            if isinstance(root, str) and root and root not in found:
                found[root] = (Path(root), f" (recorded by the run {printable(run_dir)})")
    return list(found.values())


def _check_inputs(out: Path, given: Sequence[Path], run_dirs: Sequence[Path], dataroot: str | None) -> None:
    """Refuse (UserError, whatever ``force``) an ``out`` (as the user gave it) that is, contains or lies inside an input: a
    run directory, a folder of runs given or the dataroot given; or that is or contains a dataroot any run records —
    the swap would replace it. Resolved real paths are compared."""
    target = Path(os.path.realpath(out))
    inputs = [(Path(d), "input run directory", "", True) for d in run_dirs] + [
        (Path(g), "runs folder", "", True) for g in given if Path(g).is_dir()
    ]
    if dataroot is not None:
        inputs.append((Path(dataroot), "dataroot", "", True))
    inputs += [
        (path, "dataroot", note, False) for path, note in _recorded_dataroots(run_dirs)
    ]  # a report inside one replaces nothing of it
    clashes = []  # (rank, relation, what, path, note): "is" named before "contains" before "lies inside"
    for path, what, note, inside in inputs:
        real = Path(os.path.realpath(path))
        if target == real:
            clashes.append((0, "is", what, path, note))
        elif _within(real, target):
            clashes.append((1, "contains", what, path, note))
        elif inside and _within(target, real):
            clashes.append((2, "lies inside", what, path, note))
    if clashes:
        _, relation, what, path, note = min(clashes, key=lambda c: c[0])
        message = (
            f"{out} {relation} the {what} {printable(path)}{note}: the report would replace it; choose another folder"
        )
        raise UserError(
            f"report folder {message} (force does not override this)",
            cli=f"--out {message} (--force does not override this)",
        )


def _keep_files(old: Path, new: Path, keep: Sequence[str]) -> None:
    """Copy the files ``keep`` (relative paths) that the old report ``old`` holds but did not write into the new report
    ``new`` (links as links). Refused (UserError) where the new report writes a file of that name or the entry is not a
    regular file or a link: nothing the report did not write is replaced or lost."""
    import shutil

    for rel in keep:
        src, dst = old / rel, new / rel
        if dst.exists() or dst.is_symlink():
            why = f"--force cannot keep {printable(rel)}: the new report writes a file of that name; move it away first"
            raise UserError(f"report folder {old}: {why}", cli=f"--out {old}: {why}")
        if not src.is_symlink() and not src.is_file():
            why = f"holds {printable(rel)}, which is not a regular file: refusing to replace it; move it away first"
            raise UserError(f"report folder {old} {why}", cli=f"--out {old} {why}")
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, dst, follow_symlinks=False)


def _delete_own(old: Path, kept_in: Path | None) -> list[str]:
    """Delete from the replaced report ``old`` only what it wrote (its marker's list, the marker) and the files kept as
    identical copies in ``kept_in``; then its empty folders. Returns what is left (then ``old`` stays where it is)."""
    import filecmp

    own = set(_marker_files(old) or [])
    for rel in _report_files(old):
        path = old / rel
        copy = kept_in / rel if kept_in is not None else None
        same = copy is not None and (
            (path.is_symlink() and copy.is_symlink() and os.readlink(path) == os.readlink(copy))
            or (
                not path.is_symlink()
                and path.is_file()
                and copy.is_file()
                and not copy.is_symlink()
                and filecmp.cmp(path, copy, shallow=False)
            )
        )
        if rel in own or same:
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
    with contextlib.suppress(FileNotFoundError):
        (old / REPORT_MARKER).unlink()
    for root, dirs, _files in os.walk(old, topdown=False):
        for name in dirs:
            with contextlib.suppress(OSError):
                (Path(root) / name).rmdir()  # only an empty one goes
    left = _report_files(old) if old.exists() else []
    if old.is_symlink() and not left:  # ``out`` was a link to the old report: its folder is emptied, the link goes
        old.unlink()
    with contextlib.suppress(OSError):
        old.rmdir()
    return left


def _swap_in(tmp: Path, out: Path) -> None:
    """Put the finished report ``tmp`` at ``out`` whole: the old folder is moved aside, then what it wrote removed."""
    old = None
    if out.exists():
        old = out.with_name(f".{out.name}.old-{os.getpid()}")
        if (
            old.exists() or old.is_symlink()
        ):  # kept by an earlier report of this process: it holds files no report wrote
            raise UserError(f"{old} is in the way of replacing the report {out}: move it away first")
        os.rename(out, old)
    try:
        os.rename(tmp, out)
    except OSError:
        if old is not None:
            os.rename(old, out)  # put the old report back
        raise
    if old is not None:
        left = _delete_own(old, out)
        if left:
            print(
                f"lightemma report: warning: kept {printable(old)}: it holds {len(left)} file(s) the old report did not write "
                f"and that are not in the new one ({printable(left[0])}{', …' if len(left) > 1 else ''})",
                file=sys.stderr,
            )


def _remove_stale(out: Path) -> None:
    """Hidden folders left beside ``out`` by a report that was killed (its process is gone): a half-written report is
    removed; a replaced one is put back when ``out`` is missing (killed between the two renames), else only what it
    wrote and what ``out`` holds identical copies of is removed."""
    import shutil

    for kind in ("partial", "old"):
        for path in out.parent.glob(f".{glob_escape(out.name)}.{kind}-*"):
            pid = path.name.rsplit("-", 1)[-1]
            if not pid.isdigit() or int(pid) == os.getpid() or pid_alive(int(pid)):
                continue
            if kind == "partial":
                shutil.rmtree(path, ignore_errors=True)  # only what a report wrote, and copies of files kept
            elif not out.exists() and not out.is_symlink():
                os.rename(path, out)
            else:
                _delete_own(path, out)


WARNING_EXAMPLES = 3  # warnings of one kind shown in full before the rest are counted
WARNINGS_FILE = "warnings.txt"  # every warning of a report, one a line, where some were summarised
# what differs between warnings of one kind: frame ids (scene/token), sample tokens, paths, counts and sizes
_VARYING = re.compile(r"\S+/[0-9a-f]{8,}|[0-9a-f]{8,}|(?<![\w.])/\S+|\d+(?:\.\d+)?")


def warning_kind(text: str, names: Sequence[str] = ()) -> str:
    """What a warning says without what varies between warnings of one kind: each of ``names`` (the run labels),
    frame ids, sample tokens, absolute paths and numbers replaced by a placeholder."""
    for name in sorted((n for n in names if n), key=len, reverse=True):
        text = text.replace(name, "\0")
    return _VARYING.sub("#", text)


def summarise_warnings(
    warnings: Sequence[str], examples: int = WARNING_EXAMPLES, names: Sequence[str] = ()
) -> list[tuple[str, list[str]]]:
    """Warnings grouped by :func:`warning_kind` (``names``: the run labels), in order of first appearance:
    (headline, examples) per group.

    A kind seen at most ``examples`` times gives each warning as a headline with no examples; a kind seen more often
    gives one headline, ``"N warnings like: <first>"``, and the next ``examples - 1`` warnings as examples (the rest
    are counted, not repeated). A warning given twice (the same text) counts once."""
    groups: dict[str, list[str]] = {}
    for text in dict.fromkeys(warnings):
        groups.setdefault(warning_kind(text, names), []).append(text)
    out: list[tuple[str, list[str]]] = []
    for members in groups.values():
        if len(members) <= examples:
            out += [(text, []) for text in members]
        else:
            out.append((f"{len(members)} warnings like: {members[0]}", members[1:examples]))
    return out


def _drop_empty_runs(runs: list[RunData]) -> tuple[list[RunData], list[str]]:
    """Runs with no scored frame, left out (with a warning naming each) when another run has one."""
    empty = [r for r in runs if not r.valid.any()]
    if not empty or len(empty) == len(runs):
        return runs, []
    return [r for r in runs if r.valid.any()], [
        f"left out {r.info.run_dir}: no scored frame (an empty or aborted run)" for r in empty
    ]


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
    svg: bool = False,
    force: bool = False,
    progress: bool = False,
    version: str | None = None,
    safety: bool = True,
) -> Path:
    """Evaluate runs and write tables, figures, the scenario analysis and ``index.html`` into ``out``; returns ``index.md``.

    ``frames`` adds pictures of chosen frame ids (e.g. to redraw the paper's Fig. 3 cases);
    ``case_tags`` are the scenario tags whose worst frame is drawn (default
    :data:`lightemma.evaluation.scenarios.CASE_TAGS`; ``()`` for none); ``pairwise`` compares
    every pair of runs (table, matrix figure, per-family generation verdicts);
    ``resampling`` sets the scene bootstrap (resamples, seed, confidence); ``svg`` also writes
    every figure as SVG (PNG only by default); ``progress`` shows progress bars (tqdm, on stderr).
    With ``safety`` the tables carry off-road and collision columns (from ``dataroot``/``version`` when both
    are given, else each run's own dataset), the scenarios the ``collides`` / ``off_road`` tags, and a
    bird's-eye view is drawn of each model's first colliding and first off-road frame.

    The report is written into a hidden folder beside ``out`` and swapped in whole when done: a
    killed report leaves the old one intact. An ``out`` that is a non-empty folder holding no
    lightemma report, or a report holding files it did not write (its ``.lightemma-report`` marker lists
    its own), is refused unless ``force``; an ``out`` that is, contains or lies inside an input run
    directory, a runs folder given or ``dataroot`` is refused even with ``force``. Runs without a scored frame are left out (with
    a warning) when another run has one. A ``dataroot`` that is not a folder (or lacks the folder
    ``version`` when both are given), or a negative ``top``,
    raises :class:`~lightemma.errors.UserError` before any work.
    """
    import shutil

    given = Path(out)
    out = Path(os.path.abspath(given))  # "." has no name to put a hidden folder beside
    if isinstance(top, bool) or not isinstance(top, int) or top < 0:
        raise UserError(
            f"top must be a whole number of frames, 0 or more, got {top!r}", cli=f"--top must be 0 or more, got {top!r}"
        )
    if dataroot is not None and not os.path.isdir(dataroot):
        what = "is not a folder" if os.path.exists(dataroot) else "does not exist"
        raise UserError(f"dataroot {dataroot} {what}", cli=f"--dataroot {dataroot} {what}")
    if dataroot is not None and version and not os.path.isdir(os.path.join(dataroot, version)):
        raise UserError(
            f"dataroot {dataroot} has no folder {version}",
            cli=f"--version {version}: --dataroot {dataroot} has no folder {version}",
        )
    given_dirs = [Path(d) for d in run_dirs]  # an iterator is read once
    dirs = expand_run_dirs(given_dirs)  # every run found, a corrupt one too: none may be replaced
    _check_inputs(given, given_dirs, dirs, dataroot)
    _check_target(out, force)
    out.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale(out)
    tmp = out.with_name(f".{out.name}.partial-{os.getpid()}")
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir()
    try:
        _write(
            tmp,
            given_dirs,
            convention=convention,
            common=common,
            with_paper=with_paper,
            top=top,
            dataroot=dataroot,
            pictures=pictures,
            frames=frames,
            case_tags=case_tags,
            pairwise=pairwise,
            resampling=resampling,
            svg=svg,
            progress=progress,
            version=version,
            safety=safety,
        )
        marker = {"written_by": "lightemma report", "files": _report_files(tmp)}  # what a re-report may replace
        (tmp / REPORT_MARKER).write_text(json.dumps(marker) + "\n", encoding="utf-8")
        keep = _check_target(out, force)  # again: files added to the old report while this one was written
        _keep_files(out, tmp, keep)  # with force: what the old report did not write goes into the new one
        _swap_in(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return given / "index.md"


class _Steps:
    """The report's long steps as one progress bar (tqdm on stderr), or nothing."""

    def __init__(self, enabled: bool, total: int) -> None:
        self.bar = None
        if enabled:
            from tqdm import tqdm

            self.bar = tqdm(total=total, desc="report", unit="step", leave=False)

    def step(self, what: str) -> None:
        if self.bar is not None:
            self.bar.set_postfix_str(what, refresh=False)
            self.bar.update(1)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _frame_set_id(model: Any) -> str:
    """A run's frame-set fingerprint id (``frames:3f2a…``), or ``unrecorded``."""
    return model.fingerprint["id"] if model.fingerprint is not None else "unrecorded"


def _runs_table(evaluation: Evaluation, flags: dict[str, str]) -> Table:
    rows = [
        {
            "model": m.label,
            "family": m.family,
            "run": str(m.run_dir),
            "frames": m.frames_in_run,
            "complete": "yes" if m.complete else "no",
            "integrator": m.integrator,
            "chain": m.chain,
            "answer_format": m.answer_format,
            "inputs": m.inputs,
            "frame_set": _frame_set_id(m),
        }
        for m in evaluation.models
    ]
    columns = [
        Column("model", "Model"),
        Column("family", "Family"),
        Column("run", "Run"),
        Column("frames", "Frames in run"),
        Column("complete", "Finished"),
        Column("integrator", "Integrator"),
        Column("chain", "Chain"),
        Column("answer_format", "Answer format"),
        Column("inputs", "Inputs"),
        Column("frame_set", "Frame set"),
    ]
    return Table("Runs", columns, rows, name="runs", flags=flags)


def _planning_section(w: _Writer, evaluation: Evaluation, colors: dict[str, str], flags: dict[str, str]) -> None:
    """The planning score by sub-score: one bar per model and the ground truth (when some value is there)."""
    result = evaluation.planning
    rows = [{"model": m.label, **m.planning} for m in evaluation.models] + (
        [result.ground_truth] if result.ground_truth else []
    )
    if not any(r.get(k) is not None for r in rows for k in KEYS):
        return
    w.lines += ["## Planning score by sub-score", ""]
    w.figure(
        planning_figure(rows, colors=colors, notes=flags, gt_label=GT_LABEL),
        "planning",
        "NAVSIM's planning score per model and the ground truth's own: the aggregates, then each sub-score, means over "
        "the frames with a value and their 95 % scene-bootstrap intervals; n/a where no frame has one (the table says why)",
    )


def _write(
    out: Path,
    run_dirs: Iterable[str | os.PathLike[str]],
    *,
    convention: str,
    common: bool,
    with_paper: bool,
    top: int,
    dataroot: str | None,
    pictures: bool,
    frames: Sequence[str],
    case_tags: Sequence[str] | None,
    pairwise: bool,
    resampling: Resampling,
    svg: bool,
    progress: bool,
    version: str | None,
    safety: bool,
) -> None:
    import html as html_escape

    from lightemma.report.html import write_html

    dirs, left_out = discover_runs(run_dirs)  # a corrupt manifest or a linked run: left out with a warning
    steps = _Steps(progress, total=len(dirs) + 7)
    runs = []
    for d in dirs:
        runs.append(load_run(d, details=True))
        steps.step(f"loaded {Path(d).name}")
    runs, skipped = _drop_empty_runs(runs)
    known = set().union(*(r.frame_ids for r in runs)) if runs else set()
    missing = [fid for fid in frames if fid not in known]
    if missing:
        raise UserError(f"frame(s) not in any run: {', '.join(missing[:5])}{' …' if len(missing) > 5 else ''}")
    evaluation: Evaluation = evaluate_loaded(
        runs,
        convention=convention,
        common=common,
        resampling=resampling,
        pairwise=pairwise and len(runs) > 1,
        safety=safety,
        dataroot=dataroot if version else None,
        version=version,
    )
    evaluation.warnings[:0] = [*left_out, *skipped]
    steps.step("evaluated")
    order = {m.run_dir: i for i, m in enumerate(evaluation.models)}
    runs.sort(key=lambda r: order[r.info.run_dir])
    labels = unique_labels(runs)
    colors = run_colors(
        labels
    )  # one colour per run, distinct in every figure that draws runs together (not per family)
    if len(labels) > len(RUN_PALETTE):
        evaluation.warnings.append(
            f"{len(labels)} runs, {len(RUN_PALETTE)} distinct colours: from run {len(RUN_PALETTE) + 1} on, "
            "the figures repeat colours (tell runs apart by their legends' order)"
        )
    flags = coverage_flags(evaluation)
    w = _Writer(out, svg=svg)

    w.footer = footer_lines(evaluation)  # software, frame sets, maps, metric ids: under every table file
    w.lines += [
        "# lightemma report",
        "",
        "Browse it: [index.html](index.html) (tables, figures and every frame; opens from disk).",
        "",
        "| Model | Family | Run | Frames in run | Finished | Integrator | Chain | Answer format | Inputs | Frame set |",
        "|---|---|---|---:|---|---|---|---|---|---|",
    ]
    w.lines += [
        "| "
        + " | ".join(
            markdown_cell(c)
            for c in (
                m.label + flags.get(m.label, ""),
                m.family,
                m.run_dir,
                m.frames_in_run,
                "yes" if m.complete else "no",
                m.integrator,
                m.chain,
                m.answer_format,
                m.inputs,
                _frame_set_id(m),
            )
        )
        + " |"
        for m in evaluation.models
    ]  # every cell one line: names from outside cannot split a row
    w.lines.append("")

    summary = summarise_warnings(evaluation.warnings, names=[*labels, FLOOR_LABEL, "ground truth"])
    if evaluation.warnings:
        w.lines += ["**Warnings**", ""]
        for head, more in summary:
            w.lines += [f"- {markdown_text(head)}"] + [f"  - e.g. also: {markdown_text(x)}" for x in more]
        if len(summary) < len(dict.fromkeys(evaluation.warnings)):
            every = "".join(printable(x) + "\n" for x in dict.fromkeys(evaluation.warnings))
            (out / WARNINGS_FILE).write_text(every, encoding="utf-8")
            w.lines += ["", f"Every warning, one a line: [{WARNINGS_FILE}]({WARNINGS_FILE})."]
        w.lines += [""]
    for head, more in summary:  # on stderr too: a report's warnings are not only in index.md
        print(f"lightemma report: warning: {printable(head)}", file=sys.stderr)
        for x in more:
            print(f"lightemma report:   e.g. also: {printable(x)}", file=sys.stderr)
    if len(summary) < len(dict.fromkeys(evaluation.warnings)):
        print(f"lightemma report: every warning: {WARNINGS_FILE} in the report", file=sys.stderr)

    if flags:
        w.lines += [
            f"**Fewer than half of the frames scored** for {markdown_text(', '.join(flags))}: their numbers describe only the frames they managed; every table flags them.",
            "",
        ]
    w.lines += ["## Tables I and II", ""]
    groups = frame_set_groups(evaluation)
    if groups is not None:  # runs on different frame sets: never ranked in one column (docs/evaluate.md)
        w.lines += [
            f"**Runs on {len(groups)} frame sets**: every table shows each frame set apart (its fingerprint "
            "and frame count in the title), never ranking runs across frame sets; `--common` scores every run "
            "on the frames common to all.",
            "",
        ]
    tables = frame_set_tables(evaluation_tables(evaluation, with_paper=with_paper), evaluation)
    for table in tables:
        if table.name in (
            "pairwise_ade",
            "generations",
            "pairwise_safety",
            "pairwise_planning",
            *_ABLATION_TABLES,
            "robustness",
            "visual_reliance",
        ):  # their own sections below
            continue
        w.table(table)

    numbers = {
        **evaluation.to_dict(),
        "provenance": provenance(
            evaluation, with_paper=with_paper, dataroot=dataroot if version else None, version=version
        ),
        **({"frame_set_groups": groups} if groups is not None else {}),
    }
    (out / "tables" / "evaluation.json").write_text(json.dumps(numbers, indent=2, default=str) + "\n", encoding="utf-8")

    w.table(provenance_table(evaluation))
    w.lines += ["All numbers as JSON: [tables/evaluation.json](tables/evaluation.json)", ""]

    w.lines += ["## Fig. 1 — ADE by family and generation", ""]
    main_convention = evaluation.main_convention
    points = bubble_points(evaluation, convention=main_convention, with_paper=with_paper)
    if any(p["ade_avg"] is not None for p in points):
        caption = (
            "ADE avg per model (scored frames) with its 95 % scene-bootstrap interval; bubble area ∝ time per frame; colour = family, one shade per model"
            + ("; hollow = the paper's" if with_paper else "")
        )
        w.figure(bubble_chart(points), "bubble", caption)
    else:
        w.lines += ["No model has a scored frame yet; no chart.", ""]

    if evaluation.planning is not None:  # the planning score broken into its sub-scores (report/figures/subscores.py)
        _planning_section(w, evaluation, colors, flags)
    if evaluation.explanations is not None and evaluation.explanations.shown:  # report/figures/consistency.py
        w.lines += ["## Explanations", ""]
        w.figure(
            explanations_figure(
                [{"model": m.label, **m.explanations} for m in evaluation.models], colors=colors, notes=flags
            ),
            "explanations",
            "Per model the share of frames whose stated intent is consistent with its own plan, and with what the car "
            "did (intent accuracy), with 95 % scene-bootstrap intervals; n/a for runs without stage-2 texts",
        )

    if evaluation.pairwise is not None:
        w.lines += ["## Paired comparisons", ""]
        generations = evaluation.generations()
        if generations:
            w.lines += [
                "Is each generation better than its predecessor? (ADE avg change newer − older, 95 % scene-bootstrap interval, Holm-adjusted p over all pairs)",
                "",
            ]
            w.lines += _generation_lines(generations) + [""]
        for table in tables:
            if table.name in ("pairwise_ade", "generations", "pairwise_safety", "pairwise_planning"):
                w.table(table)
        labels_shown = [m.label for m in evaluation.models]
        w.figure(
            pairwise_figure(evaluation.pairwise, labels_shown, notes=flags),
            "pairwise",
            f"ADE avg of row − column model on their common frames ({main_convention}); * significant after Holm",
        )

    _ablation_section(w, tables)

    robustness_section(w, tables, evaluation)  # a sweep's variants against its clean run, and the severity figure

    shared = common_frames(runs) if len(runs) > 1 else None
    scope = f"the {len(shared)} frames scored in every run" if shared else "each run's scored frames"
    w.lines += ["## Scenarios", "", f"ADE avg (m) per scenario tag, on {scope}. Tag rules: docs/evaluate.md.", ""]
    steps.step("tables and charts")
    for part, members in _scenario_parts(evaluation, runs, labels, shared if groups is None or shared else None):
        rows = per_tag_metrics(
            [runs[i] for i in members],
            convention=main_convention,
            frame_ids=shared or None,
            safety=evaluation.safety,
            planning=evaluation.planning,
            explanations=evaluation.explanations,
        )
        table = _scenario_table(rows, [labels[i] for i in members], flags)
        w.table(replace(table, **part), latex=False)
    w.lines += ["Case 1 of the paper (a finished turn carried into the prediction), measured over all frames:", ""]
    bias = history_bias(runs)
    for table in frame_set_tables([_bias_table(bias, flags)], evaluation):  # each run on its own frames: by frame set
        w.table(table, latex=False)
    w.figure(
        history_bias_figure(runs, colors=colors, rows=bias, notes=flags),
        "history_bias",
        "predicted and true future curvature against the last history curvature: Theil–Sen slopes with 95 % intervals, and the carry-over just after a turn",
    )

    picks = [("frame", fid, "requested frame") for fid in frames]
    spread = disagreements(runs, top=top)
    picks += [
        (
            "disagree",
            d["frame_id"],
            f"the {len(d['models'])} models shown disagree by {d['spread_m']:.1f} m at 3 s"
            + ("" if len(d["models"]) == len(runs) else " (baselines not compared)"),
        )
        for d in spread
    ]
    picks += [
        (
            "case",
            c["frame_id"],
            f"worst `{c['tag']}` frame (mean FDE {c['mean_fde']:.2f} m of {c['frames_with_tag']} tagged)",
        )
        for c in worst_frame_per_tag(runs, CASE_TAGS if case_tags is None else case_tags)
    ]
    picks = _merge_picks(picks)
    steps.step("scenario analysis")
    source = CameraSource(dataroot)
    if pictures and picks:
        cameras = source.cameras(runs, [fid for _, fid, _ in picks])
        w.lines += ["## Frames: requested, where models disagree most, and the worst of each failure case", ""]
        w.lines += [f"> {markdown_text(p)}" for p in dict.fromkeys(source.problems)] + ([""] if source.problems else [])
        _frame_pictures(
            w,
            runs,
            labels,
            picks,
            cameras,
            colors,
            shown={d["frame_id"]: d["models"] for d in spread},
            progress=progress,
        )
    if pictures and evaluation.safety is not None:
        _safety_views(w, runs, labels, evaluation.safety, colors)
    steps.step("frame pictures")
    index = out / "index.md"
    index.write_text("\n".join(w.lines) + "\n", encoding="utf-8")

    texts: dict[str, dict[str, tuple[str, str, str]]] = {}
    calibrations: dict[str, dict[str, Any]] = {}  # imported runs: the fields a camera needs, read in the same pass
    for label, run in zip(labels, runs):
        own = texts[label] = {}
        for fid, r in read_frame_records(run.info.run_dir, run.frame_ids).items():
            scene, intent, answer = (visible_lines(r.get(key) or "") for key in ("scene_text", "intent_text", "answer"))
            own[fid] = (scene, intent, answer)
            if run.info.imported and pictures and fid not in calibrations:
                calibrations[fid] = {k: r.get(k) for k in ("camera_params", "image_name", "image_path")}
    steps.step("stage texts")
    all_ids = list(dict.fromkeys(fid for run in runs for fid in run.frame_ids))
    html_cameras = source.cameras(runs, all_ids, load=False, records=calibrations) if pictures else {}
    notes = [*summary, *summarise_warnings(list(dict.fromkeys(source.problems)))]
    intro = "".join(
        f'<p class="note">{html_escape.escape(printable(head))}'
        + "".join(f"<br>e.g. also: {html_escape.escape(printable(x))}" for x in more)
        + "</p>"
        for head, more in notes
    )
    write_html(
        out,
        title="lightemma report",
        intro_html=intro,
        tables=[_runs_table(evaluation, flags), *w.tables],
        figures=w.figures,
        runs=runs,
        labels=labels,
        colors=colors,
        texts=texts,
        cameras=html_cameras,
        progress=progress,
        safety=evaluation.safety,
        planning=evaluation.planning,
        explanations=evaluation.explanations,
    )
    steps.step("index.html")
    steps.close()
