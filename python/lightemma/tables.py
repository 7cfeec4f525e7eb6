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
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

FORMATS = ("md", "csv", "latex", "json")


def fixed(digits: int) -> Callable[[Any], str]:
    def fmt(value: Any) -> str:
        if value is None or (isinstance(value, float) and not math.isfinite(value)):
            return "-"
        return f"{value:.{digits}f}"

    return fmt


def _percent(value: Any) -> str:
    return "-" if value is None else f"{100.0 * value:.2f}"


def _text(value: Any) -> str:
    return "-" if value is None else str(value)


@dataclass(frozen=True)
class Column:
    """One table column: row key, header, cell formatter."""

    key: str
    header: str
    fmt: Callable[[Any], str] = _text


ACCURACY_COLUMNS: tuple[Column, ...] = (
    Column("model", "Model"),
    Column("frames", "Frames"),
    Column("fe_pct", "FE (%)", fixed(2)),
    Column("fe_corr_pct", "FE corr (%)", fixed(2)),
    Column("api_error_frames", "API errors"),  # frames with no answer received: not format errors
    Column("ade_1s", "ADE 1s (m)", fixed(2)),
    Column("ade_2s", "ADE 2s (m)", fixed(2)),
    Column("ade_3s", "ADE 3s (m)", fixed(2)),
    Column("ade_avg", "ADE avg (m)", fixed(2)),
    Column("fde", "FDE (m)", fixed(2)),
    Column("miss_rate", "Miss (%)", _percent),
)

EFFICIENCY_COLUMNS: tuple[Column, ...] = (
    Column("model", "Model"),
    Column("seconds_per_frame", "Time/frame (s)", fixed(1)),
    Column("cost_cents_per_frame", "Cost/frame (¢)", fixed(2)),
    Column("input_tokens", "Input tokens", fixed(0)),
    Column("output_tokens", "Output tokens", fixed(0)),
    Column("gpus", "GPUs"),
    Column("run_wall_seconds", "Run wall (s)", fixed(1)),
    Column("frames_per_second", "Frames/s", fixed(2)),
    Column("frames", "Frames"),
)


@dataclass
class Table:
    """A titled table of rows."""

    title: str
    columns: Sequence[Column]
    rows: list[dict[str, Any]]
    name: str = "table"  # file stem in reports


def _cells(table: Table) -> list[list[str]]:
    out = []
    for row in table.rows:
        marked = set(row.get("anomalous") or ())
        cells = []
        for col in table.columns:
            cell = col.fmt(row.get(col.key))
            if col.key == "model" and row.get("source") == "paper":
                cell += " (paper)"
            if col.key in marked:
                cell += "†"
            cells.append(cell)
        out.append(cells)
    return out


def to_markdown(table: Table) -> str:
    """A GitHub-flavoured Markdown table under a ``###`` title."""
    headers = [c.header for c in table.columns]
    lines = [f"### {table.title}", "", "| " + " | ".join(headers) + " |", "|" + "|".join(["---"] + ["---:"] * (len(headers) - 1)) + "|"]
    lines += ["| " + " | ".join(cells) + " |" for cells in _cells(table)]
    return "\n".join(lines) + "\n"


def to_csv(table: Table) -> str:
    """CSV with a header row of the column headers (formatted cells)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow([c.header for c in table.columns])
    writer.writerows(_cells(table))
    return buf.getvalue()


_LATEX_ESCAPES = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_", "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\^{}"}


def _latex_escape(text: str) -> str:
    text = "".join(_LATEX_ESCAPES.get(ch, ch) for ch in text)
    return text.replace("¢", r"\textcent{}").replace("†", r"\textsuperscript{$\dagger$}")


def to_latex(table: Table) -> str:
    """A ``tabular`` in the style of the paper (``\\hline`` rules, model column left)."""
    spec = "l" + "c" * (len(table.columns) - 1)
    lines = [f"% {table.title}", f"\\begin{{tabular}}{{{spec}}}", r"\hline", " & ".join(_latex_escape(c.header) for c in table.columns) + r" \\", r"\hline"]
    lines += [" & ".join(_latex_escape(cell) for cell in cells) + r" \\" for cells in _cells(table)]
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
        {"name": t.name, "title": t.title, "rows": [{k: _jsonable(v) for k, v in row.items()} for row in t.rows]} for t in tables
    ]
    return json.dumps(doc, indent=2, default=str) + "\n"


def render(tables: Sequence[Table], fmt: str, *, extra: dict[str, Any] | None = None) -> str:
    """Several tables in one format (``md``, ``csv``, ``latex``, ``json``)."""
    if fmt == "json":
        return to_json(tables, extra)
    one = {"md": to_markdown, "csv": lambda t: f"# {t.title}\n" + to_csv(t), "latex": to_latex}.get(fmt)
    if one is None:
        raise ValueError(f"unknown table format {fmt!r} (choose from {', '.join(FORMATS)})")
    return "\n".join(one(t) for t in tables)
