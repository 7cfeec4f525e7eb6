"""The vllm backend against the REAL vllm package: every call lightemma makes is one vLLM accepts.

tests/unit/backends/test_local_backends.py drives the backend with a stand-in ``vllm``; this module checks that
stand-in's assumptions against the installed vllm itself: the engine keyword arguments bind to
``vllm.LLM`` (named parameters or ``EngineArgs`` fields), the ``LLM.chat`` call binds to its real
signature, each content part parses with vLLM's own chat parser, the sampling parameters are real
``SamplingParams`` / ``StructuredOutputsParams``, and results are read from real ``RequestOutput`` /
``CompletionOutput`` objects. No engine starts, so no GPU is needed — only vllm, which needs numpy 2 and
cannot share the main test environment (numpy<2 from nuscenes-devkit): run these in the vLLM
environment, ``pip install -e '.[vllm,test]' && python -m pytest tests/unit/backends/test_vllm_api.py``. They are
skipped, with that reason, where vllm cannot be imported.
"""

from __future__ import annotations

import asyncio
import dataclasses
import inspect

import numpy as np
import pytest
from PIL import Image

vllm = pytest.importorskip(
    "vllm",
    reason="vllm is not installed: it needs numpy 2 and its own environment "
    "(pip install -e '.[vllm,test]'; then python -m pytest tests/unit/backends/test_vllm_api.py)",
)

from vllm.outputs import CompletionOutput, RequestOutput  # noqa: E402

REAL_LLM = vllm.LLM  # before the fixture replaces it

from lightemma.backends.base import ChatRequest, GenerationParams  # noqa: E402
from lightemma.backends.structured import ACTIONS_SCHEMA  # noqa: E402
from lightemma.backends.vllm import VLLMBackend  # noqa: E402


class CheckedLLM:
    """``vllm.LLM`` whose calls are bound to the real signatures and whose answers are real output objects."""

    instances: list[CheckedLLM] = []

    def __init__(self, model, **kwargs):
        real = inspect.signature(REAL_LLM.__init__)
        bound = real.bind(None, model, **kwargs)  # TypeError if an argument has no place
        named = set(real.parameters) - {"self", "model", "kwargs"}
        engine_fields = {f.name for f in dataclasses.fields(vllm.EngineArgs)}
        rest = {k: v for k, v in kwargs.items() if k not in named}
        unknown = set(rest) - engine_fields
        assert not unknown, f"not vllm.LLM parameters nor EngineArgs fields: {sorted(unknown)}"
        self.bound, self.calls = bound, []
        self.llm_engine = type(
            "Engine",
            (),
            {"model_config": type("Config", (), {"hf_config": type("HF", (), {"model_type": "qwen2_5_vl"})})},
        )()
        CheckedLLM.instances.append(self)

    def chat(self, messages, **kwargs):
        inspect.signature(REAL_LLM.chat).bind(None, messages, **kwargs)
        from vllm.renderers.chat_utils import _parse_chat_message_content_mm_part as parse

        sampling = kwargs["sampling_params"]
        assert isinstance(sampling, vllm.SamplingParams)
        self.calls.append((messages, sampling))
        outputs = []
        for i, conversation in enumerate(messages):
            for turn in conversation:
                assert turn["role"] in ("user", "assistant")
                for part in turn["content"]:
                    kind, content = parse(part)  # vLLM's own parser of a content part
                    assert kind == part["type"] and content is not None
            text = "A road."
            completion = CompletionOutput(
                index=0,
                text=text,
                token_ids=[11, 12, 13],
                cumulative_logprob=None,
                logprobs=None,
                finish_reason="length",
            )
            outputs.append(
                RequestOutput(
                    request_id=str(i),
                    prompt=None,
                    prompt_token_ids=list(range(40 + i)),
                    prompt_logprobs=None,
                    outputs=[completion],
                    finished=True,
                    num_cached_tokens=7,
                )
            )
        return outputs


@pytest.fixture
def checked(monkeypatch):
    monkeypatch.setattr(vllm, "LLM", CheckedLLM)
    CheckedLLM.instances.clear()
    return vllm


@pytest.fixture
def image(tmp_path):
    path = tmp_path / "frame.jpg"
    Image.fromarray(np.random.default_rng(0).integers(0, 256, (48, 64, 3), dtype=np.uint8)).save(path)
    return str(path)


def run(backend, requests):
    async def main():
        out = await backend.generate(requests)
        await backend.aclose()
        return out

    return asyncio.run(main())


def test_engine_options_bind_to_the_real_llm_and_engine_args(checked):
    VLLMBackend(
        "Qwen/Qwen2.5-VL-7B-Instruct",
        tensor_parallel_size=2,
        pipeline_parallel_size=2,
        gpu_memory_utilization=0.5,
        max_model_len=8192,
        dtype="bfloat16",
        seed=3,
        engine_options={"enforce_eager": True},
    )
    (llm,) = CheckedLLM.instances
    args = llm.bound.arguments
    assert args["tensor_parallel_size"] == 2 and args["gpu_memory_utilization"] == 0.5 and args["seed"] == 3
    assert args["kwargs"]["limit_mm_per_prompt"] == {"image": 1} and args["kwargs"]["pipeline_parallel_size"] == 2


def test_an_argument_vllm_does_not_know_is_caught(checked):
    with pytest.raises(AssertionError, match="not_an_engine_argument"):
        VLLMBackend("Qwen/Qwen2.5-VL-7B-Instruct", engine_options={"not_an_engine_argument": 1})


def test_a_batch_is_one_real_chat_call_with_real_sampling_params_and_outputs(checked, image):
    backend = VLLMBackend("Qwen/Qwen2.5-VL-7B-Instruct", batch_size=4, batch_window=0.5)
    params = GenerationParams(max_tokens=9)
    requests = [
        ChatRequest(text=f"Describe {i}.", stage="scene", frame_id=f"f{i}", image_path=image, params=params)
        for i in range(3)
    ]
    results = run(backend, requests)
    (llm,) = CheckedLLM.instances
    ((messages, sampling),) = llm.calls
    assert len(messages) == 3 and (sampling.temperature, sampling.max_tokens) == (0.0, 9)
    assert sampling.structured_outputs is None
    assert [p["type"] for p in messages[0][0]["content"]] == ["image_pil", "text"]
    assert [(r.text, r.input_tokens, r.output_tokens, r.finish_reason, r.cached_input_tokens) for r in results] == [
        ("A road.", 40 + i, 3, "length", 7) for i in range(3)
    ]


def test_structured_stage_3_uses_the_real_structured_outputs_params(checked, image):
    backend = VLLMBackend("Qwen/Qwen2.5-VL-7B-Instruct", batch_size=1)
    assert "StructuredOutputsParams" in backend.structured_output()["mechanism"]
    schema = ACTIONS_SCHEMA
    request = ChatRequest(
        text="Actions?",
        stage="actions",
        frame_id="f0",
        image_path=image,
        params=GenerationParams(max_tokens=5),
        response_schema=schema,
        turns=(("Q1", "A1"),),
    )
    run(backend, [request])
    ((messages, sampling),) = CheckedLLM.instances[0].calls
    structured = sampling.structured_outputs
    assert isinstance(structured, vllm.sampling_params.StructuredOutputsParams)
    assert structured.json == schema.as_dict() and structured.disable_any_whitespace is True
    assert [t["role"] for t in messages[0]] == ["user", "assistant", "user"]
