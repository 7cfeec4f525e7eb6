"""``lightemma report``: tables, figures and the scenario analysis of runs in one folder.

Layout of ``OUT``::

    index.md                      links everything below, tables inline
    tables/efficiency.{md,csv,tex}, tables/accuracy_<convention>.{md,csv,tex}
    tables/pairwise_ade.{md,csv,tex}, tables/generations.{md,csv,tex}   (paired comparisons)
    tables/input_ablations.{md,csv,tex}, tables/baseline_gains.{md,csv,tex}   (does the image matter?)
    tables/scenarios.{md,csv}, tables/history_bias.{md,csv}, tables/evaluation.json
    figures/bubble.{png,svg}, figures/pairwise.{png,svg}, figures/history_bias.{png,svg}, figures/input_ablations.{png,svg}
    figures/frames/<kind>_<frame>.{png,svg}     model grids and single-model pictures

Every model keeps one colour in every figure; only scored frames enter a mean,
a figure or the frame picker (docs/statistics.md).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from glob import escape as glob_escape
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lightemma.evaluation import Evaluation, RunData, common_frames, evaluate_loaded, expand_run_dirs, load_run, read_frame_records
from lightemma._text import printable
from lightemma.evaluation.core import unique_labels
from lightemma.errors import UserError
from lightemma.evaluation.stats import Resampling
from lightemma.report.evaluation_tables import evaluation_tables
from lightemma.runs.store import pid_alive
from lightemma.report.tables import Column, Table, fixed, markdown_cell, to_csv, to_latex, to_markdown


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
        self.tables.append(table)

    def figure(self, fig: Any, stem: str, caption: str) -> Path:
        from lightemma.report.figures import save_figure

        caption = printable(caption)  # it names frames and models: one line in index.md and index.html

        paths = save_figure(fig, self.out / "figures" / stem, formats=("png", "svg") if self.svg else ("png",))
        png = paths[0]
        self.lines += [f"![{caption}]({self.rel(png)})", f"*{caption}*" + (f" ([svg]({self.rel(paths[1])}))" if self.svg else ""), ""]
        self.figures.append((self.rel(png), caption))
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
    return [printable(f"- **{family}**: " + "; ".join(parts) + ".") for family, parts in by_family.items()]


def _frame_pictures(w: _Writer, runs: Sequence[RunData], labels: Sequence[str], picks: list[tuple[str, str, str]], cameras: dict[str, Any], colors: dict[str, str], *,
                    shown: dict[str, Sequence[str]] | None = None, progress: bool = False) -> None:
    """For each (kind, frame_id, caption): a grid of the models (those of ``shown[frame_id]`` when given — the
    models a caption's number was measured on — else all), and the worst model's picture with its texts."""
    from lightemma.report.figures import frame_figure, model_grid
    from lightemma.report.pictures import stage_texts

    from lightemma import displacement_errors

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
        w.lines.append(printable(f"**{caption}** — frame `{fid}`"))
        w.lines.append("")
        w.figure(model_grid(gt, preds, camera=cameras.get(fid), title=f"{fid}: {caption}", errors=errors, colors=colors), f"frames/{kind}_{_slug(fid)}_grid", f"all models on {fid}")
        models = [lab for lab, run in zip(labels, runs) if lab in errors and run.info.family != "Baseline"] or list(errors)
        worst = max(models, key=errors.get)  # stage texts of a baseline say nothing
        run = runs[list(labels).index(worst)]
        texts = stage_texts(records[id(run)].get(fid))
        fig = frame_figure(gt, {worst: preds[worst]}, camera=cameras.get(fid), texts=texts, title=f"{fid}: {worst} (ADE {errors[worst]:.2f} m)", colors=colors)
        w.figure(fig, f"frames/{kind}_{_slug(fid)}_{_slug(worst)}", f"{worst} on {fid}, with its stage texts")


_ABLATION_TABLES = ("input_ablations", "baseline_gains")


def _ablation_section(w: _Writer, tables: Sequence[Table]) -> None:
    """"Does the model look at the road?": the input ablations and the gains over the best baseline, where the runs hold them."""
    shown = [t for t in tables if t.name in _ABLATION_TABLES]
    if not shown:
        return
    w.lines += ["## Does the model look at the road?", "",
                "Each input ablation against its model's full run, and each model against the best of the constant, "
                "constant-velocity and ego-status baselines (the history alone), paired on common frames (docs/evaluate.md).", ""]
    for table in shown:
        w.table(table)
    from lightemma.report.figures import ablation_figure

    ablations = next((t.rows for t in shown if t.name == "input_ablations"), [])
    gains = next((t.rows for t in shown if t.name == "baseline_gains"), [])
    w.figure(ablation_figure(ablations, gains), "input_ablations", "full − ablated ADE avg per ablation run, and each model's gain over "
             "the best baseline, with 95 % scene-bootstrap intervals; filled: significant after Holm")


def _safety_views(w: _Writer, runs: Sequence[RunData], labels: Sequence[str], safety: Any, colors: dict[str, str], per_model: int = 1) -> None:
    """Bird's-eye views of each model's first colliding and first off-road frames (figures/bev.py)."""
    from lightemma.evaluation.safety import frame_tags
    from lightemma.report.figures.bev import bev_figure

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


def _foreign_files(out: Path) -> list[str] | None:
    """Files in the report ``out`` that its own report did not write (its marker's file list); None: no list to compare."""
    try:
        marker = json.loads((out / REPORT_MARKER).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    own = marker.get("files") if isinstance(marker, dict) else None
    if not isinstance(own, list) or not all(isinstance(f, str) for f in own):
        return None
    own_set = set(own)
    return [f for f in _report_files(out) if f not in own_set]


def _check_target(out: Path, force: bool) -> None:
    """Refuse (UserError) an ``out`` that is a file, or — unless ``force`` — a non-empty folder that is not a lightemma
    report, or a report that holds files its report did not write (the marker's file list), or one without that list."""
    if not out.exists() and not out.is_symlink():
        return
    if not out.is_dir():
        raise UserError(f"report folder {out} is a file, not a folder", cli=f"--out {out} is a file, not a folder")
    if force or not any(out.iterdir()):
        return
    if not _is_report(out):
        raise UserError(f"{out} is not empty and holds no lightemma report: refusing to overwrite it (force=True to replace it)",
                        cli=f"--out {out} is not empty and holds no lightemma report: refusing to overwrite it (--force replaces it)")
    foreign = _foreign_files(out)
    if foreign is None:
        why = "is a lightemma report without the list of its files (an older lightemma wrote it), so files added to it cannot be told apart"
        raise UserError(f"{out} {why}: refusing to replace it (force=True replaces it)", cli=f"--out {out} {why}: refusing to replace it (--force replaces it)")
    if foreign:
        named = ", ".join(foreign[:3]) + (f" and {len(foreign) - 3} more" if len(foreign) > 3 else "")
        why = f"holds {len(foreign)} file(s) its report did not write ({named})"
        raise UserError(f"{out} {why}: refusing to replace it (force=True replaces it)", cli=f"--out {out} {why}: refusing to replace it (--force replaces it)")


def _within(inner: Path, outer: Path) -> bool:
    return inner == outer or outer in inner.parents


def _check_inputs(out: Path, given: Sequence[Path], run_dirs: Sequence[Path], dataroot: str | None) -> None:
    """Refuse (UserError, whatever ``force``) an ``out`` (as the user gave it) that is, contains or lies inside an input: a
    run directory, a folder of runs given, or the dataroot — the swap would replace it. Resolved real paths are compared."""
    target = Path(os.path.realpath(out))
    inputs = [(Path(d), "input run directory") for d in run_dirs] + [(Path(g), "runs folder") for g in given if Path(g).is_dir()]
    if dataroot is not None:
        inputs.append((Path(dataroot), "dataroot"))
    clashes = []  # (rank, relation, what, path): "is" named before "contains" before "lies inside"
    for path, what in inputs:
        real = Path(os.path.realpath(path))
        if target == real:
            clashes.append((0, "is", what, path))
        elif _within(real, target):
            clashes.append((1, "contains", what, path))
        elif _within(target, real):
            clashes.append((2, "lies inside", what, path))
    if clashes:
        _, relation, what, path = min(clashes, key=lambda c: c[0])
        message = f"{out} {relation} the {what} {path}: the report would replace it; choose another folder"
        raise UserError(f"report folder {message} (force does not override this)", cli=f"--out {message} (--force does not override this)")


def _swap_in(tmp: Path, out: Path) -> None:
    """Put the finished report ``tmp`` at ``out`` whole: the old folder is moved aside, then removed."""
    import shutil

    old = None
    if out.exists():
        old = out.with_name(f".{out.name}.old-{os.getpid()}")
        if old.exists():
            shutil.rmtree(old)
        os.rename(out, old)
    try:
        os.rename(tmp, out)
    except OSError:
        if old is not None:
            os.rename(old, out)  # put the old report back
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _remove_stale(out: Path) -> None:
    """Hidden folders left beside ``out`` by a report that was killed (its process is gone)."""
    import shutil

    for kind in ("partial", "old"):
        for path in out.parent.glob(f".{glob_escape(out.name)}.{kind}-*"):
            pid = path.name.rsplit("-", 1)[-1]
            if pid.isdigit() and int(pid) != os.getpid() and not pid_alive(int(pid)):
                shutil.rmtree(path, ignore_errors=True)


def _drop_empty_runs(runs: list[RunData]) -> tuple[list[RunData], list[str]]:
    """Runs with no scored frame, left out (with a warning naming each) when another run has one."""
    empty = [r for r in runs if not r.valid.any()]
    if not empty or len(empty) == len(runs):
        return runs, []
    return [r for r in runs if r.valid.any()], [f"left out {r.info.run_dir}: no scored frame (an empty or aborted run)" for r in empty]


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
        raise UserError(f"top must be a whole number of frames, 0 or more, got {top!r}", cli=f"--top must be 0 or more, got {top!r}")
    if dataroot is not None and not os.path.isdir(dataroot):
        what = "is not a folder" if os.path.exists(dataroot) else "does not exist"
        raise UserError(f"dataroot {dataroot} {what}", cli=f"--dataroot {dataroot} {what}")
    if dataroot is not None and version and not os.path.isdir(os.path.join(dataroot, version)):
        raise UserError(f"dataroot {dataroot} has no folder {version}", cli=f"--version {version}: --dataroot {dataroot} has no folder {version}")
    given_dirs = [Path(d) for d in run_dirs]  # an iterator is read once
    dirs = expand_run_dirs(given_dirs)
    _check_inputs(given, given_dirs, dirs, dataroot)
    _check_target(out, force)
    out.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale(out)
    tmp = out.with_name(f".{out.name}.partial-{os.getpid()}")
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir()
    try:
        _write(tmp, dirs, convention=convention, common=common, with_paper=with_paper, top=top, dataroot=dataroot, pictures=pictures,
               frames=frames, case_tags=case_tags, pairwise=pairwise, resampling=resampling, svg=svg, progress=progress,
               version=version, safety=safety)
        marker = {"written_by": "lightemma report", "files": _report_files(tmp)}  # what a re-report may replace
        (tmp / REPORT_MARKER).write_text(json.dumps(marker) + "\n", encoding="utf-8")
        _check_target(out, force)  # again: files added to the old report while this one was written
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


def _runs_table(evaluation: Evaluation, flags: dict[str, str]) -> Table:
    rows = [{"model": m.label, "family": m.family, "run": str(m.run_dir), "frames": m.frames_in_run, "complete": "yes" if m.complete else "no",
             "integrator": m.integrator, "chain": m.chain, "answer_format": m.answer_format, "inputs": m.inputs} for m in evaluation.models]
    columns = [Column("model", "Model"), Column("family", "Family"), Column("run", "Run"), Column("frames", "Frames"), Column("complete", "Finished"),
               Column("integrator", "Integrator"), Column("chain", "Chain"), Column("answer_format", "Answer format"), Column("inputs", "Inputs")]
    return Table("Runs", columns, rows, name="runs", flags=flags)


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

    from lightemma.evaluation.scenarios import CASE_TAGS, disagreements, history_bias, per_tag_metrics, worst_frame_per_tag
    from lightemma.report.evaluation_tables import coverage_flags
    from lightemma.report.figures import bubble_chart, bubble_points, history_bias_figure, model_colors, pairwise_figure
    from lightemma.report.html import write_html
    from lightemma.report.pictures import CameraSource

    dirs = expand_run_dirs(run_dirs)
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
    evaluation: Evaluation = evaluate_loaded(runs, convention=convention, common=common, resampling=resampling, pairwise=pairwise and len(runs) > 1,
                                             safety=safety, dataroot=dataroot if version else None, version=version)
    evaluation.warnings[:0] = skipped
    steps.step("evaluated")
    order = {m.run_dir: i for i, m in enumerate(evaluation.models)}
    runs.sort(key=lambda r: order[r.info.run_dir])
    labels = unique_labels(runs)
    colors = model_colors(evaluation.models)
    flags = coverage_flags(evaluation)
    w = _Writer(out, svg=svg)
    w.lines += ["# lightemma report", "", "Browse it: [index.html](index.html) (tables, figures and every frame; opens from disk).", "",
                "| Model | Family | Run | Frames | Finished | Integrator | Chain | Answer format | Inputs |",
                "|---|---|---|---:|---|---|---|---|---|"]
    w.lines += ["| " + " | ".join(markdown_cell(c) for c in (m.label + flags.get(m.label, ""), m.family, f"`{m.run_dir}`", m.frames_in_run,
                                                             "yes" if m.complete else "no", m.integrator, m.chain, m.answer_format, m.inputs)) + " |"
                for m in evaluation.models]  # every cell one line: names from outside cannot split a row
    w.lines.append("")
    if evaluation.warnings:
        w.lines += ["**Warnings**", ""] + [f"- {printable(x)}" for x in evaluation.warnings] + [""]

    if flags:
        w.lines += [f"**Fewer than half of the frames scored** for {printable(', '.join(flags))}: their numbers describe only the frames they managed; every table flags them.", ""]
    w.lines += ["## Tables I and II", ""]
    tables = evaluation_tables(evaluation, with_paper=with_paper)
    for table in tables:
        if table.name in ("pairwise_ade", "generations", "pairwise_safety", *_ABLATION_TABLES):
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

    _ablation_section(w, tables)

    shared = common_frames(runs) if len(runs) > 1 else None
    scope = f"the {len(shared)} frames scored in every run" if shared else "each run's scored frames"
    w.lines += ["## Scenarios", "", f"ADE avg (m) per scenario tag, on {scope}. Tag rules: docs/evaluate.md.", ""]
    steps.step("tables and charts")
    w.table(_scenario_table(per_tag_metrics(runs, convention=main_convention, frame_ids=shared or None, safety=evaluation.safety), labels, flags), latex=False)
    w.lines += ["Case 1 of the paper (a finished turn carried into the prediction), measured over all frames:", ""]
    bias = history_bias(runs)
    w.table(_bias_table(bias, flags), latex=False)
    w.figure(history_bias_figure(runs, colors=colors, rows=bias, notes=flags), "history_bias", "predicted and true future curvature against the last history curvature: Theil–Sen slopes with 95 % intervals, and the carry-over just after a turn")

    picks = [("frame", fid, "requested frame") for fid in frames]
    spread = disagreements(runs, top=top)
    picks += [("disagree", d["frame_id"], f"the {len(d['models'])} models shown disagree by {d['spread_m']:.1f} m at 3 s" + ("" if len(d["models"]) == len(runs) else " (baselines not compared)")) for d in spread]
    picks += [("case", c["frame_id"], f"worst `{c['tag']}` frame (mean FDE {c['mean_fde']:.2f} m of {c['frames_with_tag']} tagged)") for c in worst_frame_per_tag(runs, CASE_TAGS if case_tags is None else case_tags)]
    picks = _merge_picks(picks)
    steps.step("scenario analysis")
    source = CameraSource(dataroot)
    if pictures and picks:
        cameras = source.cameras(runs, [fid for _, fid, _ in picks])
        w.lines += ["## Frames: requested, where models disagree most, and the worst of each failure case", ""]
        w.lines += [f"> {printable(p)}" for p in dict.fromkeys(source.problems)] + ([""] if source.problems else [])
        _frame_pictures(w, runs, labels, picks, cameras, colors, shown={d["frame_id"]: d["models"] for d in spread}, progress=progress)
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
            own[fid] = (r.get("scene_text") or "", r.get("intent_text") or "", r.get("answer") or "")
            if run.info.imported and pictures and fid not in calibrations:
                calibrations[fid] = {k: r.get(k) for k in ("camera_params", "image_name", "image_path")}
    steps.step("stage texts")
    all_ids = list(dict.fromkeys(fid for run in runs for fid in run.frame_ids))
    html_cameras = source.cameras(runs, all_ids, load=False, records=calibrations) if pictures else {}
    intro = "".join(f'<p class="note">{html_escape.escape(printable(x))}</p>' for x in [*evaluation.warnings, *dict.fromkeys(source.problems)])
    write_html(out, title="lightemma report", intro_html=intro, tables=[_runs_table(evaluation, flags), *w.tables], figures=w.figures, runs=runs, labels=labels,
               colors=colors, texts=texts, cameras=html_cameras, progress=progress)
    steps.step("index.html")
    steps.close()
