"""Format evaluation rows as the paper's tables: Markdown, CSV, LaTeX or JSON.

A table is a title, a list of :class:`Column` and rows of dicts (as produced by
:meth:`lightemma.evaluation.Evaluation.accuracy_rows` / ``efficiency_rows``).
Missing values print as ``-`` like the paper's; cells the paper marks as
anomalous get a dagger.
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from lightemma._text import printable
from lightemma.errors import InputError

FORMATS = ("md", "csv", "latex", "json")


def fixed(digits: int) -> Callable[[Any], str]:
    """``digits`` decimals; a huge value (|x| ≥ 1e9) in short scientific notation (``8.33e+305``), never 309 digits."""

    def fmt(value: Any) -> str:
        if value is None or (isinstance(value, float) and not math.isfinite(value)):
            return "-"
        if abs(value) >= 1e9:
            return f"{value:.3g}"
        return f"{value:.{digits}f}"

    return fmt


def _percent(value: Any) -> str:
    return "-" if value is None else f"{100.0 * value:.2f}"


def _text(value: Any) -> str:
    return "-" if value is None else str(value)


@dataclass(frozen=True)
class Column:
    """One table column: row key, header, cell formatter; ``ci`` names a row key holding
    a [low, high] interval printed after the value (``1.07 [0.99, 1.15]``); ``na`` names a row
    key holding why the value is missing, printed as ``n/a (why)`` instead of ``-``."""

    key: str
    header: str
    fmt: Callable[[Any], str] = _text
    ci: str | None = None
    na: str | None = None


def _na_cell(col: Column, row: dict[str, Any], keys: dict[str, str] | None = None) -> str | None:
    """``n/a (why)`` for a missing value whose row says why, else None; with ``keys`` (:func:`na_reasons`) the
    cell is ``n/a`` or ``n/a [k]`` and the reason is said once, in the table's notes (:func:`table_notes`)."""
    if col.na and row.get(col.key) is None and row.get(col.na):
        return f"n/a ({row[col.na]})" if keys is None else "n/a" + keys[str(row[col.na])]
    return None


def na_reasons(table: Table) -> dict[str, str]:
    """Each distinct reason of the table's ``n/a (why)`` cells, in order, mapped to its cell marker: ``""`` when the
    table has one reason (every n/a cell says the same), else ``" [1]"``, ``" [2]"``, …"""
    found = list(
        dict.fromkeys(
            str(row[col.na])
            for row in table.rows
            for col in table.columns
            if col.na and row.get(col.key) is None and row.get(col.na)
        )
    )
    return {why: "" if len(found) == 1 else f" [{k}]" for k, why in enumerate(found, 1)}


def table_notes(table: Table) -> list[str]:
    """The table's notes, then one line per n/a reason (:func:`na_reasons`): a reason is said once per table,
    not in each of its cells."""
    keys = na_reasons(table)
    return [*table.notes, *(f"Every n/a{k} in this table: n/a ({why})." for why, k in keys.items())]


def with_interval(value: Any, interval: Any, fmt: Callable[[Any], str]) -> str:
    """``value [low, high]`` when the interval is two finite numbers, else the value alone."""
    cell = fmt(value)
    if (
        isinstance(interval, (list, tuple))
        and len(interval) == 2
        and all(isinstance(v, (int, float)) and math.isfinite(v) for v in interval)
    ):
        cell += f" [{fmt(interval[0])}, {fmt(interval[1])}]"
    return cell


def coverage_note(scored_pct: float | None) -> str:
    """The flag after the name of a model with fewer than half of its frames scored."""
    return " (no frame scored)" if scored_pct is None else f" (only {scored_pct:.0f} % scored)"


MODEL_KEYS = ("model", "model_a", "model_b", "predecessor", "baseline")  # columns whose cells name a model


#: Table II: "Frames" are the frames accounted (all of the run's, with --common those in every run), as in Table I;
#: Scored + Failed + Implausible + API errors add up to them (evaluation_tables adds "Other unscored" where they do not)
ACCURACY_COLUMNS: tuple[Column, ...] = (
    Column("model", "Model"),
    Column("frames_accounted", "Frames"),
    Column("scored", "Scored"),
    Column("failed", "Failed"),
    Column("implausible", "Implausible"),
    Column("api_errors", "API errors"),
    Column("fe_pct", "FE (%)", fixed(2)),
    Column("fe_corr_pct", "FE corr (%)", fixed(2)),
    Column("ade_1s", "ADE 1s (m)", fixed(2)),
    Column("ade_2s", "ADE 2s (m)", fixed(2)),
    Column("ade_3s", "ADE 3s (m)", fixed(2)),
    Column("ade_avg", "ADE avg (m) [95% CI]", fixed(2), ci="ade_avg_ci95"),
    Column("fde", "FDE (m) [95% CI]", fixed(2), ci="fde_ci95"),
    Column("miss_rate", "Miss (%)", _percent),
    Column("parse", "Parse"),
)

