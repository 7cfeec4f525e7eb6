"""A merged evaluation document (:func:`lightemma.evaluation.merge.merge_documents`) as Markdown, for
``lightemma evaluate --merge … --format markdown``."""

from __future__ import annotations

from typing import Any

from lightemma.report.tables import markdown_cell, markdown_text


def merged_markdown(doc: dict[str, Any]) -> str:
    """A merged document as Markdown: one table per merged table, a column per row key (its descriptor id under the
    table), values as stored (floats to 3 decimals, intervals as ``[low, high]``), then which run used which prompt set
    where they differ, then the files it came from."""

    def cell(value: Any) -> str:
        if value is None:
            return "-"
        if isinstance(value, float):
            return f"{value:.3f}"
        if isinstance(value, list):
            return "[" + ", ".join(cell(v) for v in value) + "]"
        return str(value)

    out = []
    for table in doc["tables"]:
        keys: list[str] = []
        for row in table["rows"]:
            keys.extend(k for k in row if k not in keys)
        lines = [
            f"### {markdown_text(table['title'])}",
            "",
            "| " + " | ".join(markdown_cell(k) for k in keys) + " |",
            "|" + "|".join(["---"] + ["---:"] * (len(keys) - 1)) + "|",
        ]
        lines += ["| " + " | ".join(markdown_cell(cell(row.get(k))) for k in keys) + " |" for row in table["rows"]]
        ids = [f"{k}: {d['id']}" for k, d in doc["columns"][table["name"]].items() if isinstance(d, dict)]
        lines += ["", markdown_text("Columns: " + "; ".join(ids))]
        lines += [markdown_text(n) for n in table.get("notes", [])]
        out.append("\n".join(lines) + "\n")
    prompts: dict[str, list[str]] = {}
    for run in doc["provenance"]["runs"]:
        prompt = run.get("prompt_set") or {}
        key = f"{prompt.get('name')} ({str(prompt.get('hash'))[:19]})" if prompt else "unrecorded"
        prompts.setdefault(key, []).append(str(run.get("model")))
    if len(prompts) > 1:  # marked, as lightemma evaluate marks them
        which = "; ".join(f"{k}: {', '.join(v)}" for k, v in prompts.items())
        out.append(markdown_text(f"Runs differ in prompt sets: {which} (not one protocol).") + "\n")
    fs = next(iter(doc["provenance"]["frame_sets"]))
    sources = "; ".join(
        f"{m['file']} (lightemma {m['lightemma_version']}: {', '.join(map(str, m['models']))})"
        for m in doc["merged_from"]
    )
    out.append(markdown_text(f"Merged on frame set {fs} from {sources}") + "\n")
    return "\n".join(out)
