"""The fingerprint of a frame set: which frames a number was computed on (docs/evaluate.md#what-each-number-is).

A fingerprint is a small JSON object::

    {"format": "lightemma-frames/1", "version": "v1.0-mini", "split": "all", "window": "reference",
     "limit": null, "sample": null, "n_frames": 208, "tokens": "sha256:…", "id": "frames:3f2a…"}

``tokens`` is the SHA-256 of the frames' sample tokens, sorted, one ``<token> <window>\\n`` line each (so the same
samples under another window differ); ``id`` is ``frames:`` and the first 16 hex digits of the SHA-256 of the other
fields as canonical JSON (sorted keys, no spaces), so a fingerprint edited by hand no longer matches its id.
``derived`` (true for runs written before fingerprints, recomputed from their ``frame_ids.txt`` or records, and for
imported runs) and ``from`` are not part of the id.

Every run's manifest records its frame set's fingerprint under ``dataset.fingerprint`` (``lightemma run``,
``lightemma import``); :func:`run_fingerprint` reads it back, checks it against the run's own frame list and derives it
for older runs.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from lightemma.errors import RunStoreError

FINGERPRINT_FORMAT = "lightemma-frames/1"
#: the fields the id covers, in this order (``derived`` and ``from`` are notes, not identity)
FIELDS: tuple[str, ...] = ("format", "version", "split", "window", "limit", "sample", "n_frames", "tokens")
_ID = re.compile(r"frames:[0-9a-f]{16}")
_TOKENS = re.compile(r"sha256:[0-9a-f]{64}")


def sample_token(frame_id: str) -> str:
    """The sample token of a frame id ``<scene name>/<sample token>`` (the part after the last ``/``)."""
    return frame_id.rsplit("/", 1)[-1]


def tokens_hash(frame_ids: Iterable[str], window: str) -> str:
    """``sha256:<hex>`` of the sorted sample tokens of ``frame_ids``, one ``<token> <window>`` line each."""
    tokens = sorted(sample_token(f) for f in frame_ids)
    digest = hashlib.sha256("".join(f"{t} {window}\n" for t in tokens).encode("utf-8")).hexdigest()
    return f"sha256:{digest}"


def _id(fields: Mapping[str, Any]) -> str:
    body = json.dumps({k: fields.get(k) for k in FIELDS}, sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return "frames:" + hashlib.sha256(body.encode("utf-8")).hexdigest()[:16]


def _sample(sample: Any) -> dict[str, int] | None:
    if not isinstance(sample, Mapping):
        return None
    return {"n": int(sample["n"]), "seed": int(sample.get("seed") or 0)}


def fingerprint(
    frame_ids: Iterable[str],
    *,
    version: str | None,
    split: str | None,
    window: str,
    limit: int | None = None,
    sample: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The fingerprint of the frames ``frame_ids`` (``<scene>/<sample token>``) drawn from ``version``/``split`` under
    ``window``, with ``limit`` (the first N) or ``sample`` (``{"n": N, "seed": S}``) when they narrowed it."""
    ids = list(frame_ids)
    out: dict[str, Any] = {
        "format": FINGERPRINT_FORMAT,
        "version": version,
        "split": split,
        "window": window,
        "limit": int(limit) if limit is not None else None,
        "sample": _sample(sample),
        "n_frames": len(ids),
        "tokens": tokens_hash(ids, window),
    }
    out["id"] = _id(out)
    return out


def of_dataset(dataset: Mapping[str, Any], frame_ids: Iterable[str]) -> dict[str, Any]:
    """The fingerprint of a manifest's ``dataset`` block (version, split, window, limit, sample) over ``frame_ids``."""
    return fingerprint(
        frame_ids,
        version=dataset.get("version"),
        split=dataset.get("split"),
        window=dataset.get("window") or "reference",
        limit=dataset.get("limit"),
        sample=dataset.get("sample"),
    )


