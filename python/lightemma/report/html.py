"""``index.html``: the report as one page that opens from ``file://`` — sortable tables and a frame browser.

Layout inside the report folder::

    index.html              tables (sortable), figures, the frame browser; CSS and JS inline
    html/data.js            every frame: ground truth, each model's trajectory, ADE/FDE, failure kind,
                            time, tokens, cost; scenario tags, scene, cross-model spread
    html/texts/<k>.js       stage texts, answers and projected trajectories of frames k·64 … k·64+63,
                            loaded when a frame view opens (never at start-up)
    html/images/<i>.jpg     camera thumbnails (480 px wide), only where a camera image was found

Nothing is fetched from a server or a CDN: data files are plain ``<script>`` files (browsers allow
those from ``file://``, unlike ``fetch``). Tables are built from :class:`~lightemma.report.tables.Table`
objects — a new column in a table needs no change here. Per-frame ADE / FDE are the mean and final
L2 distance over the six waypoints (docs/definitions.md#metrics, the ``lightemma`` convention).
"""

from __future__ import annotations

import html
import json
import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lightemma._text import printable
from lightemma.definitions import OUTCOMES
from lightemma.evaluation.loading import RunData
from lightemma.evaluation.scenarios import TAGS, tag_frames
from lightemma.report.figures.projection import densify, project
from lightemma.report.tables import MODEL_KEYS, REFERENCE_FRAME_SET, Table, _cells, table_notes

TEXT_CHUNK = 64  # frames per html/texts/<k>.js file
THUMB_WIDTH = 480  # px: camera thumbnails (the frame view scales them up)
ERROR_BANDS = ((0.0, 1.0, "< 1 m"), (1.0, 2.0, "1–2 m"), (2.0, 4.0, "2–4 m"), (4.0, math.inf, "≥ 4 m"))
ASSETS = Path(__file__).with_name("assets")


def _round(values: np.ndarray, digits: int) -> list[Any]:
    """A flat list of numbers rounded to ``digits``, None for NaN (JSON has no NaN)."""
    flat = np.round(np.asarray(values, dtype=np.float64).ravel(), digits)
    return [None if not math.isfinite(v) else (int(v) if digits == 0 else float(v)) for v in flat.tolist()]


def _script(call: str, payload: Any) -> str:
    """``call(payload);`` as JavaScript; ``</`` escaped so that no text can close a script element."""
    text = json.dumps(payload, ensure_ascii=False, separators=(",", ":"), allow_nan=False).replace("</", "<\\/")
    return f"{call}({text});\n"


