"""A robustness sweep: one model over the same frames under several input variants (docs/run.md#sweeps).

A variant is ``clean`` (the paper's inputs, ``--inputs full`` of a run) or any ``--inputs`` of :mod:`lightemma.inputs`
(``no-image``, ``blank-image``, ``no-history``, ``corrupt:NAME@SEVERITY``, ``history-noise@SIGMA[,SIGMA_K]``,
``history-stale@K``). :func:`sweep` runs each variant as an ordinary run through the public :func:`lightemma.run`
(``lightemma.resume`` for one that was cut off), each in its own folder::

    OUT/sweep.json                                  the sweep manifest (written atomically after every change)
    OUT/<variant folder>/<model>/<run_id>/          one run directory per variant (clean, corrupt-fog-3, …)

The frames are loaded once and every run gets the same ones (the same ``--sample`` / ``--limit`` of the same set). The
sweep manifest records the model, the variants (each with its run directory and status), the frame set (the request
and a SHA-256 of its sorted frame ids), the settings that decide what is asked, and the cost estimate. Running the
same sweep again resumes the unfinished variants and skips the finished ones; a different model, variant list, frame
set or setting is refused in one line (start a new sweep in another folder).

Cost: for a paid API model one estimate for the whole sweep comes first (the sum of each unfinished variant's
estimate on its frames still to run, :func:`lightemma.pipeline.runner.estimate_run`); ``max_cost_cents`` bounds the
whole sweep: when the sweep is estimated above it (each call admitted as a run admits it, records already spent
included) nothing is run; else each variant's run gets the limit less what the other variants have spent, so the
sweep's total never exceeds it.
"""

from __future__ import annotations

import hashlib
import os
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from lightemma.backends import backend_kind
from lightemma.errors import RunStopped, UserError
from lightemma.frames.sample import sample_frames
from lightemma.inputs import check_inputs, history_noise
from lightemma.models.catalog import resolve
from lightemma.nuscenes import load_frames
from lightemma.pipeline.estimate import no_bill
from lightemma.pipeline.runner import estimate_run, resume
from lightemma.prompts import DEFAULT_PROMPT_SET
from lightemma.runs.store import find_run_dirs, read_manifest, read_run

SWEEP_FILE = "sweep.json"
SWEEP_FORMAT = "lightemma-sweep/1"
CLEAN = "clean"  # the variant of the paper's inputs (a run's --inputs full)
#: run() keywords that decide what is asked: recorded in the sweep manifest and equal on every re-run
ASKED = (
    "backend",
    "temperature",
    "max_tokens",
    "reask",
    "max_attempts",
    "integrate_method",
    "speed_range",
    "max_abs_curvature",
    "chain",
    "answer_format",
    "prompt_set",
    "transport",
    "price",
    "batch",
    "max_retries",
    "backoff_base",
)
#: run()/resume() keywords of where and how fast it runs: they may change from one session to the next
SESSION = ("concurrency", "timeout", "rpm", "tpm")

Log = Callable[[str], None]


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def _canonical(variant: str) -> str:
    """One spelling per variant: ``full`` is ``clean``; a history noise's numbers as Python's shortest repr."""
    if variant in (CLEAN, "full"):
        return CLEAN
    try:
        check_inputs(variant)
        noise = history_noise(variant)
    except ValueError as exc:
        raise UserError(f"--inputs: variant {variant!r}: {str(exc).removeprefix(f'--inputs {variant}: ')}") from None
    if noise is not None:
        speed, curvature = noise
        return f"history-noise@{speed:g}" + (f",{curvature:g}" if curvature else "")
    return variant


