"""A stand-in for the ``vllm`` module that imports in any process (Ray replicas load it by name).

``LLM`` answers every conversation with a short text (stage 3: six valid actions) and counts
tokens the way vLLM does (prompt tokens include 100 image tokens). ``engine_kwargs`` of the
last engine built in this process are kept for the tests; the replica's own ``info`` carries them
back to the driver.
"""

from __future__ import annotations

__version__ = "0.32.0-fake"

ACTIONS = "[(5.0, 0.0), (5.1, 0.0), (5.2, 0.0), (5.3, 0.0), (5.4, 0.0), (5.5, 0.0)]"


class SamplingParams:
    def __init__(self, *, temperature, max_tokens):
        self.temperature, self.max_tokens = temperature, max_tokens


class _Config:
    class hf_config:  # noqa: N801 - vLLM's attribute name
        model_type = "qwen2_5_vl"


class _Engine:
    model_config = _Config


class _Completion:
    def __init__(self, text):
        self.text, self.token_ids, self.finish_reason = text, list(range(len(text.split()) + 1)), "stop"


class _Output:
    def __init__(self, text, n_prompt):
        self.prompt_token_ids, self.outputs, self.num_cached_tokens = list(range(n_prompt)), [_Completion(text)], 0


class LLM:
    def __init__(self, model, **kwargs):
        self.model, self.engine_kwargs, self.llm_engine = model, kwargs, _Engine()

    def chat(self, conversations, sampling_params=None, use_tqdm=True):
        outputs = []
        for conversation in conversations:
            (turn,) = conversation
            text = turn["content"][-1]["text"]
            has_image = turn["content"][0]["type"] == "image_pil"
            answer = ACTIONS if "(v1, c1)" in text else "A straight road, no other cars."
            outputs.append(_Output(answer, len(text.split()) + (100 if has_image else 0)))
        return outputs