class FrameTable:
    """Every frame of the report's runs in one frame order, with each model's values as (M, N) arrays."""

    def __init__(self, runs: Sequence[RunData], labels: Sequence[str]) -> None:
        order: dict[str, int] = {}
        for run in runs:
            for fid in run.frame_ids:
                order.setdefault(fid, len(order))
        self.frame_ids = list(order)
        n, m = len(self.frame_ids), len(runs)
        self.labels = list(labels)
        self.rows = np.full((m, n), -1, dtype=np.int64)  # row of frame j in run i, -1 when absent
        for i, run in enumerate(runs):
            self.rows[i, [order[f] for f in run.frame_ids]] = np.arange(len(run.frame_ids))
        self.gt = np.full((n, 6, 2), np.nan)
        self.history = np.full((n, 6, 2), np.nan)
        self.scene = [""] * n
        self.pred = np.full((m, n, 6, 2), np.nan)
        self.valid = np.zeros((m, n), dtype=bool)
        self.failure = np.full((m, n), -1, dtype=np.int64)  # -1: not in the run
        self.seconds = np.full((m, n), np.nan)
        self.tokens_in = np.full((m, n), np.nan)
        self.tokens_out = np.full((m, n), np.nan)
        self.cost = np.full((m, n), np.nan)
        for i, run in reversed(list(enumerate(runs))):  # the first run that has a frame gives its truth
            present = self.rows[i] >= 0
            r = self.rows[i, present]
            self.gt[present] = run.gt_positions[r]
            if run.history_actions is not None:
                self.history[present] = run.history_actions[r]
            if run.scene_index is not None and run.scene_names:
                for j, s in zip(np.flatnonzero(present).tolist(), run.scene_index[r].tolist()):
                    self.scene[j] = run.scene_names[s] if 0 <= s < len(run.scene_names) else ""
            self.pred[i, present] = run.trajectory[r]
            self.valid[i, present] = run.valid[r]
            failure = run.failure if run.failure is not None else np.where(run.valid, 0, 1)
            self.failure[i, present] = failure[r]
            self.seconds[i, present] = run.seconds[r]
            self.tokens_in[i, present] = run.input_tokens[r]
            self.tokens_out[i, present] = run.output_tokens[r]
            self.cost[i, present] = run.cost_cents[r]
        self.pred[~self.valid] = np.nan  # an unscored frame shows no path
        with np.errstate(invalid="ignore"):
            dist = np.linalg.norm(self.pred - self.gt[None], axis=-1)  # (M, N, 6)
        self.ade = np.where(self.valid, dist.mean(axis=-1), np.nan)
        self.fde = np.where(self.valid, dist[..., -1], np.nan)
        self.is_baseline = np.array([run.info.family == "Baseline" for run in runs], dtype=bool)

    def __len__(self) -> int:
        return len(self.frame_ids)

    def tags(self) -> np.ndarray:
        """(N,) bit mask of :data:`TAGS` per frame (0 where the frame has no usable history)."""
        usable = np.isfinite(self.gt).all(axis=(1, 2)) & np.isfinite(self.history).all(axis=(1, 2))
        bits = np.zeros(len(self), dtype=np.int64)
        if usable.any():
            masks = tag_frames(self.gt[usable], self.history[usable])
            packed = np.zeros(int(usable.sum()), dtype=np.int64)
            for k, tag in enumerate(TAGS):
                packed |= masks[tag].astype(np.int64) << k
            bits[usable] = packed
        return bits

    def spread(self) -> np.ndarray:
        """(N,) largest distance (m) between two models' 3 s endpoints on a frame both scored; NaN with < 2.

        Baselines are left out when at least two other models are compared (as in
        :func:`lightemma.evaluation.scenarios.disagreements`).
        """
        compared = ~self.is_baseline if (~self.is_baseline).sum() >= 2 else np.ones_like(self.is_baseline)
        ends = self.pred[compared, :, -1]  # (M', N, 2)
        with np.errstate(invalid="ignore"):
            d = np.linalg.norm(ends[:, None] - ends[None, :], axis=-1)  # (M', M', N)
        d = np.where(np.isfinite(d), d, -1.0).max(axis=(0, 1))
        return np.where(d >= 0, d, np.nan)


def safety_flags(ft: FrameTable, safety: Any) -> dict[str, list[list[int | None]]]:
    """Per model and frame, ``collides`` and ``off_road`` (docs/definitions.md#safety: the model's own footprints
    overlap an annotated agent at some step / a footprint corner leaves the drivable area at some step) as 1 or 0;
    None where the frame has no value (not scored, not in the run, no dataroot, or no map / annotations for it).
    ``safety``: the evaluation's :class:`~lightemma.evaluation.safety.SafetyResult`, or None (every value None)."""
    m, n = len(ft.labels), len(ft)
    out: dict[str, list[list[int | None]]] = {key: [[None] * n for _ in range(m)] for key in ("collides", "off_road")}
    if safety is None:
        return out
    index = {fid: j for j, fid in enumerate(ft.frame_ids)}
    for i, label in enumerate(ft.labels):
        rs = safety.runs.get(label)
        if rs is None or rs.model is None:
            continue
        hit = rs.model.collide.any(axis=(1, 2))
        off = rs.model.off_steps.any(axis=1)
        for k, fid in enumerate(rs.frame_ids):
            j = index.get(fid)
            if j is None:
                continue
            if rs.model.coll_ok[k]:
                out["collides"][i][j] = int(hit[k])
            if rs.model.area_ok[k]:
                out["off_road"][i][j] = int(off[k])
    return out


