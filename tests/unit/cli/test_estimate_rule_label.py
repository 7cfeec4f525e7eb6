"""The estimate line names the image rule it counted by, also for a model served from another --api-base.

`lightemma run --model claude-4.6-sonnet --api-base URL --estimate` counted Anthropic's rule (width × height / 750)
and labelled the figure "openai rule" (the label came from the route, the count from the model).
"""

from __future__ import annotations

import pytest

from lightemma.nuscenes import load_frames
from lightemma.pipeline.runner import estimate_run


@pytest.mark.parametrize(
    ("model", "rule"),
    [
        ("claude-4.6-sonnet", "anthropic"),
        ("gemini-2.0-flash", "gemini"),
        ("gemini-3.0-flash", "gemini"),
        ("gpt-4o", "openai"),
    ],
)
def test_the_label_is_the_rule_counted(synth_root, elsewhere, model, rule) -> None:
    # elsewhere: 127.0.0.1 is not the provider's host here, so the route is the OpenAI-compatible one
    frames = load_frames(synth_root, "v1.0-mini", split="all")
    for api_base in (None, "http://127.0.0.1:9/v1"):
        est = estimate_run(model, frames=frames, api_base=api_base)
        assert est.image_tokens is not None
        assert f", {rule} rule)" in est.line(), (api_base, est.line())
    claude = estimate_run("claude-4.6-sonnet", frames=frames, api_base="http://127.0.0.1:9/v1")
    assert "Anthropic:" in claude.report()  # the rule described below the line is the same one