#: off-road and collision beside ADE (docs/definitions.md#safety); values are shares, printed in %
SAFETY_COLUMNS: tuple[Column, ...] = (
    Column("offroad", "Off-road (%) [95% CI]", _percent, ci="offroad_ci95", na="offroad_na"),
    Column("offroad_1s", "Off-road 1s (%)", _percent, na="offroad_na"),
    Column("offroad_2s", "Off-road 2s (%)", _percent, na="offroad_na"),
    Column("offroad_3s", "Off-road 3s (%)", _percent, na="offroad_na"),
    Column("offroad_centre", "Off-road centre (%)", _percent, na="offroad_na"),
    Column("collision_1s", "Col. 1s (%)", _percent, na="collision_na"),
    Column("collision_2s", "Col. 2s (%)", _percent, na="collision_na"),
    Column("collision_3s", "Col. 3s (%)", _percent, na="collision_na"),
    Column("collision", "Collision (%) [95% CI]", _percent, ci="collision_ci95", na="collision_na"),
    Column("collision_vehicle", "Col. vehicles (%)", _percent, na="collision_na"),
    Column("collision_vru", "Col. VRU (%)", _percent, na="collision_na"),
    Column("area_source", "Drivable area"),
)

EFFICIENCY_COLUMNS: tuple[Column, ...] = (
    Column("model", "Model"),
    Column("seconds_per_frame", "Time/frame (s)", fixed(1)),
    Column("cost_cents_per_frame", "Cost/frame (¢)", fixed(2)),
    Column("input_tokens", "Input tokens", fixed(0)),
    Column("cached_pct", "Cached (%)", fixed(1)),
    Column("output_tokens", "Output tokens", fixed(0)),
    Column("gpus", "GPUs"),
    Column("run_wall_seconds", "Run wall (s)", fixed(1)),
    Column("frames_per_second", "Frames/s", fixed(2)),
    Column("frames", "Frames"),
)

#: Table I's extra column when a batch run is among its rows (``lightemma run --batch``)
BATCH_TURNAROUND_COLUMN = Column("batch_turnaround_s", "Batch turnaround (s)", fixed(0))


#: the ``frame_set`` of a split table holding its reference rows (the ground truth's, the paper's), not a frame set's
REFERENCE_FRAME_SET = "reference"


@dataclass
class Table:
    """A titled table of rows."""

    title: str
    columns: Sequence[Column]
    rows: list[dict[str, Any]]
    name: str = "table"  # file stem in reports
    flags: dict[str, str] = field(default_factory=dict)  # model label -> note after its name (cells and headers)
    notes: list[str] = field(default_factory=list)  # lines printed under the table (Markdown) or as comments
    #: the frame set of a table split by frame set (report.evaluation_tables.frame_set_tables): a fingerprint id,
    #: ``unrecorded`` or ``reference`` (the reference rows); None for a table of every run
    frame_set: str | None = None
    frame_set_label: str | None = None  # that frame set in words: id, version, split, window, frame count

    @property
    def stem(self) -> str:
        """The table's file stem: its ``name``, then ``_`` and its frame set (``frames-3f2a…``) when split by frame
        set, so that the parts of a split table never share a file (letters, digits, ``_``, ``-`` only)."""
        if self.frame_set is None:
            return self.name
        return f"{self.name}_{re.sub(r'[^A-Za-z0-9_-]+', '-', self.frame_set)}"

    def headers(self) -> list[str]:
        return [printable(c.header + self.flags.get(c.header, "")) for c in self.columns]  # a header can name a model


def _cells(table: Table, *, split_intervals: bool = False, na_once: bool = False) -> list[list[str]]:
    """Formatted cells; intervals inline (``1.07 [0.99, 1.15]``) or, with ``split_intervals``, in two cells of their own;
    with ``na_once`` an n/a cell leaves its reason to :func:`table_notes` (CSV cells keep theirs: a CSV has no notes)."""
    keys = na_reasons(table) if na_once else None
    out = []
    for row in table.rows:
        marked = set(row.get("anomalous") or ())
        cells = []
        for col in table.columns:
            na = _na_cell(col, row, keys)
            if col.ci and split_intervals:
                interval = row.get(col.ci) or (None, None)
                cells += [na or col.fmt(row.get(col.key)), col.fmt(interval[0]), col.fmt(interval[1])]
                continue
            value = row.get(col.key)
            cell = na or (with_interval(value, row.get(col.ci), col.fmt) if col.ci else col.fmt(value))
            if value is None and col.key in (row.get("not_applicable") or ()):
                cell = "n/a"  # e.g. per-frame latency of a batch run
            if row.get("source") == "diff" and isinstance(value, (int, float)) and value > 0 and cell != "-":
                cell = "+" + cell  # a difference row: signed
            if col.key in MODEL_KEYS and row.get("source") not in ("paper", "diff"):
                cell += table.flags.get(str(value), "")
            if col.key == "model" and row.get("source") == "paper":
                cell += " (paper)"
            if col.key == "model" and row.get("note"):
                cell += f" ({row['note']})"
            if col.key in marked:
                cell += "†"
            cells.append(printable(cell))  # names from outside (model, scene, run): one line, no control character
        out.append(cells)
    return out