def intent_flags(ft: FrameTable, explanations: Any) -> dict[str, list[list[int | None]]]:
    """Per model and frame, ``contra`` (the stated intent contradicts the model's own plan) and ``contra_gt`` (it
    contradicts what the car did: the ground truth's behaviour) as 1 or 0 (docs/definitions.md#explanation-audit);
    None where there is no verdict (no stage-2 text, a baseline, not in the run, no ground truth).
    ``explanations``: the evaluation's :class:`~lightemma.evaluation.intent_audit.ExplanationResult`, or None."""
    m, n = len(ft.labels), len(ft)
    out: dict[str, list[list[int | None]]] = {key: [[None] * n for _ in range(m)] for key in ("contra", "contra_gt")}
    if explanations is None:
        return out
    index = {fid: j for j, fid in enumerate(ft.frame_ids)}
    for i, label in enumerate(ft.labels):
        audit = explanations.runs.get(label)
        if audit is None:
            continue
        for k, fid in enumerate(audit.frame_ids):
            j = index.get(fid)
            if j is None or not audit.has_text[k]:
                continue
            out["contra"][i][j] = int(audit.verdict[k] == "contradicts")
            if audit.truth_verdict is not None:
                out["contra_gt"][i][j] = int(audit.truth_verdict[k] == "contradicts")
    return out


def intent_entries(ft: FrameTable, explanations: Any) -> dict[int, list[dict[str, Any] | None]]:
    """Per frame index, per model what the frame view shows beside the stage-2 text: the read intent
    (``lon``, ``lat``), the verdict against the plan and its ``reason``, the verdict against the ground truth
    (``truth``, None without one), and the described-objects tags (``objects``); None where the model has no
    stage-2 text for the frame. Only frames some model has an entry for are keys."""
    out: dict[int, list[dict[str, Any] | None]] = {}
    if explanations is None:
        return out
    index = {fid: j for j, fid in enumerate(ft.frame_ids)}
    for i, label in enumerate(ft.labels):
        audit = explanations.runs.get(label)
        if audit is None:
            continue
        objects = getattr(explanations, "objects", {}).get(label)
        tags: dict[str, list[str]] = {}
        if objects is not None:
            for k, fid in enumerate(objects.frame_ids):
                found = [
                    t
                    for t, v in (
                        ("hallucinated pedestrian", objects.check.hallucinated_pedestrian[k]),
                        ("missed pedestrian", objects.check.missed_pedestrian[k]),
                    )
                    if v
                ]
                if found:
                    tags[fid] = found
        for k, fid in enumerate(audit.frame_ids):
            j = index.get(fid)
            if j is None or not audit.has_text[k]:
                continue
            row = out.setdefault(j, [None] * len(ft.labels))
            row[i] = {
                "lon": str(audit.stated_longitudinal[k]),
                "lat": str(audit.stated_lateral[k]),
                "verdict": str(audit.verdict[k]),
                "reason": printable(audit.reason[k]),
                "truth": None if audit.truth_verdict is None else str(audit.truth_verdict[k]),
                "objects": tags.get(fid, []),
            }
    return out


#: the frame view draws every SIM_STRIDE-th re-simulated state of the planning score (0.3 s apart: 11 points)
SIM_STRIDE = 3


def simulated_paths(ft: FrameTable, planning: Any) -> list[list[float | None]] | None:
    """Per model a flat list over frames of the planning score's re-simulated path (docs/definitions.md#planning-score):
    11 points 0.3 s apart from 0 to 3 s, x, y (m) in the keyframe's ego frame; None where the frame was not simulated.
    ``planning``: the evaluation's :class:`~lightemma.evaluation.planning_score.PlanningResult`, or None (then None)."""
    if planning is None:
        return None
    points = 30 // SIM_STRIDE + 1
    out = np.full((len(ft.labels), len(ft), points, 2), np.nan)
    index = {fid: j for j, fid in enumerate(ft.frame_ids)}
    for i, label in enumerate(ft.labels):
        rp = planning.runs.get(label)
        if rp is None or rp.path is None:
            continue
        for k, fid in enumerate(rp.frame_ids):
            j = index.get(fid)
            if j is not None:
                out[i, j] = rp.path[k, ::SIM_STRIDE]
    return [_round(p, 2) for p in out]


