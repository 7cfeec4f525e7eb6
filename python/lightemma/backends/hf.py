"""``hf`` backend: a local vision-language checkpoint through transformers, batched.

Any checkpoint that ``AutoModelForImageTextToText`` + ``AutoProcessor`` load
(Qwen2-VL, Qwen2.5-VL, Qwen3-VL, Llama-3.2-Vision (Mllama), Llama-4, … from the
hub or a local path) is prompted through the model's own chat template, each
stage as one user turn with the image first (:mod:`lightemma.backends.local`).

Requests from the per-frame chains are gathered by a
:class:`~lightemma.backends.batching.MicroBatcher` into batches of up to
``batch_size`` requests of one stage; one thread owns the model and runs one
left-padded ``generate`` per batch. Decoding is greedy at temperature 0
(sampling otherwise). A stage-3 request of a structured run is decoded under
xgrammar's grammar for the actions JSON schema (its transformers logits
processor masks every token the schema does not allow, so the answer cannot
break the format); multi-turn requests (the ``conversation`` chain) go through
the model's chat template like single turns. transformers has no prefix cache
across requests: every call's cached input tokens are 0. Placement: bf16 and ``device_map="auto"`` across the
GPUs present; float32 on CPU. torch and transformers are imported when a
backend is built, never when this module is imported.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from typing import Any

from lightemma.backends.base import Backend, ChatRequest, ChatResult
from lightemma.backends.batching import DEFAULT_BATCH_WINDOW, MicroBatcher, Timeout
from lightemma.backends.local import DECODING, check_options, conversation, load_image, require, token_counting
from lightemma.backends.retry import short_message
from lightemma.errors import UserError

DTYPES = ("auto", "bfloat16", "float16", "float32")


class HFBackend(Backend):
    """A transformers model answering the chain's requests in micro-batches.

    Options: ``batch_size`` (requests per forward pass, default 8; 1 is the
    paper's way), ``batch_window`` (seconds to wait for a batch to fill),
    ``max_pixels`` (image-size cap: the processor's pixel budget for Qwen-style
    processors, a Pillow downscale before the processor otherwise), ``dtype``
    (``auto``: bfloat16 on GPU, float32 on CPU), ``device`` (``cuda``: all visible
    GPUs, ``cuda:N``: one, or ``cpu``; default cuda when available), ``device_map``
    (default ``"auto"`` for ``cuda``),
    ``attn_implementation`` and ``trust_remote_code`` (passed to transformers).
    """

    name = "hf"

    def __init__(
        self,
        model: str,
        *,
        batch_size: int = 8,
        batch_window: float = DEFAULT_BATCH_WINDOW,
        max_pixels: int | None = None,
        dtype: str = "auto",
        device: str | None = None,
        device_map: str | dict[str, Any] | None = None,
        attn_implementation: str | None = None,
        trust_remote_code: bool = False,
        timeout: float | None = None,
    ) -> None:
        if dtype not in DTYPES:
            raise UserError(f"--dtype must be one of {', '.join(DTYPES)}, got {dtype!r}")
        check_options(batch_size, max_pixels)
        if timeout is not None and not (timeout > 0):
            raise UserError(f"--timeout must be a positive number of seconds, got {timeout}")
        self.timeout = None if timeout is None else float(timeout)
        torch = require("torch", "hf")
        transformers = require("transformers", "hf")
        self.model_id = model
        self.max_pixels = max_pixels
        self._torch = torch
        self.device = device or ("cuda" if torch.cuda.is_available() else "cpu")
        on_gpu = self.device.startswith("cuda")
        self.dtype = {
            "auto": torch.bfloat16 if on_gpu else torch.float32,
            "bfloat16": torch.bfloat16,
            "float16": torch.float16,
            "float32": torch.float32,
        }[dtype]
        if device_map is None and self.device == "cuda":  # all visible GPUs; "cuda:N" pins one
            device_map = "auto"
        self._model, self._processor = self._load(
            transformers, model, device_map, attn_implementation, trust_remote_code
        )
        if device_map is None:
            self._model.to(self.device)
        self.device_map = device_map
        self.model_type = str(getattr(self._model.config, "model_type", "unknown"))
        self.architecture = type(self._model).__name__
        self.devices = sorted({str(p.device) for p in self._model.parameters()})
        self.gpus = sum(1 for d in self.devices if d.startswith("cuda"))  # distinct GPUs holding weights; 0 on CPU
        self._image_cap = self._cap_images(max_pixels)
        self._eos_ids = self._end_ids()
        self._oom_error = getattr(torch, "OutOfMemoryError", torch.cuda.OutOfMemoryError)
        self.oom_splits = 0  # batches halved after running out of GPU memory
        self._grammars: dict[Any, Any] = {}  # ResponseSchema -> xgrammar CompiledGrammar
        self._transformers_version = transformers.__version__
        self._batcher = MicroBatcher(
            self._run_batch,
            batch_size=batch_size,
            batch_window=batch_window,
            name=f"lightemma-hf-{self.model_type}",
            describe_fatal=self._describe_fatal,
            deadline=self.timeout,
        )

    def _describe_fatal(self, exc: BaseException) -> str:
        """The one line for a model that fails every batch the same way."""
        if isinstance(exc, Timeout):
            return (
                f"{self.model_id}: every batch runs past --timeout {self.timeout:g} s ({short_message(exc)}); raise "
                "--timeout, or lower --batch-size / --max-tokens"
            )
        if isinstance(exc, self._oom_error):
            return (
                f"{self.model_id}: out of GPU memory even for one request; lower --max-pixels, "
                "or spread the model over more GPUs (--device cuda)"
            )
        return (
            f"transformers {self._transformers_version} cannot generate with {self.model_type}: "
            f"{type(exc).__name__}: {short_message(exc)} — install the tested versions "
            "(pip install -c constraints.txt '.[hf]' in the lightemma checkout) or another transformers release"
        )

    # -- loading ----------------------------------------------------------------------------------

    def _load(
        self, transformers: Any, model: str, device_map: Any, attn_implementation: str | None, trust_remote_code: bool
    ) -> tuple[Any, Any]:
        kwargs: dict[str, Any] = {"dtype": self.dtype, "trust_remote_code": trust_remote_code}
        if device_map is not None:
            kwargs["device_map"] = device_map
        if attn_implementation:
            kwargs["attn_implementation"] = attn_implementation
        try:
            processor = transformers.AutoProcessor.from_pretrained(model, trust_remote_code=trust_remote_code)
            loaded = transformers.AutoModelForImageTextToText.from_pretrained(model, **kwargs)
        except (OSError, ValueError, KeyError) as exc:
            raise UserError(
                f"cannot load {model!r} as an image-text-to-text model with transformers "
                f"{transformers.__version__}: {short_message(exc, 400)}"
            ) from None
        loaded.eval()
        # Decode plainly: the checkpoint's sampling settings (top-k/top-p, repetition penalty, …) are not
        # used, so that hf and vllm decode the same way; only its special token ids are kept.
        self.checkpoint_generation_config = loaded.generation_config.to_diff_dict()
        loaded.generation_config = transformers.GenerationConfig(
            **{k: getattr(loaded.generation_config, k) for k in ("bos_token_id", "eos_token_id", "pad_token_id")}
        )
        tokenizer = processor.tokenizer
        tokenizer.padding_side = "left"  # generation continues every row from its last real token
        if tokenizer.pad_token_id is None:
            tokenizer.pad_token = tokenizer.eos_token
        return loaded, processor

    def _cap_images(self, max_pixels: int | None) -> str | None:
        """Apply ``max_pixels``: the processor's own pixel budget where it has one, else a Pillow downscale."""
        if max_pixels is None:
            return None
        image_processor = getattr(self._processor, "image_processor", None)
        size = getattr(image_processor, "size", None)
        try:
            budget = dict(size) if size is not None else {}  # a dict, or transformers 5's SizeDict
        except (TypeError, ValueError):
            budget = {}
        if hasattr(image_processor, "merge_size") and budget.get("longest_edge"):  # Qwen-style: a pixel budget
            shortest = min(budget.get("shortest_edge") or max_pixels, max_pixels)
            budget.update(longest_edge=max_pixels, shortest_edge=shortest)
            assert size is not None and image_processor is not None  # else: budget is {}, or no merge_size
            image_processor.size = budget if isinstance(size, dict) else type(size)(**budget)
            for attr, value in (("max_pixels", max_pixels), ("min_pixels", shortest)):
                if getattr(image_processor, attr, None) is not None:
                    setattr(image_processor, attr, value)
            return "processor pixel budget (size.longest_edge)"
        return "Pillow downscale before the processor"

    def _end_ids(self) -> set[int]:
        """Token ids that end an answer: the generation config's EOS ids plus the tokenizer's."""
        ids: set[int] = set()
        eos = getattr(self._model.generation_config, "eos_token_id", None)
        ids.update(eos if isinstance(eos, (list, tuple)) else [eos] if eos is not None else [])
        if self._processor.tokenizer.eos_token_id is not None:
            ids.add(self._processor.tokenizer.eos_token_id)
        return ids

    # -- the Backend interface --------------------------------------------------------------------

    @property
    def stats(self) -> dict[str, Any]:
        """Batches run so far, requests answered, mean and max batch size, batches halved for memory."""
        return {**self._batcher.stats.to_dict(), "oom_splits": self.oom_splits}

    @property
    def info(self) -> Mapping[str, Any]:
        torch = self._torch
        import transformers

        return {
            "backend": "hf",
            "model": self.model_id,
            "model_type": self.model_type,
            "architecture": self.architecture,
            "processor": type(self._processor).__name__,
            "device": self.device,
            "device_map": self.device_map if isinstance(self.device_map, str) or self.device_map is None else "custom",
            "gpus": self.gpus,
            "gpu_names": [torch.cuda.get_device_name(torch.device(d)) for d in self.devices if d.startswith("cuda")],
            "dtype": str(self.dtype).removeprefix("torch."),
            "batch_size": self._batcher.batch_size,
            "batch_window_s": self._batcher.batch_window,
            "timeout_s": self.timeout,
            "deadline": (
                "per batch: generation stops at --timeout (the batch fails as Timeout); a batch still running "
                "5-10 s later stops the run, resumable"
                if self.timeout
                else None
            ),
            "batching": "micro-batches of one stage, built around the oldest pending request; left padding",
            "max_pixels": self.max_pixels,
            "image_cap": self._image_cap,
            "decoding": DECODING,
            "token_counting": token_counting(self.model_type),
            "cached_input_tokens": "0: transformers keeps no prefix cache across requests",
            "seconds": "wall time of the batch the request ran in",
            "torch": torch.__version__,
            "transformers": transformers.__version__,
        }

    async def generate(self, requests: Sequence[ChatRequest]) -> list[ChatResult]:
        """Answer ``requests`` (in order) through the micro-batcher; a failed batch gives error results."""
        return await self._batcher.submit(requests)

    def sampling(self) -> str | None:
        """``--samples K``: K ``generate`` requests, each decoded with temperature sampling (they share micro-batches)."""
        return "calls"

    def structured_output(self) -> dict[str, Any]:
        """How stage 3 is constrained to the actions JSON schema (recorded in the manifest), or a UserError."""
        require("xgrammar", "hf")
        from importlib.metadata import version

        return {
            "mechanism": f"xgrammar {version('xgrammar')} grammar of the JSON schema (no free whitespace), applied by "
            "its transformers logits processor",
            "pair_count_enforced": True,
        }

    def _logits_processors(self, requests: Sequence[ChatRequest]) -> list[Any]:
        """The xgrammar logits processor for a batch with a response schema (one per ``generate``), else none."""
        schema = requests[0].response_schema
        if schema is None:
            return []
        xgr = require("xgrammar", "hf")
        from xgrammar.contrib.hf import LogitsProcessor

        compiled = self._grammars.get(schema)
        if compiled is None:
            tokenizer = self._processor.tokenizer
            vocab = self._model.get_output_embeddings().weight.shape[0]  # logits width (may exceed the tokenizer's)
            info = xgr.TokenizerInfo.from_huggingface(tokenizer, vocab_size=vocab, stop_token_ids=sorted(self._eos_ids))
            compiled = xgr.GrammarCompiler(info).compile_json_schema(schema.schema, any_whitespace=False)
            self._grammars[schema] = compiled
        return [LogitsProcessor(compiled)]

    async def aclose(self) -> None:
        """Stop the worker thread and free the model's (GPU) memory."""
        await self._batcher.aclose()
        self._model = None
        if self._torch.cuda.is_available():
            self._torch.cuda.empty_cache()

    # -- one batch, on the worker thread ----------------------------------------------------------

    def _run_batch(self, requests: Sequence[ChatRequest]) -> list[ChatResult]:
        """One left-padded ``generate`` over ``requests`` (same stage and params); results in order.

        A batch mixing requests with and without an image runs as two batches. A batch that runs
        out of GPU memory is halved and retried (down to single requests, whose OOM is an error).
        """
        with_image = [i for i, r in enumerate(requests) if r.image_path]
        if 0 < len(with_image) < len(requests):
            without = [i for i, r in enumerate(requests) if not r.image_path]
            results: dict[int, ChatResult] = {}
            for part in (with_image, without):
                results.update(zip(part, self._run_batch([requests[i] for i in part])))
            return [results[i] for i in range(len(requests))]
        try:
            return self._generate(requests)
        except self._oom_error:
            if len(requests) == 1:
                raise
            self.oom_splits += 1
            if self._torch.cuda.is_available():
                self._torch.cuda.empty_cache()
            half = len(requests) // 2
            return self._run_batch(requests[:half]) + self._run_batch(requests[half:])

    def _generate(self, requests: Sequence[ChatRequest]) -> list[ChatResult]:
        start = time.perf_counter()
        inputs = self._encode(requests)
        params = requests[0].params
        processors = self._logits_processors(requests)
        extra: dict[str, object] = {"logits_processor": processors} if processors else {}  # generate()'s keywords
        if self.timeout is not None:  # transformers' MaxTimeCriteria: generation stops at the deadline
            extra["max_time"] = max(0.0, self.timeout - (time.perf_counter() - start))
        with self._torch.inference_mode():
            output = self._model.generate(**inputs, **self._decoding(params), **extra)
        if self.timeout is not None and time.perf_counter() - start >= self.timeout:
            raise Timeout(f"generation stopped at --timeout {self.timeout:g} s before the batch finished")
        prompt_len = inputs["input_ids"].shape[1]
        input_counts = inputs["attention_mask"].sum(dim=1).tolist()
        generated = output[:, prompt_len:].tolist()
        seconds = time.perf_counter() - start
        return [self._result(row, int(n_in), seconds) for row, n_in in zip(generated, input_counts)]

    def _decoding(self, params: Any) -> dict[str, Any]:
        """``generate`` arguments for ``params``: greedy at temperature 0, else pure temperature sampling."""
        common = {
            "max_new_tokens": params.max_tokens,
            "eos_token_id": sorted(self._eos_ids),
            "pad_token_id": self._processor.tokenizer.pad_token_id,
        }
        if params.temperature > 0:
            return {**common, "do_sample": True, "temperature": params.temperature, "top_k": 0, "top_p": 1.0}
        return {**common, "do_sample": False}

    def _encode(self, requests: Sequence[ChatRequest]) -> Any:
        """Chat template + processor for a batch: padded tensors on the model's first device."""
        has_image = bool(requests[0].image_path)
        image_part = {"type": "image"} if has_image else None
        texts = [
            self._processor.apply_chat_template(conversation(r, image_part), add_generation_prompt=True, tokenize=False)
            for r in requests
        ]
        cap = self.max_pixels if self._image_cap and self._image_cap.startswith("Pillow") else None
        images = [[load_image(str(r.image_path), cap)] for r in requests] if has_image else None
        inputs = self._processor(text=texts, images=images, padding=True, return_tensors="pt")
        return inputs.to(self._model.device, dtype=self.dtype)

    def _result(self, row: list[int], input_tokens: int, seconds: float) -> ChatResult:
        """One generated row: text up to the first end token; output tokens include that end token.

        A row without an end token stopped at ``max_new_tokens``: ``finish_reason`` "length" (else "stop").
        """
        end = next((i for i, t in enumerate(row) if t in self._eos_ids), None)
        n_out = len(row) if end is None else end + 1
        text = self._processor.tokenizer.decode(row[: n_out if end is None else end], skip_special_tokens=True)
        return ChatResult(
            text=text,
            input_tokens=input_tokens,
            output_tokens=n_out,
            seconds=seconds,
            cost_cents=None,
            finish_reason="length" if end is None else "stop",
            cached_input_tokens=0,
        )
