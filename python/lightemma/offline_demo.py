"""``lightemma demo``: the whole benchmark on a fresh machine, no dataset and no keys needed.

1. writes a small synthetic nuScenes-format dataset (every scenario kind:
   cruising, braking at a red light, starting at green, turns, straight just
   after a turn, …) under ``OUT/data``;
2. runs the baselines (constant, constant velocity, ego status, oracle under Euler
   and midpoint integration) through the ordinary run pipeline into ``OUT/runs``,
   plus, for each API key that is set, one of the paper's models on a few frames,
   with all its inputs and again without the image (``--inputs no-image``);
3. evaluates them and writes the report to ``OUT/report/index.md`` — with the
   "does the model look at the road?" tables (the ablation against the full run,
   each model's gain over the best baseline) when a model ran.

The baselines run on every frame, an API model on its first ``api_limit``. When an API model ran, every model is
scored on the frames scored in every run (``common``, as ``lightemma evaluate --common``), and the demo says so: a
model on 12 frames is never ranked against baselines on 80. Warnings of the runs (the ego baseline's fit on the
demo's few scenes) are passed on as one line each.
"""

from __future__ import annotations

import os
import shutil
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypedDict

import lightemma
from lightemma.errors import UserError


class _RunArgs(TypedDict):
    """The settings every demo run shares (``lightemma.run``'s keywords)."""

    dataroot: Path
    version: str
    split: str
    output: Path
    progress: bool


class _ApiArgs(TypedDict, total=False):
    """The API settings of a demo run of an API model (``lightemma.run``'s keywords)."""

    timeout: float
    max_retries: int
    api_base: str | None


MARKER = ".lightemma-demo"
VERSION = "v1.0-mini"
# (model, integrator) pairs; the oracle twice, to show each integrator's error floor
BASELINE_RUNS: tuple[tuple[str, str], ...] = (
    ("baseline:constant", "euler"),
    ("baseline:cv", "euler"),
    ("baseline:ego", "euler"),
    ("baseline:oracle", "euler"),
    ("baseline:oracle", "midpoint"),
)
# one paper model per provider, run only when its key is in the environment (full inputs, then each of these ablations)
API_ABLATIONS: tuple[str, ...] = ("no-image",)
API_MODELS: tuple[tuple[str, str], ...] = (
    ("OPENAI_API_KEY", "gpt-4o"),
    ("ANTHROPIC_API_KEY", "claude-3.7-sonnet"),
    ("GEMINI_API_KEY", "gemini-2.0-flash"),
)


@dataclass
class DemoResult:
    """Where the demo put things."""

    out: Path
    dataroot: Path
    run_dirs: list[Path]
    index: Path
    skipped: dict[str, str] = field(default_factory=dict)  # paper model -> why it did not run
    common: bool = False  # every model scored on the frames scored in every run (an API model ran)


def _prepare(out: Path) -> None:
    """Create ``out``, or clear the runs and report of an earlier demo there; never anything else."""
    if out.exists() and any(out.iterdir()) and not (out / MARKER).exists():
        raise UserError(f"{out} exists and is not a lightemma demo folder; choose another with --out")
    out.mkdir(parents=True, exist_ok=True)
    (out / MARKER).write_text("written by `lightemma demo`; safe to delete\n", encoding="utf-8")
    for name in ("runs", "report"):
        shutil.rmtree(out / name, ignore_errors=True)


def api_models(environ: os._Environ[str] | dict[str, str] | None = None) -> list[str]:
    """The API models whose key is set (one per provider)."""
    environ = os.environ if environ is None else environ
    return [model for variable, model in API_MODELS if environ.get(variable)]


def skipped_api_models(
    environ: os._Environ[str] | dict[str, str] | None = None, *, use_api: bool = True
) -> dict[str, str]:
    """The paper models the demo will not run, each with the reason (no key, or ``--no-api``)."""
    environ = os.environ if environ is None else environ
    if not use_api:
        return {model: "--no-api" for _, model in API_MODELS}
    return {model: f"no key: set {variable}" for variable, model in API_MODELS if not environ.get(variable)}


def skipped_line(skipped: dict[str, str]) -> str:
    """``skipped paper models: gpt-4o (no key: set OPENAI_API_KEY), …``"""
    return "skipped paper models: " + ", ".join(f"{model} ({why})" for model, why in skipped.items())