def frame_data(
    ft: FrameTable,
    models: Sequence[Mapping[str, Any]],
    images: Mapping[int, str],
    safety: Any = None,
    planning: Any = None,
    explanations: Any = None,
) -> dict[str, Any]:
    """The payload of ``html/data.js``: columns over frames, one list per model for per-model values
    (``collides`` / ``off_road``: :func:`safety_flags`; ``sim``: :func:`simulated_paths`; ``contra`` /
    ``contra_gt``: :func:`intent_flags`)."""
    return {
        **safety_flags(ft, safety),
        **intent_flags(ft, explanations),
        "sim": simulated_paths(ft, planning),
        "models": list(models),
        "tags": list(TAGS),
        "failures": [name or "scored" for name in OUTCOMES],
        "bands": [[lo, None if math.isinf(hi) else hi, name] for lo, hi, name in ERROR_BANDS],
        "chunk": TEXT_CHUNK,
        "ids": [
            printable(fid) for fid in ft.frame_ids
        ],  # shown only: a control or bidirectional character as a visible escape
        "scene": [printable(scene) for scene in ft.scene],
        "tagbits": ft.tags().tolist(),
        "spread": _round(ft.spread(), 2),
        "gt": _round(ft.gt, 2),
        "image": [images.get(j) for j in range(len(ft))],
        "pred": [_round(p, 2) for p in ft.pred],
        "ade": [_round(a, 3) for a in ft.ade],
        "fde": [_round(f, 3) for f in ft.fde],
        "fail": ft.failure.tolist(),
        "seconds": [_round(s, 2) for s in ft.seconds],
        "tok_in": [_round(t, 0) for t in ft.tokens_in],
        "tok_out": [_round(t, 0) for t in ft.tokens_out],
        "cost": [_round(c, 4) for c in ft.cost],
    }


def _sort_key(value: Any) -> Any:
    """The value a column sorts by: the raw number when there is one, else the cell's text."""
    if isinstance(value, bool):
        return int(value)
    if isinstance(value, (int, float)) and math.isfinite(value):
        return value
    return None


def table_html(table: Table, links: Mapping[str, str]) -> str:
    """One :class:`Table` as a sortable HTML table; ``links`` maps a cell's model label or tag to a frame-browser query."""
    numeric = [
        any(_sort_key(row.get(col.key)) is not None for row in table.rows) for col in table.columns
    ]  # right-aligned
    num = ' class="num"'
    head = "".join(
        f'<th scope="col" data-col="{k}"{num if numeric[k] else ""}>{html.escape(h)}</th>'
        for k, h in enumerate(table.headers())
    )
    body = []
    for row, cells in zip(table.rows, _cells(table, na_once=True)):
        tds = []
        for k, (col, cell) in enumerate(zip(table.columns, cells)):
            value = row.get(col.key)
            sort = _sort_key(value)
            attr = ("" if sort is None else f' data-sort="{sort!r}"') + (num if numeric[k] else "")
            text = html.escape(cell)
            target = None
            if row.get("source") not in ("paper", "diff") and (col.key in MODEL_KEYS or col.key == "tag"):
                target = links.get(f"{col.key == 'tag' and 'tag' or 'model'}:{value}")
            if target:
                text = f'<a href="{html.escape(target)}" class="frames-link">{text}</a>'
            tds.append(f"<td{attr}>{text}</td>")
        cls = f' class="{row["source"]}"' if row.get("source") in ("paper", "diff") else ""
        body.append(f"<tr{cls}>" + "".join(tds) + "</tr>")
    notes = "".join(f'<p class="note">{html.escape(printable(n))}</p>' for n in table_notes(table))
    attr, label = "", ""
    if table.frame_set is not None:  # one frame set's part of a table split by frame set: labelled, sorted on its own
        text = printable(table.frame_set_label or table.frame_set)
        text = text if table.frame_set == REFERENCE_FRAME_SET else f"Frame set {text}"
        attr = f' data-frame-set="{html.escape(table.frame_set)}"'
        label = f'<p class="frame-set-label">{html.escape(text)}</p>'
    title = html.escape(printable(table.title))
    return (
        f'<section class="table" id="table-{html.escape(table.stem)}"{attr}>{label}<h3>{title}</h3>'
        f'<div class="scroll"><table class="sortable"><thead><tr>{head}</tr></thead><tbody>{"".join(body)}</tbody></table></div>{notes}</section>'
    )


