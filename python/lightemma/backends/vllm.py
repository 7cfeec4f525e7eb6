"""``vllm`` backend: a local checkpoint through vLLM's offline ``LLM.chat``, batched over a whole stage.

Requests from the per-frame chains are gathered by the same
:class:`~lightemma.backends.batching.MicroBatcher` as the ``hf`` backend (one
stage per batch, default up to 64 requests) and answered by ONE ``LLM.chat``
call over the batch's conversations; vLLM schedules them with continuous
batching. Each conversation is one user turn with the image first (or, in the
``conversation`` chain, the earlier turns with the image in the first;
:mod:`lightemma.backends.local`), and prefix caching is on, so the template
header and image of a frame are computed once and reused by its later stages;
each call records the prompt tokens served from that cache (``num_cached_tokens``).
A stage-3 request of a structured run is constrained to the actions JSON schema
through vLLM's structured outputs (``SamplingParams(structured_outputs=
StructuredOutputsParams(json=…))``, vLLM ≥ 0.12).

Not supported by current vLLM (0.32): Llama-3.2-Vision (``mllama``); such
models are refused with a pointer to ``--backend hf``. An OpenAI-compatible ``vllm serve`` server
is reached instead through the API backend with ``--api-base``.

vLLM needs a GPU and its own environment (it pins torch and transformers): it
is the ``vllm`` extra, separate from ``hf``. It is imported when a backend is
built, never when this module is imported.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from typing import Any

from lightemma.backends.base import Backend, ChatRequest, ChatResult
from lightemma.backends.batching import MicroBatcher
from lightemma.backends.local import (
    DECODING,
    check_options,
    conversation,
    is_mllama,
    load_image,
    require,
    token_counting,
)
from lightemma.backends.retry import short_message
from lightemma.errors import UserError

DEFAULT_BATCH_SIZE = 64
DEFAULT_BATCH_WINDOW = 0.02
MLLAMA_REFUSAL = "{model} is Llama-3.2-Vision (mllama), which vLLM 0.32 does not support; run it with --backend hf"


class VLLMBackend(Backend):
    """A vLLM engine answering the chain's requests, one ``LLM.chat`` per micro-batch.

    Options: ``batch_size`` (requests per ``LLM.chat`` call, default 64),
    ``batch_window``, ``tensor_parallel_size`` (GPUs to shard each layer over, default 1),
    ``pipeline_parallel_size`` (GPUs to split the layers over, default 1; the engine uses
    tensor × pipeline GPUs),
    ``gpu_memory_utilization`` (default 0.9), ``max_pixels`` (Pillow downscale
    of each image before vLLM's processor), ``dtype`` (``auto`` lets vLLM take
    the checkpoint's, i.e. bf16 for the paper's models), ``max_model_len``,
    ``seed``, ``enable_prefix_caching`` (default on), ``trust_remote_code`` (the
    checkpoint's own code runs; default off), ``engine_options`` (more
    ``vllm.LLM`` keyword arguments). ``vllm`` is the vllm module itself, or
    the name of a module to import in its place, for tests that inject a stand-in.
    """

    name = "vllm"

    def __init__(
        self,
        model: str,
        *,
        batch_size: int = DEFAULT_BATCH_SIZE,
        batch_window: float = DEFAULT_BATCH_WINDOW,
        tensor_parallel_size: int = 1,
        pipeline_parallel_size: int = 1,
        gpu_memory_utilization: float = 0.9,
        max_pixels: int | None = None,
        dtype: str = "auto",
        max_model_len: int | None = None,
        seed: int = 0,
        enable_prefix_caching: bool = True,
        trust_remote_code: bool = False,
        engine_options: Mapping[str, Any] | None = None,
        vllm: Any = None,
    ) -> None:
        if is_mllama(model):
            raise UserError(MLLAMA_REFUSAL.format(model=model))
        if tensor_parallel_size < 1:
            raise UserError(f"--tensor-parallel-size must be at least 1, got {tensor_parallel_size}")
        if pipeline_parallel_size < 1:
            raise UserError(f"--pipeline-parallel-size must be at least 1, got {pipeline_parallel_size}")
        if not 0 < gpu_memory_utilization <= 1:
            raise UserError(f"--gpu-memory-utilization must be in (0, 1], got {gpu_memory_utilization}")
        check_options(batch_size, max_pixels)
        self._vllm = vllm if vllm is not None and not isinstance(vllm, str) else require(vllm or "vllm", "vllm")
        self.model_id = model
        self.max_pixels = max_pixels
        self.tensor_parallel_size = tensor_parallel_size
        self.pipeline_parallel_size = pipeline_parallel_size
        self.gpu_memory_utilization = gpu_memory_utilization
        self.enable_prefix_caching = enable_prefix_caching
        self.engine_kwargs: dict[str, Any] = {
            "tensor_parallel_size": tensor_parallel_size,
            **({"pipeline_parallel_size": pipeline_parallel_size} if pipeline_parallel_size > 1 else {}),
            "gpu_memory_utilization": gpu_memory_utilization,
            "dtype": dtype,
            "seed": seed,
            "limit_mm_per_prompt": {"image": 1},
            "enable_prefix_caching": enable_prefix_caching,
            **({"max_model_len": max_model_len} if max_model_len else {}),
            **({"trust_remote_code": True} if trust_remote_code else {}),
            **dict(engine_options or {}),
        }
        try:
            self._llm = self._vllm.LLM(model, **self.engine_kwargs)
        except (OSError, ValueError) as exc:
            raise UserError(f"vLLM cannot load {model!r}: {short_message(exc, 400)}") from None
        self.model_type = self._engine_model_type()
        if is_mllama(model, self.model_type):
            raise UserError(MLLAMA_REFUSAL.format(model=model))
        self.prefix_cached_tokens = 0
        self._batcher = MicroBatcher(
            self._run_batch,
            batch_size=batch_size,
            batch_window=batch_window,
            name="lightemma-vllm",
            describe_fatal=self._describe_fatal,
        )

    def _describe_fatal(self, exc: BaseException) -> str:
        """The one line for an engine that fails every batch the same way."""
        return (
            f"vLLM {getattr(self._vllm, '__version__', '?')} cannot generate with {self.model_type}: "
            f"{type(exc).__name__}: {short_message(exc)}"
        )

    def _engine_model_type(self) -> str:
        """The checkpoint's ``model_type`` as the engine loaded it ("unknown" where it cannot be read)."""
        try:
            return str(self._llm.llm_engine.model_config.hf_config.model_type)
        except AttributeError:
            return "unknown"

    # -- the Backend interface --------------------------------------------------------------------

    @property
    def stats(self) -> dict[str, Any]:
        """Batches run so far, requests answered, batch sizes, prompt tokens served from the prefix cache."""
        return {**self._batcher.stats.to_dict(), "prefix_cached_tokens": self.prefix_cached_tokens}

    @property
    def info(self) -> Mapping[str, Any]:
        engine = {
            k: v for k, v in self.engine_kwargs.items() if isinstance(v, (str, int, float, bool, dict, type(None)))
        }
        return {
            "backend": "vllm",
            "model": self.model_id,
            "model_type": self.model_type,
            "gpus": self.tensor_parallel_size * self.pipeline_parallel_size,
            "tensor_parallel_size": self.tensor_parallel_size,
            "pipeline_parallel_size": self.pipeline_parallel_size,
            "gpu_memory_utilization": self.gpu_memory_utilization,
            "dtype": engine.get("dtype"),
            "engine": engine,
            "batch_size": self._batcher.batch_size,
            "batch_window_s": self._batcher.batch_window,
            "batching": "one LLM.chat per micro-batch of one stage (vLLM continuous batching inside); image first, "
            "prefix caching " + ("on" if self.enable_prefix_caching else "off"),
            "max_pixels": self.max_pixels,
            "image_cap": "Pillow downscale before vLLM's processor" if self.max_pixels else None,
            "decoding": DECODING,
            "token_counting": token_counting(self.model_type) + " (vLLM's prompt_token_ids and output token_ids)",
            "cached_input_tokens": "vLLM's num_cached_tokens per request (prefix cache hits)",
            "seconds": "wall time of the LLM.chat call the request ran in",
            "vllm": getattr(self._vllm, "__version__", None),
        }

    async def generate(self, requests: Sequence[ChatRequest]) -> list[ChatResult]:
        """Answer ``requests`` (in order) through the micro-batcher; a failed batch gives error results."""
        return await self._batcher.submit(requests)

    async def aclose(self) -> None:
        """Stop the worker thread and drop the engine."""
        await self._batcher.aclose()
        self._llm = None

    # -- one batch, on the worker thread ----------------------------------------------------------

    def sampling(self) -> str | None:
        """``--samples K``: K requests, each decoded with vLLM's temperature sampling."""
        return "calls"

    def structured_output(self) -> dict[str, Any]:
        """How stage 3 is constrained to the actions JSON schema (recorded in the manifest), or a UserError."""
        params = getattr(getattr(self._vllm, "sampling_params", None), "StructuredOutputsParams", None)
        if params is None:
            raise UserError(
                f"--answer-format structured: vLLM {getattr(self._vllm, '__version__', '?')} has no "
                "StructuredOutputsParams (vLLM 0.12 or later has); use --answer-format text"
            )
        return {
            "mechanism": "vLLM structured outputs: SamplingParams(structured_outputs=StructuredOutputsParams("
            "json=schema, disable_any_whitespace=True)); vLLM picks the grammar engine (xgrammar by default)",
            "pair_count_enforced": True,
        }

    def conversation(self, request: ChatRequest) -> list[dict[str, Any]]:
        """The conversation for ``request``: earlier turns (if any), the PIL image first in the first user turn."""
        image = None
        if request.image_path:
            image = {"type": "image_pil", "image_pil": load_image(str(request.image_path), self.max_pixels)}
        return conversation(request, image)

    def _sampling(self, request: ChatRequest) -> Any:
        """vLLM sampling parameters of a batch like ``request``: its decoding, and its response schema if any."""
        params = request.params
        extra: dict[str, Any] = {}
        if request.response_schema is not None:
            extra["structured_outputs"] = self._vllm.sampling_params.StructuredOutputsParams(
                json=request.response_schema.as_dict(), disable_any_whitespace=True
            )
        return self._vllm.SamplingParams(
            temperature=max(0.0, params.temperature), max_tokens=params.max_tokens, **extra
        )

    def _run_batch(self, requests: Sequence[ChatRequest]) -> list[ChatResult]:
        """One ``LLM.chat`` over the batch's conversations (same stage, params and schema); results in order."""
        start = time.perf_counter()
        sampling = self._sampling(requests[0])
        conversations = [self.conversation(r) for r in requests]
        outputs = self._llm.chat(conversations, sampling_params=sampling, use_tqdm=False)
        if len(outputs) != len(requests):
            raise RuntimeError(f"vLLM returned {len(outputs)} outputs for {len(requests)} conversations")
        seconds = time.perf_counter() - start
        self.prefix_cached_tokens += sum(int(getattr(o, "num_cached_tokens", 0) or 0) for o in outputs)
        return [self._result(o, seconds) for o in outputs]

    @staticmethod
    def _result(output: Any, seconds: float) -> ChatResult:
        completion = output.outputs[0]
        finish = getattr(completion, "finish_reason", None)
        cached = getattr(output, "num_cached_tokens", None)
        return ChatResult(
            text=completion.text,
            input_tokens=len(output.prompt_token_ids or []),
            output_tokens=len(completion.token_ids),
            seconds=seconds,
            cost_cents=None,
            finish_reason=str(finish) if finish is not None else None,
            cached_input_tokens=int(cached) if isinstance(cached, int) and cached >= 0 else None,
        )
