"""Backends: one base class (:class:`lightemma.backends.base.Backend`), several implementations, one factory.

:func:`create_backend` (:mod:`lightemma.backends.factory`) picks one from a model string:

* ``baseline:constant|cv|oracle|ego`` → :class:`lightemma.backends.baseline.BaselineBackend`;
* ``backend="hf"`` / ``"vllm"`` → the local backends (optional extras), in this process or, with
  ``replicas``/``ray_address``, as replicas over a Ray cluster (:mod:`lightemma.backends.ray`);
* anything else → :class:`lightemma.backends.api.APIBackend` (litellm), including
  registry names (``gpt-4o``, ``Claude-3.7-Sonnet``), litellm strings
  (``anthropic/claude-sonnet-4-6``) and OpenAI-compatible servers (``--api-base``);
  with ``batch=True``, :class:`lightemma.backends.batch.BatchBackend` (the provider's batch API).

Implementations are imported lazily, so ``import lightemma.backends`` is cheap
and a missing optional dependency is reported only when that backend is asked for.
"""

from __future__ import annotations

from lightemma.backends.base import STAGES, Backend, ChatRequest, ChatResult, GenerationParams
from lightemma.backends.factory import BACKENDS, KINDS, backend_class, backend_kind, create_backend, local_backend

__all__ = [
    "BACKENDS",
    "KINDS",
    "STAGES",
    "Backend",
    "ChatRequest",
    "ChatResult",
    "GenerationParams",
    "backend_class",
    "backend_kind",
    "create_backend",
    "local_backend",
]