def tables_html(tables: Sequence[Table], links: Mapping[str, str]) -> str:
    """Every table (:func:`table_html`); the parts of a table split by frame set
    (:func:`lightemma.report.evaluation_tables.frame_set_tables`) side by side in one ``frame-set-groups`` block, each
    part its own labelled group with its own sorting, so no run is ranked against a run of another frame set."""
    out: list[str] = []
    k = 0
    while k < len(tables):
        table = tables[k]
        if table.frame_set is None:
            out.append(table_html(table, links))
            k += 1
            continue
        end = k
        while end < len(tables) and tables[end].name == table.name and tables[end].frame_set is not None:
            end += 1
        parts = "\n".join(table_html(t, links) for t in tables[k:end])
        out.append(f'<div class="frame-set-groups" data-table="{html.escape(table.name)}">{parts}</div>')
        k = end
    return "\n".join(out)


def _projections(camera: Any, trajectories: Sequence[np.ndarray], scale: float) -> list[list[int] | None]:
    """Each trajectory projected into the camera image (pixels of the thumbnail), as a flat [u, v, …] polyline."""
    out: list[list[int] | None] = []
    for traj in trajectories:
        if not np.isfinite(traj).all():
            out.append(None)
            continue
        uv, visible = project(densify(traj, steps=3), camera.intrinsic, camera.extrinsic)
        uv = uv[visible] * scale
        out.append(np.round(uv).astype(int).ravel().tolist() if len(uv) >= 2 else None)
    return out


def write_thumbnail(camera: Any, path: Path) -> tuple[float, list[int]] | None:
    """A JPEG of the camera's image, :data:`THUMB_WIDTH` px wide; returns (scale from image pixels, [width, height]),
    or None when the image cannot be read (missing, unreadable, or over the size cap)."""
    from PIL import Image

    from lightemma.report.figures.frame_view import load_image, open_image

    if camera.image is not None:
        full = Image.fromarray(camera.image)
        width = full.width
        thumb = (
            full.resize((THUMB_WIDTH, max(1, round(full.height * THUMB_WIDTH / full.width))), Image.Resampling.BILINEAR)
            if full.width > THUMB_WIDTH
            else full
        )
    else:
        header = open_image(camera.path)
        if header is None:
            return None
        width = header.width
        header.close()
        pixels = load_image(camera.path, width=THUMB_WIDTH)
        if pixels is None:
            return None
        thumb = Image.fromarray(pixels)
    thumb.save(path, "JPEG", quality=72)
    return thumb.width / width, [thumb.width, thumb.height]


def _progress(items: Sequence[Any], enabled: Any, what: str) -> Any:
    if not enabled or not items:
        return items
    from tqdm import tqdm

    return tqdm(items, desc=what, unit="frame", leave=False)