def parse_variants(spec: str | Sequence[str], *, require_clean: bool = True) -> list[str]:
    """The variants of ``spec`` (a comma-separated list, or a sequence), canonical, in the order given.

    ``clean`` (or ``full``) is the paper's inputs; every other variant is an ``--inputs`` value of
    :mod:`lightemma.inputs`. A comma inside ``history-noise@SIGMA,SIGMA_K`` belongs to its variant (a piece that is a
    plain number after a ``history-noise@…`` joins it). Raises a one-line :class:`~lightemma.errors.UserError` for an
    empty list, an unknown or malformed variant, a variant given twice (``clean`` and ``full`` are one), or, with
    ``require_clean``, no clean variant (the paired table needs one).
    """
    if isinstance(spec, str):
        pieces: list[str] = []
        for piece in (p.strip() for p in spec.split(",")):
            if (
                pieces
                and pieces[-1].startswith("history-noise@")
                and "," not in pieces[-1]
                and re.fullmatch(r"\d+(?:\.\d*)?|\.\d+", piece)
            ):
                pieces[-1] += "," + piece
            else:
                pieces.append(piece)
    else:
        pieces = [str(p).strip() for p in spec]
    if not pieces or pieces == [""]:
        raise UserError("--inputs: no variant given (e.g. --inputs clean,corrupt:fog@3,no-image)")
    variants: list[str] = []
    for piece in pieces:
        if not piece:
            raise UserError(f"--inputs {','.join(pieces)}: an empty variant (two commas in a row, or a trailing comma)")
        variant = _canonical(piece)
        if variant in variants:
            same = "" if variant == piece else f" (as {variant})"
            raise UserError(f"--inputs: variant {piece!r}{same} is given twice; each variant runs once")
        variants.append(variant)
    if require_clean and CLEAN not in variants:
        raise UserError(
            "--inputs: no clean variant; the robustness table pairs every variant with the clean run on the "
            "same frames: add clean to the list"
        )
    return variants


def variant_inputs(variant: str) -> str:
    """The run's ``inputs`` of a (canonical) variant: ``full`` for ``clean``, else the variant itself."""
    return "full" if variant == CLEAN else variant


def variant_folder(variant: str) -> str:
    """The folder of a variant's run under the sweep: ``clean``, ``corrupt-fog-3``, ``history-noise-0.5-0.01``."""
    return re.sub(r"[^A-Za-z0-9.]+", "-", variant).strip("-")


def frame_set_id(frame_ids: Sequence[str]) -> str:
    """SHA-256 (hex, first 16 digits) of the sorted frame ids, one a line: which frames a sweep runs."""
    return hashlib.sha256("\n".join(sorted(frame_ids)).encode("utf-8")).hexdigest()[:16]


@dataclass
class SweepResult:
    """What :func:`sweep` did: the sweep folder, its manifest, and per variant the run of this session (None where the
    variant was finished before and skipped)."""

    sweep_dir: Path
    manifest: dict[str, Any]
    runs: dict[str, Any] = field(default_factory=dict)  # variant -> RunResult | None

    def report(self) -> str:
        """One line per variant: its status, valid frames and run directory; then how to evaluate the sweep."""
        lines = [
            f"sweep {self.sweep_dir}: {self.manifest['model']}, {len(self.manifest['variants'])} variant(s) over "
            f"{self.manifest['frame_set']['n_frames']} frame(s)"
        ]
        for entry in self.manifest["variants"]:
            summary = entry.get("summary") or {}
            frames = f"{summary.get('ade_frames', 0)}/{summary.get('frames', 0)} frames scored" if summary else "-"
            when = (
                "skipped (finished before)"
                if entry["variant"] in self.runs and self.runs[entry["variant"]] is None
                else entry["status"]
            )
            lines.append(f"  {entry['variant']:<28} {when:<26} {frames:<22} {entry.get('run_dir') or '-'}")
        lines.append(
            f"evaluate it: lightemma evaluate {self.sweep_dir}   "
            f"(report: lightemma report {self.sweep_dir} --out REPORT)"
        )
        return "\n".join(lines)


def _load(dataset: Mapping[str, Any], frames: Sequence[Any] | None) -> tuple[Sequence[Any], Sequence[Any]]:
    """(every frame of the set, the frames the sweep runs: its --sample / --limit of them), loaded once."""
    loaded: Any = frames
    if loaded is None:
        loaded = load_frames(
            dataset["dataroot"],
            dataset["version"],
            split=dataset["split"],
            scenes=dataset["scenes"],
            window=dataset["window"],
            on_bad_record=dataset["on_bad_record"],
        )
    sample, limit = dataset.get("sample"), dataset.get("limit")
    if sample is not None and limit is not None:
        raise UserError(
            "--sample and --limit are exclusive: --limit takes the first N frames, --sample N spreads N over the scenes"
        )
    if sample is not None:
        if sample["n"] < 1 or sample["n"] > len(loaded):
            raise UserError(f"--sample {sample['n']} must be between 1 and the {len(loaded)} frames of the set")
        chosen = sample_frames(loaded, sample["n"], sample["seed"])
    elif limit is not None:
        if limit < 1:
            raise UserError(f"--limit must be at least 1, got {limit}")
        chosen = loaded.head(limit) if hasattr(loaded, "head") else list(loaded)[:limit]
    else:
        chosen = loaded
    if not len(chosen):
        raise UserError("no frames to run; choose other scenes (--split, --scenes) or --window full")
    return loaded, chosen


