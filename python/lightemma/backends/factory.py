"""One factory for every backend kind, over one registry of kinds (data: kind → where its class lives).

:func:`create_backend` builds any backend from a model string (the library's call);
:func:`run_backend` builds the one a run's settings name (the runner's call: it turns the
settings into the chosen kind's options, then calls :func:`create_backend`, and shows the
backend's notices). Every class in :data:`KINDS` subclasses :class:`~lightemma.backends.base.Backend`
(``tests/unit/backends/test_backend_interface.py``).

Which kind serves a model (:func:`backend_kind`): an explicit ``backend``, else ``baseline:…``
→ ``baseline``, a registry entry for a local checkpoint → ``hf`` / ``vllm`` (unless an
``api_base`` is given), anything else → ``api``. Then ``batch=True`` turns ``api`` into ``batch``
(the provider's batch interface), and ``replicas`` > 1 or a ``ray_address`` turns ``hf`` /
``vllm`` into ``ray`` (replicas over a Ray cluster).

Classes are imported when first built, so importing this module is cheap, and a missing
optional dependency is reported (naming the extra to install) only when that kind is asked for.
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lightemma.backends.base import Backend
from lightemma.cache import ResponseCache
from lightemma.errors import UserError
from lightemma.models.catalog import lookup

#: the kinds a user chooses with ``--backend`` (``batch`` and ``ray`` follow from ``--batch`` and ``--replicas``)
BACKENDS = ("api", "hf", "vllm", "baseline")


@dataclass(frozen=True)
class BackendKind:
    """Where one kind's class lives: ``module``.``cls``; ``extra`` is the pip extra its dependencies come with
    (``""``: none beyond lightemma's own)."""

    module: str
    cls: str
    extra: str
    what: str


#: every backend kind lightemma builds: kind → its class (imported when first built)
KINDS: dict[str, BackendKind] = {
    "api": BackendKind(
        "lightemma.backends.api",
        "APIBackend",
        "",
        "a model behind a provider's API (litellm or the direct OpenAI-compatible transport)",
    ),
    "batch": BackendKind(
        "lightemma.backends.batch",
        "BatchBackend",
        "",
        "a model behind a provider's batch API (OpenAI, Anthropic, Gemini)",
    ),
    "hf": BackendKind(
        "lightemma.backends.hf", "HFBackend", "hf", "a local checkpoint run by transformers in this process"
    ),
    "vllm": BackendKind(
        "lightemma.backends.vllm", "VLLMBackend", "vllm", "a local checkpoint run by vLLM in this process"
    ),
    "ray": BackendKind(
        "lightemma.backends.ray", "RayBackend", "ray", "replicas of a local checkpoint (hf or vllm) as Ray actors"
    ),
    "baseline": BackendKind(
        "lightemma.backends.baseline",
        "BaselineBackend",
        "",
        "a baseline that answers from the frame itself (constant, cv, oracle, ego)",
    ),
}


def backend_class(kind: str) -> type[Backend]:
    """The class of ``kind`` (a key of :data:`KINDS`), imported now.

    Raises :class:`UserError` (one line) for an unknown kind, and for a kind whose optional dependency is
    missing (naming the extra to install)."""
    spec = KINDS.get(kind)
    if spec is None:
        raise UserError(f"unknown backend kind {kind!r}; the kinds are {', '.join(KINDS)}")
    try:
        cls: type[Backend] = getattr(importlib.import_module(spec.module), spec.cls)
    except ImportError as exc:
        hint = f"; install it with: pip install 'lightemma[{spec.extra}]'" if spec.extra else ""
        raise UserError(f"the {spec.cls} backend is not available ({exc}){hint}") from None
    return cls


def backend_kind(model: str, backend: str | None = None, api_base: str | None = None) -> str:
    """Which of :data:`BACKENDS` serves ``model``: explicit ``backend``, else baseline/api by the model string.

    Registry entries for local checkpoints default to ``hf`` unless an
    ``api_base`` (e.g. a vLLM server) is given, which makes them ``api``.
    """
    if backend is not None:
        if backend not in BACKENDS:
            raise UserError(f"unknown backend {backend!r}; choose one of {', '.join(BACKENDS)}")
        return backend
    if model.strip().lower().startswith("baseline:"):
        return "baseline"

    info = lookup(model)
    if info is not None and info.backend in ("hf", "vllm") and not api_base:
        return info.backend
    return "api"


def local_backend(kind: str, checkpoint: str, **options: Any) -> Backend:
    """A local backend (``kind`` ``hf`` or ``vllm``) for ``checkpoint`` (a hub id or a path), in this process."""
    if kind not in ("hf", "vllm"):
        raise UserError(f"a local backend is hf or vllm, not {kind!r}")
    return _build(kind, checkpoint, **options)


def create_backend(
    model: str,
    *,
    backend: str | None = None,
    api_base: str | None = None,
    replicas: int = 1,
    ray_address: str | None = None,
    gpus_per_replica: float | None = None,
    batch: bool = False,
    **options: Any,
) -> Backend:
    """A ready backend for ``model``, of any kind in :data:`KINDS`. ``options`` go to the backend's constructor.

    For the API backend: ``timeout``, ``retry`` (RetryPolicy), ``rpm``, ``tpm``,
    ``cache`` (ResponseCache), ``api_key_env``, ``price``, ``transport``. A missing API key raises
    :class:`~lightemma.errors.UserError` naming the variable, before any work. ``batch=True`` sends
    the model's calls through its provider's batch interface
    (:class:`~lightemma.backends.batch.BatchBackend`; options ``api_key_env``, ``timeout``,
    ``poll_seconds``, ``price``).

    For ``hf``/``vllm``: ``replicas`` > 1 or a ``ray_address`` runs that many replicas of the model
    as Ray actors (:class:`lightemma.backends.ray.RayBackend`, the ``ray`` extra); ``replicas=1``
    without an address runs the model in this process and needs no Ray. Other backends refuse them,
    as every backend but ``api`` refuses a ``price`` and ``batch``.
    """
    kind = backend_kind(model, backend, api_base)
    if options.get("price") is not None and kind != "api":
        raise UserError(
            f"--price is the price of a provider's tokens; {model} runs on the {kind} backend and "
            "is billed none: drop --price"
        )
    if batch and kind != "api":
        raise UserError(f"--batch is for models behind a provider's API; {model} runs on the {kind} backend")
    distributed = replicas != 1 or ray_address is not None or gpus_per_replica is not None
    if distributed and kind not in ("hf", "vllm"):
        raise UserError(
            f"--replicas, --ray-address and --gpus-per-replica are for local models (--backend hf or "
            f"vllm); {model} runs on the {kind} backend"
        )
    if api_base and kind != "api":
        fix = (
            "drop --api-base: a baseline computes its answers itself"
            if kind == "baseline"
            else f"drop --api-base to run the model here, or drop --backend {kind} to reach the server"
        )
        raise UserError(
            f"--api-base is for models behind an API; {model} runs on the {kind} backend, which would ignore it ({fix})"
        )
    if kind == "baseline":
        return _build("baseline", model.split(":", 1)[1] if ":" in model else model, **options)
    if kind in ("hf", "vllm"):
        info = lookup(model)
        checkpoint = info.model_id if info is not None else model
        if replicas < 1:
            raise UserError(f"--replicas must be at least 1, got {replicas}")
        if replicas > 1 or ray_address is not None:
            return _build(
                "ray",
                kind,
                checkpoint,
                replicas=replicas,
                address=ray_address,
                gpus_per_replica=gpus_per_replica,
                **options,
            )
        if gpus_per_replica is not None:
            raise UserError(
                "--gpus-per-replica goes with --replicas N (N > 1) or --ray-address; in one process, "
                "--device chooses the GPUs"
            )
        return local_backend(kind, checkpoint, **options)
    return _build("batch" if batch else "api", model, api_base=api_base, **options)


def _build(kind: str, *args: Any, **options: Any) -> Backend:
    """An instance of ``kind``'s class, built from ``args`` and ``options`` (each class takes its own)."""
    cls: Any = backend_class(kind)
    backend: Backend = cls(*args, **options)
    return backend


def run_backend(
    model: str,
    *,
    backend: str | None,
    api_base: str | None,
    output: str | os.PathLike[str],
    timeout: float | None,
    rpm: float | None,
    tpm: float | None,
    max_retries: int,
    backoff_base: float,
    backoff_cap: float,
    transport: str = "litellm",
    api_key_env: str | None = None,
    price: Sequence[float] | None = None,
    cache: str | None = None,
    backend_options: Mapping[str, Any] | None = None,
    replicas: int = 1,
    ray_address: str | None = None,
    gpus_per_replica: float | None = None,
    batch: bool = False,
    batch_poll: float | None = None,
    log: Callable[[str], None] | None = None,
) -> Backend:
    """The backend a run's settings name (the runner's one call), its notices shown once.

    ``api_base`` is the endpoint as the user gave it (credentials and all; the run's settings record it
    without them); ``output`` is the run's output directory, which a relative ``cache`` path (the response
    cache's file) is under. The API settings (``timeout``, ``rpm``, ``tpm``, ``transport``, retries and
    backoff, ``cache``, ``api_key_env``, ``price``) go to an ``api`` backend; ``timeout`` also bounds each
    batch of an ``hf`` model; ``batch`` (with ``batch_poll`` seconds, default 30) takes ``api_key_env``,
    ``timeout`` and ``price`` and refuses ``cache``, ``rpm`` and ``tpm``; ``backend_options`` go to the
    backend's constructor (not to a batch backend). Each notice goes to ``log`` (else a warning).
    Raises :class:`UserError` (one line) for settings the backend cannot take, before anything is built.
    """
    kind = backend_kind(model, backend, api_base)
    placement: dict[str, Any] = {"replicas": replicas, "ray_address": ray_address, "gpus_per_replica": gpus_per_replica}
    given_price = tuple(price) if price is not None else None
    if batch and kind == "api":
        ignored = [flag for flag, value in (("--cache", cache), ("--rpm", rpm), ("--tpm", tpm)) if value]
        if ignored:
            raise UserError(
                f"{', '.join(ignored)} do(es) not apply to --batch (the provider paces a batch itself, "
                "and the run's batch journal keeps every result); drop them or drop --batch"
            )
        # the endpoint as the user gave it, the key variable named: the same key rule as a normal run
        built = create_backend(
            model,
            backend=kind,
            api_base=api_base,
            batch=True,
            **placement,
            api_key_env=api_key_env,
            timeout=timeout,
            poll_seconds=batch_poll or 30.0,
            price=given_price,
        )
        return _with_notices(built, log)
    options = dict(backend_options or {})
    if kind == "api":
        if api_key_env:
            options["api_key_env"] = api_key_env
        if given_price is not None:
            options["price"] = given_price
        from lightemma.backends.retry import RetryPolicy

        options.update(
            timeout=timeout,
            rpm=rpm,
            tpm=tpm,
            transport=transport,
            retry=RetryPolicy(max_retries=max_retries, base=backoff_base, cap=backoff_cap),
            cache=ResponseCache(cache if os.path.isabs(cache) else Path(output) / cache, log=log) if cache else None,
        )
    elif given_price is not None:
        options["price"] = given_price  # refused by create_backend, naming the kind
    if kind == "hf" and timeout:
        # a deadline per batch, in this process or in each replica (docs/run.md#when-a-run-cannot-succeed)
        options.setdefault("timeout", timeout)
    built = create_backend(model, backend=kind, api_base=api_base, batch=batch, **placement, **options)
    return _with_notices(built, log)


def _with_notices(backend: Backend, log: Callable[[str], None] | None) -> Backend:
    """``backend``, its one-line notices (plain http to another host, …) shown once: to ``log``, else as warnings."""
    for notice in backend.notices:
        if log:
            log(notice)
        else:
            import warnings

            warnings.warn(notice, stacklevel=4)
    return backend
