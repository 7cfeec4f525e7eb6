"""The resume trust policy: what a run directory's manifest may not choose by itself.

A run directory may come from someone else. Its manifest says how the run was made, but never where requests, keys
or writes go, nor what code runs: those the user gives again when resuming (docs/run.md#resuming), and
:func:`check_trusted` refuses the resume in one line otherwise, before anything is sent, loaded or written.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from lightemma.backends.retry import redact_url
from lightemma.errors import UserError
from lightemma.pipeline.config import DEFAULT_CACHE, RunConfig, short_repr

#: backend options a manifest may carry into a resume by itself: numbers and names that say how the model runs here.
#: Any other (``trust_remote_code``, ``attn_implementation`` — transformers may fetch kernels from the hub —,
#: ``engine_options``, ``runtime_env``, ``vllm``, …) can fetch or run code, so the resume's caller gives it again.
INERT_BACKEND_OPTIONS = frozenset(
    {
        "batch_size",
        "batch_window",
        "max_pixels",
        "dtype",
        "device",
        "device_map",
        "tensor_parallel_size",
        "pipeline_parallel_size",
        "gpu_memory_utilization",
        "max_model_len",
        "seed",
        "enable_prefix_caching",
        "fit_split",
        "folds",
        "max_image_bytes",
        "max_restarts",
        "max_sends",
    }
)


def check_trusted(
    run_dir: Path,
    config: RunConfig,
    api_base: str | None,
    api_key_env: str | None,
    cache: str | bool | None,
    ray_address: str | None = None,
    backend_options: Mapping[str, Any] | None = None,
) -> None:
    """Refuse to resume a run whose manifest would choose where requests, keys or writes go, or what code runs.

    ``config`` is the run's (:meth:`RunConfig.from_manifest`). Its endpoint (``api_base``), its key variable
    (``api_key_env``) and its response cache path must be the ones the user gives now (``--api-base``,
    ``--api-key-env``, ``--cache``); a Ray cluster the run's replicas joined (``ray_address``) is joined
    again only when the user names one (``--ray-address``); and backend options outside
    :data:`INERT_BACKEND_OPTIONS` (``trust_remote_code``, …) hold only when ``backend_options`` gives them
    again, equal (``--trust-remote-code``). Otherwise a one-line :class:`~lightemma.errors.UserError`. Nothing is
    shown or asked.
    """
    recorded = redact_url(config.api.api_base)  # a manifest written before redaction may hold a password
    options = config.local.backend_options  # never an api_key: RunConfig.from_manifest refuses one
    if backend_options is not None and not isinstance(backend_options, Mapping):
        raise UserError(
            f"backend_options must be a mapping of option names to values, got {type(backend_options).__name__}"
        )
    inert = sorted(str(k) for k in (backend_options or {}) if k in INERT_BACKEND_OPTIONS)
    if inert:
        raise UserError(
            f"{run_dir}: a resume takes {', '.join(inert)} from the run's manifest; drop them from backend_options"
        )
    trust = options.get("trust_remote_code")
    if trust is not None and not isinstance(trust, bool):
        raise UserError(
            f"{run_dir}: the manifest's trust_remote_code is {short_repr(trust)}, not true or false; start a new run"
        )

    def active(opts: Mapping[str, Any]) -> dict[str, Any]:  # options that can fetch or run code, unset ones left out
        return {k: v for k, v in opts.items() if k not in INERT_BACKEND_OPTIONS and v is not None and v is not False}

    live, given = active(options), active(backend_options or {})
    differ = sorted(k for k in live.keys() | given.keys() if live.get(k) != given.get(k))
    if differ:
        if differ == ["trust_remote_code"]:
            why = (
                f"this run loaded {short_repr(config.model)} with trust_remote_code (the checkpoint's own Python "
                "code runs); a run directory does not choose what code runs: resume it with --trust-remote-code if "
                "you trust that checkpoint"
                if live.get("trust_remote_code")
                else "this run did not load the model with trust_remote_code; drop --trust-remote-code"
            )
        else:
            shown = ", ".join(
                f"{short_repr(k)}: the run's {short_repr(live[k]) if k in live else '(none)'}, given "
                f"{short_repr(given[k]) if k in given else '(none)'}"
                for k in differ
            )
            why = (
                f"backend options that can fetch or run code differ from the run's ({shown}); a run directory does "
                "not choose what code runs: give the run's own again to resume "
                "(lightemma.resume(..., backend_options={...}))"
            )
        raise UserError(f"{run_dir}: {why}")
    recorded_ray = config.local.ray_address
    if recorded_ray is not None and not (isinstance(recorded_ray, str) and recorded_ray.strip()):
        raise UserError(
            f"{run_dir}: the manifest's ray_address is {short_repr(recorded_ray)}, not an address; start a new run"
        )
    if recorded_ray and not ray_address:
        raise UserError(
            f"{run_dir}: this run's replicas joined the Ray cluster at {short_repr(recorded_ray)}; a run "
            "directory does not choose where the model runs: resume it with --ray-address (that one or "
            "another)"
        )
    if (redact_url(api_base) or None) != (recorded or None):
        if recorded and not api_base:
            why = (
                f"this run was made against an --api-base endpoint ({recorded}); a run directory does not choose "
                "where requests and keys go: resume it with the same --api-base URL"
            )
        elif not recorded:
            why = "this run was not made against an --api-base endpoint; drop --api-base"
        else:
            why = f"the --api-base given is not the run's endpoint ({recorded}); give the run's own, or start a new run"
        raise UserError(f"{run_dir}: {why}")
    if (config.api.api_key_env or None) != (api_key_env or None):
        named = config.api.api_key_env
        why = (
            f"this run sent the key in --api-key-env {named}; resume it with the same --api-key-env"
            if named and not api_key_env
            else "the --api-key-env given is not the run's; give the run's own (or none if it had none)"
        )
        raise UserError(f"{run_dir}: {why}")
    recorded_cache = config.api.cache
    output = run_dir.parent.parent
    if recorded_cache is None:
        if cache:
            raise UserError(f"{run_dir}: this run kept no response cache; drop --cache")
        return
    want = (output / recorded_cache if not os.path.isabs(recorded_cache) else Path(recorded_cache)).resolve()
    if cache is None or cache is False:
        raise UserError(
            f"{run_dir}: this run kept a response cache ({want}), outside the run directory; a run "
            f"directory does not choose where lightemma writes: resume it with --cache {want}"
            + (" (or --cache, the default place)" if recorded_cache == DEFAULT_CACHE else "")
        )
    given_cache = (output / DEFAULT_CACHE if cache is True else Path(cache)).resolve()
    if given_cache != want:
        raise UserError(
            f"{run_dir}: the --cache given ({given_cache}) is not the run's response cache ({want}); give the run's own"
        )