def read_sweep(sweep_dir: str | os.PathLike[str]) -> dict[str, Any] | None:
    """The sweep manifest of ``sweep_dir`` (None when the folder has none); a one-line UserError when unreadable."""
    import json

    path = Path(sweep_dir) / SWEEP_FILE
    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UserError(f"{path}: not a readable sweep manifest ({exc})") from None
    if (
        not isinstance(doc, dict)
        or doc.get("format") != SWEEP_FORMAT
        or not isinstance(doc.get("variants"), list)
        or not all(isinstance(v, dict) and isinstance(v.get("variant"), str) for v in doc["variants"])
    ):
        raise UserError(
            f"{path}: not a {SWEEP_FORMAT} sweep manifest (written by another lightemma version, or edited)"
        )
    return doc


def _write(sweep_dir: Path, manifest: dict[str, Any]) -> None:
    from lightemma.runs.store import write_json_atomic

    manifest["updated_at"] = _now()
    write_json_atomic(sweep_dir / SWEEP_FILE, manifest)


def _variant_run(sweep_dir: Path, variant: str, model: str) -> Path | None:
    """The run directory of ``variant`` under the sweep (None when it has none yet); refused when there are two, or
    when the one there is not this model's run of this variant."""
    folder = sweep_dir / variant_folder(variant)
    if not folder.is_dir():
        return None
    found = find_run_dirs(folder)
    if not found:
        return None
    if len(found) > 1:
        raise UserError(
            f"{folder} holds {len(found)} runs of variant {variant}; a sweep keeps one per variant (remove the "
            "extra one, or start a new sweep)"
        )
    config = read_manifest(found[0]).get("config") or {}
    if config.get("model") != model or config.get("inputs", "full") != variant_inputs(variant):
        raise UserError(
            f"{found[0]}: not a run of {model} with --inputs {variant_inputs(variant)} (it has "
            f"{config.get('model')!r}, {config.get('inputs')!r}); the sweep's folder was changed: start a new sweep"
        )
    return found[0]


def _finished(run_dir: Path) -> bool:
    """The run finished its last session without a stop (every frame has its record)."""
    manifest = read_manifest(run_dir)
    sessions = manifest.get("sessions") or []
    last = sessions[-1] if sessions and isinstance(sessions[-1], dict) else {}
    return bool(manifest.get("finished_at")) and not last.get("stopped") and not last.get("interrupted")


def _spent(run_dir: Path | None) -> float:
    """US cents a run's records say were spent (0 without a run)."""
    if run_dir is None:
        return 0.0

    return sum(float(r.get("cost_cents") or 0.0) for r in read_run(run_dir).records.values())


def _done_ids(run_dir: Path | None) -> set[str]:
    if run_dir is None:
        return set()

    return set(read_run(run_dir).records)


def estimate_sweep(
    model: str,
    variants: Sequence[str],
    todo: Mapping[str, Sequence[Any]],
    *,
    options: Mapping[str, Any],
    api_base: str | None,
) -> list[tuple[str, Any]]:
    """Per variant the :class:`~lightemma.pipeline.estimate.Estimate` of its frames still to run (``todo``); nothing is
    called. Only for a paid API model (the caller checks the backend kind)."""
    out = []
    for variant in variants:
        frames = todo[variant]
        if not len(frames):
            out.append((variant, None))
            continue
        out.append(
            (
                variant,
                estimate_run(
                    model,
                    frames=frames,
                    prompt_set=options.get("prompt_set", _default_prompt_set()),
                    chain=options.get("chain", "independent"),
                    answer_format=options.get("answer_format", "text"),
                    inputs=variant_inputs(variant),
                    max_tokens=options.get("max_tokens", 512),
                    api_base=api_base,
                    backend=options.get("backend"),
                    price=options.get("price"),
                ),
            )
        )
    return out