def write_html(
    out: Path,
    *,
    title: str,
    intro_html: str,
    tables: Sequence[Table],
    figures: Sequence[tuple[str, str]],
    runs: Sequence[RunData],
    labels: Sequence[str],
    colors: Mapping[str, str],
    texts: Mapping[str, Mapping[str, Sequence[str]]],
    cameras: Mapping[str, Any] | None = None,
    progress: bool = False,
    safety: Any = None,
    planning: Any = None,
    explanations: Any = None,
) -> Path:
    """Write ``index.html`` and ``html/`` into ``out`` (see the module docstring); returns the page.

    ``texts`` maps a model label to {frame id: (scene, intent, answer)}; ``cameras``
    maps a frame id to a :class:`~lightemma.report.figures.frame_view.Camera` (or None);
    ``figures`` are (path relative to ``out``, caption) of PNGs already written; ``progress``
    shows a progress bar over the camera thumbnails; ``safety`` (the evaluation's
    :class:`~lightemma.evaluation.safety.SafetyResult`, or None) gives each model's per-frame
    ``collides`` / ``off_road`` flags: a frame-browser filter and columns of the frame view; ``planning`` (the
    evaluation's :class:`~lightemma.evaluation.planning_score.PlanningResult`, or None) the re-simulated path each model's
    plan is scored on, dotted in the frame view's bird's-eye view; ``explanations`` (the evaluation's
    :class:`~lightemma.evaluation.intent_audit.ExplanationResult`, or None) the read intent shown beside each stage-2
    text with its contradiction highlighted, and the frame-browser filter on contradictions (:func:`intent_flags`).
    """
    ft = FrameTable(runs, labels)
    models = [
        {
            "label": printable(lab),
            "color": colors.get(lab, "#444444"),
            "family": run.info.family,
            "baseline": run.info.family == "Baseline",
        }
        for lab, run in zip(labels, runs)
    ]
    data_dir = out / "html"
    (data_dir / "texts").mkdir(parents=True, exist_ok=True)
    images: dict[int, str] = {}
    scales: dict[int, float] = {}
    cameras = cameras or {}
    sizes: dict[int, list[int]] = {}
    with_image = [
        (j, cameras[fid])
        for j, fid in enumerate(ft.frame_ids)
        if cameras.get(fid) is not None and (cameras[fid].image is not None or cameras[fid].path)
    ]
    if with_image:
        (data_dir / "images").mkdir(exist_ok=True)
    for j, camera in _progress(with_image, progress, "camera thumbnails"):
        name = f"html/images/{j}.jpg"
        written = write_thumbnail(camera, out / name)
        if written is not None:
            scales[j], sizes[j] = written
            images[j] = name
    (data_dir / "data.js").write_text(
        _script("LE.data", frame_data(ft, models, images, safety, planning, explanations)), encoding="utf-8"
    )
    intents = intent_entries(ft, explanations)
    for k in range(0, max(1, -(-len(ft) // TEXT_CHUNK))):
        chunk: dict[str, Any] = {}
        for j in range(k * TEXT_CHUNK, min(len(ft), (k + 1) * TEXT_CHUNK)):
            fid = ft.frame_ids[j]
            entry: dict[str, Any] = {"texts": [list(texts.get(lab, {}).get(fid) or ()) or None for lab in labels]}
            if j in intents:
                entry["intent"] = intents[j]
            if j in scales:
                entry["proj"] = _projections(cameras[fid], [ft.gt[j], *ft.pred[:, j]], scales[j])
                entry["size"] = sizes[j]
            chunk[str(j)] = entry
        (data_dir / "texts" / f"{k}.js").write_text(_script("LE.chunk", {"k": k, "frames": chunk}), encoding="utf-8")
    links = {f"model:{lab}": f"#frames?model={i}&sort=worst" for i, lab in enumerate(labels)}
    links.update({f"tag:{tag}": f"#frames?tag={tag}" for tag in TAGS})
    links["tag:all"] = "#frames"
    body_tables = tables_html(tables, links)
    body_figures = "\n".join(
        f'<figure><img src="{html.escape(src)}" alt="{html.escape(cap)}" loading="lazy"><figcaption>{html.escape(cap)}</figcaption></figure>'
        for src, cap in figures
    )
    replacements = {
        "{{title}}": html.escape(title),
        "{{css}}": (ASSETS / "report.css").read_text(encoding="utf-8"),
        "{{js}}": (ASSETS / "report.js").read_text(encoding="utf-8"),
        "{{intro}}": intro_html,
        "{{tables}}": body_tables,
        "{{figures}}": body_figures,
    }
    template = (ASSETS / "report.html").read_text(encoding="utf-8")
    page = re.sub(
        r"\{\{(\w+)\}\}", lambda m: replacements["{{" + m.group(1) + "}}"], template
    )  # one pass: no inserted text is scanned again
    index = out / "index.html"
    index.write_text(page, encoding="utf-8")
    return index