def run_demo(
    out: str | os.PathLike[str] = "lightemma-demo",
    *,
    scenes: int | None = None,
    keyframes: int = 24,
    use_api: bool = True,
    api_limit: int = 12,
    api_base: str | None = None,
    log: Callable[[str], None] = print,
) -> DemoResult:
    """Generate data, run baselines (and keyed API models), evaluate, report; see the module docstring.

    ``api_base`` sends the API models to another OpenAI-compatible server.
    """
    if scenes is not None and (isinstance(scenes, bool) or not isinstance(scenes, int) or scenes < 1):
        raise UserError(
            f"scenes must be at least 1 (or None: one per scenario kind), got {scenes!r}",
            cli=f"--scenes must be at least 1, got {scenes!r}",
        )
    if isinstance(api_limit, bool) or not isinstance(api_limit, int) or api_limit < 1:  # 0 would run every frame
        raise UserError(
            f"api_limit must be at least 1 frame, got {api_limit!r}",
            cli=f"--api-limit must be at least 1, got {api_limit!r}",
        )
    out = Path(out).resolve()
    _prepare(out)
    from lightemma.frames.model import SYNTH_MARKER, summary_line
    from lightemma.report import write_report
    from lightemma.synth import KINDS, write_dataset

    scenes = scenes or len(KINDS)
    log(f"1/3 writing a synthetic dataset ({scenes} scenes × {keyframes} keyframes) to {out / 'data'}")
    if (out / "data" / SYNTH_MARKER).is_file():  # an earlier demo's dataset, maybe of other --scenes/--keyframes:
        shutil.rmtree(out / "data")  # write_dataset never rewrites the shared files of another dataset
    dataroot = Path(
        write_dataset(
            out / "data",
            scenes=scenes,
            seed=0,
            version=VERSION,
            keyframes=keyframes,
            images=True,
            sweeps=False,
            overwrite=True,
        )
    )
    common: _RunArgs = {
        "dataroot": dataroot,
        "version": VERSION,
        "split": "all",
        "output": out / "runs",
        "progress": False,
    }
    run_dirs = []
    models = [(m, method, "full") for m, method in BASELINE_RUNS]
    models += [(m, "euler", inputs) for m in api_models() for inputs in ("full", *API_ABLATIONS)] if use_api else []
    skipped = skipped_api_models(use_api=use_api)
    if skipped:
        log(skipped_line(skipped))
    for i, (model, method, inputs) in enumerate(models, start=1):
        limit = api_limit if not model.startswith("baseline:") else None
        shown = "" if inputs == "full" else f", inputs {inputs}"
        log(f"2/3 run {i}/{len(models)}: {model} ({method}{shown})" + (f", first {limit} frames" if limit else ""))
        try:
            # a demo should not wait long
            api: _ApiArgs = {"timeout": 60.0, "max_retries": 2, "api_base": api_base} if limit else {}
            with warnings.catch_warnings(record=True) as caught:  # the run's warnings (the ego baseline's small fit)
                warnings.simplefilter("always", UserWarning)  # the others as the filters in place say
                result = lightemma.run(
                    model,
                    integrate_method=method,
                    limit=limit,
                    concurrency=8 if limit else 32,
                    inputs=inputs,
                    **api,
                    **common,
                )
            for warning in caught:  # one line each; the runner's own warnings are UserWarnings that start "warning: "
                shown = "" if issubclass(warning.category, UserWarning) else f"{warning.category.__name__}: "
                log(f"    {shown}{warning.message}")
        except UserError as exc:
            if model.startswith("baseline:") and model != "baseline:ego":  # the ego baseline's cross-fit needs 3 scenes
                raise
            log(f"    skipped {model}: {exc}")
            skipped[model] = str(exc)
            continue
        log(f"    frames: {summary_line(result.manifest['dataset'])}")
        run_dirs.append(Path(result.run_dir))
    api_ran = any(not model.startswith("baseline:") for model, _, _ in models if model not in skipped)
    if api_ran:
        log(
            f"3/3 evaluating and writing the report to {out / 'report'}: every model is scored on the frames scored in "
            f"every run (the API models ran on the first {api_limit} frames, the baselines on all)"
        )
    else:
        log(f"3/3 evaluating and writing the report to {out / 'report'}")
    try:
        index = write_report([out / "runs"], out / "report", convention="all", common=api_ran, with_paper=True, top=3)
    except UserError as exc:
        if not api_ran or "no frame is valid for every run" not in str(exc):
            raise
        api_ran = False  # the runs share no scored frame: each is scored on its own, and the report's warnings say so
        log(
            "    warning: no frame is scored in every run, so the report scores each model on its own frames, which "
            "differ between the API models and the baselines: do not rank them against each other"
        )
        index = write_report([out / "runs"], out / "report", convention="all", with_paper=True, top=3)
    return DemoResult(out=out, dataroot=dataroot, run_dirs=run_dirs, index=index, skipped=skipped, common=api_ran)