def _default_prompt_set() -> str:
    return DEFAULT_PROMPT_SET


def _money(cents: float | None) -> str:
    return "unknown" if cents is None else f"~${cents / 100:,.2f}"


def _sum(values: Sequence[float | None]) -> float | None:
    return None if any(v is None for v in values) else float(sum(v for v in values if v is not None))


def sweep_estimate_lines(
    estimates: Sequence[tuple[str, Any]], *, batch: bool = False
) -> tuple[list[str], float | None]:
    """The estimate's lines (one per variant, then the sweep's total) and the total US cents admitted by ``--max-cost``
    (each call at the estimate, or its upper bound where the image tokens are unknown; None where unbounded)."""
    lines, admitted = [], []
    for variant, est in estimates:
        if est is None:
            lines.append(f"  {variant}: finished, nothing to run")
            continue
        lines.append(f"  {variant}: {est.line().removeprefix('estimate: ')}")
        per_call = est.admitted_cents_per_call(batch)
        admitted.append(None if per_call is None else per_call * est.calls)
    live = [e for _, e in estimates if e is not None]
    frames, calls = sum(e.frames for e in live), sum(e.calls for e in live)
    normal, batched = _sum([e.cost_cents for e in live]), _sum([e.batch_cost_cents for e in live])
    head = (
        f"sweep estimate: {len(live)} variant(s) to run, {frames:,} frame runs, {calls:,} calls: {_money(normal)} "
        f"normal, {_money(batched)} with --batch (the sum of the variants below)"
    )
    return [head, *lines], _sum(admitted)


