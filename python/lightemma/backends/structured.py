"""Structured answers (``--answer-format structured``): the stage-3 JSON schema every backend enforces.

The schema fixes the answer's *shape*: a JSON object with the one key
``"actions"`` holding exactly ``n`` (6) pairs of JSON numbers,
``{"actions": [[v1, c1], …, [v6, c6]]}`` — the form
:func:`lightemma.parse_actions` reads with ``mode="json"``. Its only bound on
the values is a magnitude of :data:`MAGNITUDE` (1000) for every number, far
outside the plausibility limits (speed −10 to 50 m/s, |curvature| ≤ 1 /m),
which stay the parser's gate: an implausible answer still fails visibly and is
re-asked. The bound is there so that a number always ends: without it a grammar
lets a degenerate model write digits until the output limit (a tiny random model
does, greedily: ``5628.001284284284…``), and with it grammar engines that honour
it (xgrammar, so ``hf`` and ``vllm``) allow at most 6 decimals. The bound never
turns an implausible value into a plausible one: a number the model wanted
beyond ±1000 is cut after at least three digits, i.e. to a magnitude ≥ 100 — still
implausible (this holds while the plausibility limits stay under 100). The cost:
a value with more than 6 decimals is cut at the 6th (under 1e-6 m/s or 1/m).

Each backend enforces the schema its own way (recorded in the run manifest):
``response_format`` with ``strict`` JSON schema (OpenAI and OpenAI-compatible
servers; litellm maps it to Gemini's response schema and Anthropic's output
format or forced tool call), vLLM's structured outputs, xgrammar in the ``hf``
backend. Where a mechanism drops part of the schema (Anthropic's grammar has no
``minItems``/``maxItems``: litellm moves them into the description), the pair
count is asked for but not enforced, and an answer of another length fails as a
format error, as it would in text mode.
"""

from __future__ import annotations

from typing import Any

from lightemma.backends.base import ResponseSchema

#: what providers are told the schema is called
ACTIONS_SCHEMA_NAME = "driving_actions"
#: the bound on every number's magnitude (m/s or 1/m): a length limit, never a plausibility limit
MAGNITUDE = 1000


def actions_schema_dict(n: int = 6) -> dict[str, Any]:
    """The JSON schema of a stage-3 answer of ``n`` (speed m/s, curvature 1/m) pairs."""
    number = {"type": "number", "minimum": -MAGNITUDE, "maximum": MAGNITUDE}
    pair = {"type": "array", "items": number, "minItems": 2, "maxItems": 2}
    return {
        "type": "object",
        "properties": {
            "actions": {
                "type": "array",
                "description": f"the next {n} actions at 0.5 s intervals, each [speed in m/s, curvature in 1/m]",
                "items": pair,
                "minItems": n,
                "maxItems": n,
            }
        },
        "required": ["actions"],
        "additionalProperties": False,
    }


ACTIONS_SCHEMA = ResponseSchema.of(ACTIONS_SCHEMA_NAME, actions_schema_dict())


def openai_response_format(schema: ResponseSchema) -> dict[str, Any]:
    """The OpenAI ``response_format`` asking for ``schema`` in strict mode (what litellm maps for other providers)."""
    return {"type": "json_schema", "json_schema": {"name": schema.name, "schema": schema.as_dict(), "strict": True}}
