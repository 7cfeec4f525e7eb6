"""``lightemma evaluate --merge A.json B.json …``: join tables written by earlier ``evaluate --format json`` calls.

A lab keeps a longitudinal leaderboard by merging the JSON of evaluations made on other machines or other days instead
of re-reading every run. Documents are merged only where nothing differs that would make their numbers incomparable
(docs/evaluate.md#merging-evaluations):

* each file is read and checked by :func:`~lightemma.evaluation.descriptors.read_evaluation_json` (its format, its
  frame-set fingerprints, every column's descriptor, every value against its descriptor's range);
* every file covers exactly one frame set, the same one (same fingerprint id), and none was scored with ``--common``
  (its scores are on the frames common to its own runs, a subset that differs from file to file);
* the same tables, in the same order, with the same columns and the same descriptor (id, version, unit, range …) for
  each column; the same miss threshold, parse definition, ``--keep-implausible`` and resampling;
* only per-run tables (efficiency, accuracy, safety, planning, explanations, described objects): paired comparisons,
  generations and ablations compare runs within one file, and the paper's rows (``--with-paper``) are not runs;
* no model label in two files; the reference rows (the ground truth's) are equal in every file.

Anything else raises :class:`~lightemma.errors.UserError` in one line naming both files and the field; the merged
document is built in memory and checked again before anything is written.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from lightemma.errors import UserError
from lightemma.evaluation.descriptors import _software, check_evaluation_json, read_evaluation_json

#: tables whose rows are one per run (plus the ground truth's reference rows): the only ones that can be merged
_PER_RUN = re.compile(r"^(efficiency|accuracy_[a-z0-9]+|safety_[a-z0-9]+|planning|explanations|described_objects)$")
#: top-level keys that must be equal in every merged document
_SAME = ("parse", "keep_implausible", "resampling")


def _fail(a: Path, b: Path | None, field: str, why: str) -> UserError:
    where = f"{a} and {b}" if b is not None else f"{a}"
    return UserError(f"--merge: {where}: {field}: {why}")


def _frame_set(path: Path, doc: dict[str, Any]) -> str:
    frame_sets = doc["provenance"]["frame_sets"]
    runs = doc["provenance"].get("runs")
    if not isinstance(runs, list) or not runs:
        raise _fail(path, None, "provenance.runs", "no runs")
    used = {r.get("frame_set") if isinstance(r, dict) else None for r in runs}
    if None in used or not used <= set(frame_sets):
        raise _fail(
            path, None, "provenance.runs[].frame_set", "a run without a frame set recorded in provenance.frame_sets"
        )
    names = {u for u in used if u is not None}  # all of used: None was ruled out above
    if len(names) != 1:
        raise _fail(
            path,
            None,
            "provenance.frame_sets",
            f"its runs cover {len(names)} frame sets ({', '.join(sorted(names))}); "
            "only evaluations of one frame set merge",
        )
    if doc.get("common"):
        raise _fail(
            path,
            None,
            "common",
            "scored with --common (on the frames common to its own runs); evaluate without --common to merge",
        )
    return next(iter(names))


def _check_tables(path: Path, doc: dict[str, Any]) -> None:
    if "paper" in doc["provenance"]:
        raise _fail(path, None, "provenance.paper", "has the paper's rows (--with-paper); evaluate without it to merge")
    for t, table in enumerate(doc["tables"]):
        if not _PER_RUN.match(str(table["name"])):
            raise _fail(
                path,
                None,
                f"tables[{t}] ({table['name']})",
                "compares runs within this file (paired comparisons, generations, ablations); "
                "evaluate without --pairwise to merge",
            )


def merge_documents(paths: Sequence[str | Path]) -> dict[str, Any]:
    """Read the ``evaluate --format json`` files ``paths`` (two or more) and return one merged document of the same
    format: tables with every file's run rows (in file order, then the reference rows), ``provenance.runs`` of every
    file, ``merged_from`` naming each file with its software and models, warnings prefixed with their file. Raises
    :class:`~lightemma.errors.UserError` (one line, both files and the field) on any mismatch listed in the module's
    docstring; nothing is returned half-merged."""
    if len(paths) < 2:
        raise UserError("--merge: give two or more JSON files written by lightemma evaluate --format json")
    docs = [(Path(p), read_evaluation_json(p)) for p in paths]
    first_path, first = docs[0]
    frame_sets = [_frame_set(path, doc) for path, doc in docs]  # each file on its own first, then one against another
    for path, doc in docs:
        _check_tables(path, doc)
    frame_set = frame_sets[0]
    names = [t["name"] for t in first["tables"]]
    labels: dict[str, Path] = {}
    for path, doc in docs:
        for run in doc["provenance"]["runs"]:
            label = run.get("model")
            if label in labels:
                raise _fail(
                    labels[label],
                    path,
                    "provenance.runs[].model",
                    f"model {label!r} is in both (each run is merged once)",
                )
            labels[label] = path
    for (path, doc), fs in zip(docs[1:], frame_sets[1:]):
        if fs != frame_set:
            raise _fail(first_path, path, "provenance.frame_sets", f"frame set {frame_set} is not {fs}")
        for key in _SAME:
            if doc.get(key) != first.get(key):
                raise _fail(first_path, path, key, f"{first.get(key)!r} is not {doc.get(key)!r}")
        if doc["provenance"]["miss_threshold_m"] != first["provenance"]["miss_threshold_m"]:
            raise _fail(
                first_path,
                path,
                "provenance.miss_threshold_m",
                f"{first['provenance']['miss_threshold_m']!r} is not {doc['provenance']['miss_threshold_m']!r}",
            )
        other = [t["name"] for t in doc["tables"]]
        if other != names:
            raise _fail(first_path, path, "tables", f"tables {', '.join(names)} are not {', '.join(other)}")
        for name in names:
            a, b = first["columns"][name], doc["columns"][name]
            for key in list(a) + [k for k in b if k not in a]:
                if key not in a or key not in b:
                    only = path if key in b else first_path
                    raise _fail(first_path, path, f"columns.{name}.{key}", f"only in {only}")
                if a[key] != b[key]:
                    differs = next(k for k in a[key] if a[key].get(k) != b[key].get(k))
                    raise _fail(
                        first_path,
                        path,
                        f"columns.{name}.{key}.{differs}",
                        f"{a[key].get(differs)!r} is not {b[key].get(differs)!r}",
                    )

    tables = []
    for i, name in enumerate(names):
        run_rows: list[dict[str, Any]] = []
        reference: list[dict[str, Any]] | None = None
        notes: list[str] = []
        for path, doc in docs:
            table = doc["tables"][i]
            models = {r.get("model") for r in doc["provenance"]["runs"]}
            run_rows += [r for r in table["rows"] if r.get("model") in models]
            refs = [r for r in table["rows"] if r.get("model") not in models]
            if reference is None:
                reference = refs
            elif refs != reference:
                raise _fail(
                    first_path,
                    path,
                    f"tables[{i}] ({name}) reference rows",
                    "the ground truth's rows differ (other frames scored or other map / annotations)",
                )
            notes += [n for n in table.get("notes", []) if n not in notes]
        title = first["tables"][i]["title"]
        rows = run_rows + (reference or [])
        tables.append({"name": name, "title": title, "rows": rows, **({"notes": notes} if notes else {})})

    merged: dict[str, Any] = {
        "format": first["format"],
        "provenance": {
            **_software(),
            "frame_sets": {frame_set: first["provenance"]["frame_sets"][frame_set]},
            "runs": [run for _, doc in docs for run in doc["provenance"]["runs"]],
            "miss_threshold_m": first["provenance"]["miss_threshold_m"],
        },
        "columns": first["columns"],
        "common": False,
        "n_common": None,
        **{key: first.get(key) for key in _SAME},
        "warnings": [f"{path}: {w}" for path, doc in docs for w in doc.get("warnings", [])],
        "merged_from": [
            {
                "file": str(path),
                "lightemma_version": doc["provenance"].get("lightemma_version"),
                "git_revision": doc["provenance"].get("git_revision"),
                "models": [r.get("model") for r in doc["provenance"]["runs"]],
            }
            for path, doc in docs
        ],
        "tables": tables,
    }
    return check_evaluation_json(merged, "merged document")