def sweep(
    model: str,
    *,
    inputs: str | Sequence[str],
    out: str | os.PathLike[str],
    dataroot: str | os.PathLike[str] | None = None,
    version: str = "v1.0-test",
    split: str | None = None,
    scenes: Sequence[str] | None = None,
    window: str = "reference",
    limit: int | None = None,
    sample: int | None = None,
    sample_seed: int = 0,
    on_bad_record: str = "skip",
    frames: Sequence[Any] | None = None,
    api_base: str | None = None,
    api_key_env: str | None = None,
    cache: str | bool | None = None,
    max_cost_cents: float | None = None,
    estimate_only: bool = False,
    progress: bool = True,
    log: Log | None = None,
    **options: Any,
) -> SweepResult:
    """Run ``model`` over one frame set under each variant of ``inputs`` (see the module docstring); resumable.

    ``inputs``: variants as :func:`parse_variants` reads them (must hold ``clean``). ``out``: the sweep folder (new,
    empty, or an earlier sweep of the same model, variants, frame set and settings, which is resumed). Frames come from
    ``dataroot`` / ``version`` / ``split`` / ``scenes`` / ``window`` with ``limit`` or ``sample`` / ``sample_seed``
    (as :func:`lightemma.run`), or from ``frames`` in memory (the same must be given to resume). ``options``: further
    keywords of :func:`lightemma.run` (:data:`ASKED`, recorded and compared on a re-run; :data:`SESSION`, free).
    ``cache=True`` keeps one response cache for every variant at ``OUT/cache.sqlite``. ``max_cost_cents``: the whole
    sweep's limit (US cents). ``estimate_only``: return after the estimate (``SweepResult.manifest['estimate']``),
    nothing written.

    Raises a one-line :class:`~lightemma.errors.UserError` before anything is sent or written for bad input (an
    unknown or repeated variant, no clean variant, a baseline model, a sweep folder of another sweep, a changed variant
    list, frame set or setting, an estimate above ``max_cost_cents``); a variant's run that stops raises its
    :class:`~lightemma.errors.RunStopped` once the sweep manifest records it (running the sweep again continues).
    """
    unknown = sorted(set(options) - set(ASKED) - set(SESSION) - {"gpus", "backend_options", "batch_poll"})
    if unknown:
        raise UserError(
            f"sweep() takes no keyword {unknown[0]!r}; run keywords it passes on: {', '.join((*ASKED, *SESSION))}"
        )
    variants = parse_variants(inputs)
    sweep_dir = Path(out)
    resolve(model)  # an unknown baseline is refused as a run refuses it
    kind = backend_kind(model, options.get("backend"), api_base)
    if kind == "baseline":
        raise UserError(
            f"a sweep varies what a model is shown; {model} is a baseline, which reads the frame's numbers "
            "itself and is shown nothing"
        )
    if max_cost_cents is not None and kind != "api":
        raise UserError(
            f"--max-cost bounds a provider's bill; {model} runs through the {kind} backend (no bill): drop --max-cost"
        )
    if max_cost_cents is not None and not (max_cost_cents == max_cost_cents and 0 < max_cost_cents < float("inf")):
        raise UserError(f"--max-cost must be a finite number of cents greater than 0, got {max_cost_cents:g}")
    if frames is None and not dataroot:
        raise UserError("--dataroot is required (a nuScenes directory)")
    dataset: dict[str, Any] = {
        "dataroot": os.fspath(Path(dataroot).resolve()) if frames is None and dataroot else None,
        "version": version if frames is None else None,
        "split": split,
        "scenes": list(scenes) if scenes else None,
        "window": window,
        "limit": limit,
        "sample": {"n": int(sample), "seed": int(sample_seed)} if sample is not None else None,
        "on_bad_record": on_bad_record,
        "in_memory": frames is not None,
    }
    if cache is True:
        cache = os.fspath((sweep_dir / "cache.sqlite").resolve())
    elif cache:
        cache = os.fspath(Path(cache).resolve())
    asked = {k: options[k] for k in ASKED if k in options}
    asked = {k: list(v) if isinstance(v, tuple) else v for k, v in asked.items()}
    asked["cache"] = cache or None
    asked = {k: v for k, v in asked.items() if v is not None}  # a setting not given is the run's default
    existing = read_sweep(sweep_dir)
    if existing is None and sweep_dir.exists() and (not sweep_dir.is_dir() or any(sweep_dir.iterdir())):
        raise UserError(
            f"--out {sweep_dir}: {'not a folder' if not sweep_dir.is_dir() else 'holds files but no ' + SWEEP_FILE}; "
            "give a new or empty folder for a sweep"
        )
    if existing is not None:
        _same_sweep(sweep_dir, existing, model, variants, dataset, asked)
        if max_cost_cents is None:  # the sweep's limit holds until a new one is given
            max_cost_cents = existing.get("max_cost_cents")
    every, chosen = _load(dataset, frames)
    ids = [f.frame_id for f in chosen]
    fsid = frame_set_id(ids)
    if existing is not None and existing["frame_set"].get("id") != fsid:
        raise UserError(
            f"{sweep_dir}: the frames loaded now are not the sweep's frame set "
            f"(sweep {existing['frame_set'].get('id')}, "
            f"{existing['frame_set'].get('n_frames')} frames; now {fsid}, {len(ids)} frames): the dataset "
            "changed since the sweep started; start a new sweep in another folder"
        )
    runs = {v: (_variant_run(sweep_dir, v, model) if existing is not None else None) for v in variants}
    finished = {v for v, d in runs.items() if d is not None and _finished(d)}
    todo: dict[str, list[Any]] = {}
    for v in variants:
        done_ids = set() if v in finished else _done_ids(runs[v])
        todo[v] = [] if v in finished else [f for f in chosen if f.frame_id not in done_ids]
    spent_by = {v: _spent(d) for v, d in runs.items()}  # US cents each variant's run has spent so far
    estimate: dict[str, Any] | None = None
    if kind == "api":
        per_variant = estimate_sweep(model, variants, todo, options=options, api_base=api_base)
        lines, admitted = sweep_estimate_lines(per_variant, batch=bool(options.get("batch")))
        spent = sum(spent_by.values())
        estimate = {
            "lines": lines,
            "admitted_cents": admitted,
            "spent_cents": spent,
            "variants": {v: e.to_dict() if e is not None else None for v, e in per_variant},
        }
        if log and not estimate_only:
            for line in lines:
                log(line)
        if max_cost_cents is not None and not estimate_only:
            if admitted is None:
                raise UserError(
                    f"--max-cost {max_cost_cents:g}: the sweep's spending cannot be bounded (the price or the "
                    f"image tokens of {model} are unknown; see --estimate); nothing was run: drop --max-cost"
                )
            if spent + admitted > max_cost_cents:
                raise UserError(
                    f"--max-cost {max_cost_cents:g}: the sweep is estimated at {admitted:.3f} ¢ to run"
                    + (f" (plus {spent:.3f} ¢ already spent)" if spent else "")
                    + f" over {len([v for v in variants if todo[v]])} variant(s); nothing was run: raise "
                    "--max-cost, or sweep fewer variants or frames (--sample N)"
                )
    else:
        estimate = {"lines": [no_bill(model, kind, len(ids) * len(variants))]}
        if log and not estimate_only:
            log(estimate["lines"][0])
    manifest: dict[str, Any] = existing or {
        "format": SWEEP_FORMAT,
        "model": model,
        "created_at": _now(),
        "variants": [
            {
                "variant": v,
                "inputs": variant_inputs(v),
                "folder": variant_folder(v),
                "run_dir": None,
                "status": "pending",
            }
            for v in variants
        ],
        "dataset": dataset,
        "frame_set": {"id": fsid, "n_frames": len(ids), "rule": "sha256 of the sorted frame ids"},
        "settings": asked,
        "max_cost_cents": max_cost_cents,
    }
    manifest["estimate"] = estimate
    if estimate_only:
        return SweepResult(sweep_dir, manifest)
    if max_cost_cents is not None:
        manifest["max_cost_cents"] = max_cost_cents
    created = existing is None  # a refusal before the sweep's first run leaves nothing of it behind
    sweep_dir.mkdir(parents=True, exist_ok=True)
    manifest["finished_at"] = None
    _write(sweep_dir, manifest)
    result = SweepResult(sweep_dir, manifest)
    by_variant = {e["variant"]: e for e in manifest["variants"]}
    session = {k: options[k] for k in SESSION if options.get(k) is not None}
    for variant in variants:
        entry = by_variant[variant]
        run_dir = runs[variant] or _variant_run(sweep_dir, variant, model)
        if variant in finished:
            entry.update(status="finished", run_dir=_rel(sweep_dir, run_dir))
            result.runs[variant] = None
            continue
        limit_v = None
        if max_cost_cents is not None:
            others = sum(spent for v, spent in spent_by.items() if v != variant)
            limit_v = max_cost_cents - others
            if limit_v <= 0:
                entry["status"] = "stopped"
                _write(sweep_dir, manifest)
                raise UserError(
                    f"--max-cost {max_cost_cents:g}: the sweep's other variants spent {others:.3f} ¢, nothing is "
                    f"left for {variant}; raise --max-cost and run the sweep again to finish it"
                )
        if log:
            log(
                f"variant {variant} ({variants.index(variant) + 1}/{len(variants)}): "
                + (f"resuming {run_dir}" if run_dir is not None else "new run")
            )
        entry["status"] = "running"
        _write(sweep_dir, manifest)
        try:
            if run_dir is not None:
                done = resume(
                    run_dir,
                    frames=every,
                    api_base=api_base,
                    api_key_env=api_key_env,
                    cache=cache or None,
                    max_cost_cents=limit_v,
                    progress=progress,
                    log=log,
                    backend_options=_trusted_options(options),
                    **session,
                )
            else:
                from lightemma.pipeline import run

                run_kw: dict[str, Any] = {
                    k: (tuple(v) if k in ("speed_range", "price") and isinstance(v, list) else v)
                    for k, v in options.items()
                    if v is not None
                }
                done = run(
                    model,
                    dataroot=dataroot if frames is None else None,
                    version=version,
                    split=split,
                    scenes=scenes,
                    window=window,
                    limit=limit,
                    sample=sample,
                    sample_seed=sample_seed,
                    on_bad_record=on_bad_record,
                    frames=every,
                    output=sweep_dir / variant_folder(variant),
                    inputs=variant_inputs(variant),
                    api_base=api_base,
                    api_key_env=api_key_env,
                    cache=cache or None,
                    max_cost_cents=limit_v,
                    progress=progress,
                    log=log,
                    **run_kw,
                )
        except RunStopped as exc:
            entry.update(status="stopped", run_dir=_rel(sweep_dir, Path(str(exc.run_dir))))
            _write(sweep_dir, manifest)
            if log:
                log(
                    f"variant {variant} stopped (below); after the fix, run the same sweep command again: finished "
                    "variants are skipped, this one is resumed"
                )
            raise
        except BaseException as exc:
            found = _find_quietly(sweep_dir, variant, model)
            if created and isinstance(exc, UserError) and not any(_find_quietly(sweep_dir, v, model) for v in variants):
                _remove_new_sweep(sweep_dir)  # refused before any run existed: as if never started
                raise
            entry.update(status="interrupted" if found is not None else "pending", run_dir=_rel(sweep_dir, found))
            _write(sweep_dir, manifest)
            raise
        spent_by[variant] = _spent(done.run_dir)
        entry.update(
            status="finished",
            run_dir=_rel(sweep_dir, done.run_dir),
            summary={k: done.summary.get(k) for k in ("frames", "ade_frames") if k in done.summary},
        )
        _write(sweep_dir, manifest)
        result.runs[variant] = done
    for entry in manifest["variants"]:  # skipped variants: their summary from their run's manifest
        if "summary" not in entry and entry.get("run_dir"):
            summary = read_manifest(sweep_dir / entry["run_dir"]).get("summary") or {}
            entry["summary"] = {k: summary.get(k) for k in ("frames", "ade_frames") if k in summary}
    manifest["finished_at"] = _now()
    _write(sweep_dir, manifest)
    return result


