"""Backends: one small interface (:mod:`lightemma.backends.base`), several implementations.

:func:`create_backend` picks one from a model string:

* ``baseline:constant|cv|oracle`` → :class:`lightemma.backends.baseline.BaselineBackend`;
* ``backend="hf"`` / ``"vllm"`` → the local backends (optional extras), in this process or, with
  ``replicas``/``ray_address``, as replicas over a Ray cluster (:mod:`lightemma.backends.ray`);
* anything else → :class:`lightemma.backends.api.APIBackend` (litellm), including
  registry names (``gpt-4o``, ``Claude-3.7-Sonnet``), litellm strings
  (``anthropic/claude-sonnet-4-6``) and OpenAI-compatible servers (``--api-base``).

Implementations are imported lazily, so ``import lightemma.backends`` is cheap
and a missing optional dependency is reported only when that backend is asked for.
"""

from __future__ import annotations

import importlib
from typing import Any

from lightemma.backends.base import STAGES, Backend, ChatRequest, ChatResult, GenerationParams
from lightemma.errors import UserError

BACKENDS = ("api", "hf", "vllm", "baseline")

__all__ = ["BACKENDS", "STAGES", "Backend", "ChatRequest", "ChatResult", "GenerationParams", "create_backend", "backend_kind",
           "local_backend"]


def backend_kind(model: str, backend: str | None = None, api_base: str | None = None) -> str:
    """Which backend serves ``model``: explicit ``backend``, else baseline/api by the model string.

    Registry entries for local checkpoints default to ``hf`` unless an
    ``api_base`` (e.g. a vLLM server) is given, which makes them ``api``.
    """
    if backend is not None:
        if backend not in BACKENDS:
            raise UserError(f"unknown backend {backend!r}; choose one of {', '.join(BACKENDS)}")
        return backend
    if model.strip().lower().startswith("baseline:"):
        return "baseline"
    from lightemma.registry import lookup

    info = lookup(model)
    if info is not None and info.backend in ("hf", "vllm") and not api_base:
        return info.backend
    return "api"


def _load(module: str, cls: str, extra: str) -> Any:
    try:
        return getattr(importlib.import_module(module), cls)
    except ImportError as exc:
        hint = f"; install it with: pip install 'lightemma[{extra}]'" if extra else ""
        raise UserError(f"the {cls} backend is not available ({exc}){hint}") from None


def local_backend(kind: str, checkpoint: str, **options: Any) -> Backend:
    """A local backend (``kind`` ``hf`` or ``vllm``) for ``checkpoint`` (a hub id or a path), in this process."""
    module, cls_name = ("lightemma.backends.hf", "HFBackend") if kind == "hf" else ("lightemma.backends.vllm", "VLLMBackend")
    return _load(module, cls_name, kind)(checkpoint, **options)


def create_backend(model: str, *, backend: str | None = None, api_base: str | None = None, replicas: int = 1,
                   ray_address: str | None = None, gpus_per_replica: float | None = None, **options: Any) -> Backend:
    """A ready backend for ``model``. ``options`` go to the backend's constructor.

    For the API backend: ``timeout``, ``retry`` (RetryPolicy), ``rpm``, ``tpm``,
    ``cache`` (ResponseCache), ``api_key``. A missing API key raises
    :class:`~lightemma.errors.UserError` naming the variable, before any work.

    For ``hf``/``vllm``: ``replicas`` > 1 or a ``ray_address`` runs that many replicas of the model
    as Ray actors (:class:`lightemma.backends.ray.RayBackend`, the ``ray`` extra); ``replicas=1``
    without an address runs the model in this process and needs no Ray. Other backends refuse them.
    """
    kind = backend_kind(model, backend, api_base)
    distributed = replicas != 1 or ray_address is not None or gpus_per_replica is not None
    if distributed and kind not in ("hf", "vllm"):
        raise UserError(f"--replicas, --ray-address and --gpus-per-replica are for local models (--backend hf or vllm); "
                        f"{model} runs on the {kind} backend")
    if api_base and kind != "api":
        fix = ("drop --api-base: a baseline computes its answers itself" if kind == "baseline" else
               f"drop --api-base to run the model here, or drop --backend {kind} to reach the server")
        raise UserError(f"--api-base is for models behind an API; {model} runs on the {kind} backend, which would "
                        f"ignore it ({fix})")
    if kind == "baseline":
        cls = _load("lightemma.backends.baseline", "BaselineBackend", "")
        return cls(model.split(":", 1)[1] if ":" in model else model, **options)
    if kind in ("hf", "vllm"):
        from lightemma.registry import lookup

        info = lookup(model)
        checkpoint = info.model_id if info is not None else model
        if replicas < 1:
            raise UserError(f"--replicas must be at least 1, got {replicas}")
        if replicas > 1 or ray_address is not None:
            from lightemma.backends.ray import RayBackend

            return RayBackend(kind, checkpoint, replicas=replicas, address=ray_address, gpus_per_replica=gpus_per_replica,
                              **options)
        if gpus_per_replica is not None:
            raise UserError("--gpus-per-replica goes with --replicas N (N > 1) or --ray-address; in one process, "
                            "--device chooses the GPUs")
        return local_backend(kind, checkpoint, **options)
    from lightemma.backends.api import APIBackend

    return APIBackend(model, api_base=api_base, **options)