_MARKDOWN_ESCAPES = {"&": "&amp;", "<": "&lt;", ">": "&gt;"}


def markdown_text(text: Any) -> str:
    """``text`` as inert Markdown inline text: one line (:func:`~lightemma._text.printable`: control and bidirectional
    characters as visible escapes), ``&``, ``<``, ``>`` as entities (no raw HTML, no autolink) and ``](`` as ``]\\(``
    (no link). Renders as the text itself; for names from outside (models, scenes, runs, frames) in ``index.md``."""
    return "".join(_MARKDOWN_ESCAPES.get(ch, ch) for ch in printable(text)).replace("](", "]\\(")


def markdown_code(text: Any) -> str:
    """``text`` as a Markdown code span (shown as it is: no HTML, no entity, no link is read inside one), one line: its
    fence is one backtick longer than the longest run of backticks in it, so no backtick in the text can end it."""
    text = printable(text)
    runs = [len(r) for r in re.findall("`+", text)]
    fence = "`" * (max(runs, default=0) + 1)
    pad = (
        " "
        if not text or text.startswith("`") or text.endswith("`") or (text.startswith(" ") and text.endswith(" "))
        else ""
    )
    return f"{fence}{pad}{text}{pad}{fence}"


def markdown_cell(text: Any) -> str:
    """``text`` as one Markdown table cell: :func:`markdown_text` with ``|`` escaped, so it cannot split the row."""
    return markdown_text(text).replace("|", "\\|")


def to_markdown(table: Table) -> str:
    """A GitHub-flavoured Markdown table under a ``###`` title; every cell one line of inert text (:func:`markdown_cell`:
    no raw HTML, no link), title and notes too."""
    headers = [markdown_cell(h) for h in table.headers()]
    lines = [
        f"### {markdown_text(table.title)}",
        "",
        "| " + " | ".join(headers) + " |",
        "|" + "|".join(["---"] + ["---:"] * (len(headers) - 1)) + "|",
    ]
    lines += ["| " + " | ".join(markdown_cell(c) for c in cells) + " |" for cells in _cells(table, na_once=True)]
    if table_notes(table):
        lines += [""] + [markdown_text(note) for note in table_notes(table)]
    return "\n".join(lines) + "\n"


def to_csv(table: Table) -> str:
    """CSV with a header row of the column headers (formatted cells); an interval gets two columns of its own (low, high)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    headers = []
    for col, header in zip(table.columns, table.headers()):
        base = header.split(" [")[0]
        headers += [base, f"{base} CI low", f"{base} CI high"] if col.ci else [header]
    writer.writerow(headers)
    writer.writerows(_cells(table, split_intervals=True))
    return buf.getvalue()


_LATEX_ESCAPES = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\^{}",
}


def _latex_escape(text: str) -> str:
    text = "".join(_LATEX_ESCAPES.get(ch, ch) for ch in text)
    return text.replace("¢", r"\textcent{}").replace("†", r"\textsuperscript{$\dagger$}")


def to_latex(table: Table) -> str:
    """A ``tabular`` in the style of the paper (``\\hline`` rules, model column left)."""
    spec = "l" + "c" * (len(table.columns) - 1)
    lines = [
        f"% {printable(table.title)}",
        *(f"% {printable(note)}" for note in table_notes(table)),
        f"\\begin{{tabular}}{{{spec}}}",
        r"\hline",
        " & ".join(_latex_escape(h) for h in table.headers()) + r" \\",
        r"\hline",
    ]
    lines += [" & ".join(_latex_escape(cell) for cell in cells) + r" \\" for cells in _cells(table, na_once=True)]
    lines += [r"\hline", r"\end{tabular}"]
    return "\n".join(lines) + "\n"


def _jsonable(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def to_json(tables: Sequence[Table], extra: dict[str, Any] | None = None) -> str:
    """All tables as one JSON document: raw (unformatted) row values keyed by table name."""
    doc: dict[str, Any] = dict(extra or {})
    doc["tables"] = [
        {
            "name": t.name,
            "title": t.title,
            "rows": [{k: _jsonable(v) for k, v in row.items()} for row in t.rows],
            **({"notes": t.notes} if t.notes else {}),
        }
        for t in tables
    ]
    return json.dumps(doc, indent=2, default=str) + "\n"


def render(tables: Sequence[Table], fmt: str, *, extra: dict[str, Any] | None = None) -> str:
    """Several tables in one format (``md``, ``csv``, ``latex``, ``json``)."""
    if fmt == "json":
        return to_json(tables, extra)
    one = {"md": to_markdown, "csv": lambda t: f"# {printable(t.title)}\n" + to_csv(t), "latex": to_latex}.get(fmt)
    if one is None:
        raise InputError(f"unknown table format {fmt!r} (choose from {', '.join(FORMATS)})")
    return "\n".join(one(t) for t in tables)