def check_fingerprint(fp: Any, where: str) -> dict[str, Any]:
    """``fp`` when it is a well-formed fingerprint whose id matches its fields; else a one-line
    :class:`~lightemma.errors.RunStoreError` naming ``where`` and the field (a hand-edited fingerprint, another
    format)."""
    if not isinstance(fp, Mapping):
        raise RunStoreError(f"{where}: not a frame-set fingerprint (an object with {', '.join(FIELDS)}, id)")
    if fp.get("format") != FINGERPRINT_FORMAT:
        raise RunStoreError(
            f"{where}.format: {fp.get('format')!r} is not {FINGERPRINT_FORMAT!r} (another lightemma version)"
        )
    for key in (*FIELDS, "id"):
        if key not in fp:
            raise RunStoreError(f"{where}.{key}: missing")
    if not isinstance(fp["tokens"], str) or not _TOKENS.fullmatch(fp["tokens"]):
        raise RunStoreError(f"{where}.tokens: {fp['tokens']!r} is not sha256:<64 hex digits>")
    if isinstance(fp["n_frames"], bool) or not isinstance(fp["n_frames"], int) or fp["n_frames"] < 0:
        raise RunStoreError(f"{where}.n_frames: {fp['n_frames']!r} is not a count")
    if not isinstance(fp["id"], str) or not _ID.fullmatch(fp["id"]):
        raise RunStoreError(f"{where}.id: {fp['id']!r} is not frames:<16 hex digits>")
    if _id(fp) != fp["id"]:
        raise RunStoreError(
            f"{where}.id: {fp['id']} does not match its fields (they hash to {_id(fp)}: edited by hand?)"
        )
    return dict(fp)


def describe_fingerprint(fp: Mapping[str, Any]) -> str:
    """One line: ``frames:3f2a… (v1.0-mini, split all, reference window, 208 frames, limit 10)``."""
    parts = [
        str(fp.get("version") or "version unknown"),
        f"split {fp['split']}" if fp.get("split") else "named scenes",
        f"{fp.get('window')} window",
        f"{fp.get('n_frames')} frames",
    ]
    if fp.get("limit") is not None:
        parts.append(f"limit {fp['limit']}")
    if fp.get("sample"):
        parts.append(f"sample {fp['sample']['n']} seed {fp['sample']['seed']}")
    if fp.get("derived"):
        parts.append(f"derived from {fp.get('from') or 'the records'}")
    return f"{fp['id']} ({', '.join(parts)})"


def run_fingerprint(run_dir: str | Path, manifest: Mapping[str, Any], recorded_ids: Iterable[str]) -> dict[str, Any]:
    """The frame-set fingerprint of a run: its manifest's ``dataset.fingerprint``, checked, or derived for a run written
    without one (``derived: true``) from its ``frame_ids.txt`` — else, for imported runs and runs without one, from the
    frames it recorded (``recorded_ids``). A recorded fingerprint that does not match its id, the manifest's dataset
    (version, split, window, limit) or the run's ``frame_ids.txt`` is a one-line
    :class:`~lightemma.errors.RunStoreError` naming the file and field."""
    from lightemma.runs.store import FRAME_IDS_FILE, read_frame_ids

    run_dir = Path(run_dir)
    dataset_value = manifest.get("dataset")
    dataset: Mapping[str, Any] = dataset_value if isinstance(dataset_value, Mapping) else {}
    where = f"{run_dir / 'manifest.json'}: dataset.fingerprint"
    listed = read_frame_ids(run_dir)
    if "fingerprint" in dataset:
        fp = check_fingerprint(dataset["fingerprint"], where)
        for key in ("version", "split", "window", "limit"):
            if (
                key in dataset
                and dataset.get(key) != fp.get(key)
                and not (key == "window" and dataset.get(key) is None)
            ):
                raise RunStoreError(f"{where}.{key}: {fp.get(key)!r} disagrees with dataset.{key} {dataset.get(key)!r}")
        if listed is not None:
            window = fp["window"]
            if len(listed) != fp["n_frames"] or tokens_hash(listed, window) != fp["tokens"]:
                raise RunStoreError(
                    f"{where}.tokens: does not match the {len(listed)} frames of {run_dir / FRAME_IDS_FILE} "
                    f"(fingerprint: {fp['n_frames']} frames)"
                )
        return fp
    ids, source = (listed, FRAME_IDS_FILE) if listed is not None else (list(recorded_ids), "frames.jsonl")
    fp = of_dataset(dataset, ids)
    return {**fp, "derived": True, "from": source}