def _remove_new_sweep(sweep_dir: Path) -> None:
    """Remove the sweep manifest this session wrote and the folders left empty under ``sweep_dir`` (nothing else)."""
    (sweep_dir / SWEEP_FILE).unlink(missing_ok=True)
    for folder in sorted((p for p in sweep_dir.rglob("*") if p.is_dir()), key=lambda p: len(p.parts), reverse=True):
        if not any(folder.iterdir()):
            folder.rmdir()
    if not any(sweep_dir.iterdir()):
        sweep_dir.rmdir()


def _trusted_options(options: Mapping[str, Any]) -> dict[str, Any] | None:
    opts = options.get("backend_options") or {}
    return {"trust_remote_code": True} if opts.get("trust_remote_code") else None


def _find_quietly(sweep_dir: Path, variant: str, model: str) -> Path | None:
    try:
        return _variant_run(sweep_dir, variant, model)
    except (UserError, OSError, ValueError):
        return None


def _rel(sweep_dir: Path, run_dir: Path | None) -> str | None:
    if run_dir is None:
        return None
    try:
        return Path(run_dir).resolve().relative_to(sweep_dir.resolve()).as_posix()
    except ValueError:
        return os.fspath(run_dir)


def _same_sweep(
    sweep_dir: Path,
    existing: Mapping[str, Any],
    model: str,
    variants: list[str],
    dataset: Mapping[str, Any],
    asked: Mapping[str, Any],
) -> None:
    """Refuse, in one line, to continue a sweep with another model, variant list, frame set or setting."""
    where = f"{sweep_dir}: "
    fix = "; run the sweep with its own, or start a new sweep in another folder"
    if existing.get("model") != model:
        raise UserError(f"{where}this sweep is of {existing.get('model')!r}, not {model!r}{fix}")
    before = [v["variant"] for v in existing["variants"]]
    if before != variants:
        raise UserError(
            f"{where}the variants differ from the sweep's (sweep: {','.join(before)}; now: {','.join(variants)}){fix}"
        )
    recorded = existing.get("dataset") or {}
    for key in ("dataroot", "version", "split", "scenes", "window", "limit", "sample", "on_bad_record", "in_memory"):
        if recorded.get(key) != dataset.get(key):
            raise UserError(
                f"{where}the frame set differs from the sweep's ({key}: sweep {recorded.get(key)!r}, now "
                f"{dataset.get(key)!r}){fix}"
            )
    settings = existing.get("settings") or {}
    for key in sorted(set(settings) | set(asked)):
        if settings.get(key) != asked.get(key):
            raise UserError(
                f"{where}the setting {key} differs from the sweep's (sweep {settings.get(key)!r}, now "
                f"{asked.get(key)!r}){fix}"
            )
