"""Backends: one small interface (:mod:`lightemma.backends.base`), several implementations.

:func:`create_backend` picks one from a model string:

* ``baseline:constant|cv|oracle`` → :class:`lightemma.backends.baseline.BaselineBackend`;
* ``backend="hf"`` / ``"vllm"`` → the local backends (optional extras);
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

__all__ = ["BACKENDS", "STAGES", "Backend", "ChatRequest", "ChatResult", "GenerationParams", "create_backend", "backend_kind"]


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


def create_backend(model: str, *, backend: str | None = None, api_base: str | None = None, **options: Any) -> Backend:
    """A ready backend for ``model``. ``options`` go to the backend's constructor.

    For the API backend: ``timeout``, ``retry`` (RetryPolicy), ``rpm``, ``tpm``,
    ``cache`` (ResponseCache), ``api_key``. A missing API key raises
    :class:`~lightemma.errors.UserError` naming the variable, before any work.
    """
    kind = backend_kind(model, backend, api_base)
    if kind == "baseline":
        cls = _load("lightemma.backends.baseline", "BaselineBackend", "")
        return cls(model.split(":", 1)[1] if ":" in model else model, **options)
    if kind in ("hf", "vllm"):
        from lightemma.registry import lookup

        info = lookup(model)
        checkpoint = info.model_id if info is not None else model
        module, cls_name = ("lightemma.backends.hf", "HFBackend") if kind == "hf" else ("lightemma.backends.vllm", "VLLMBackend")
        return _load(module, cls_name, kind)(checkpoint, **options)
    from lightemma.backends.api import APIBackend

    return APIBackend(model, api_base=api_base, **options)
