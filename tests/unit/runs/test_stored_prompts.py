"""An imported run's prompts: the shared text once per run, each frame's part per frame — and always exact."""

from __future__ import annotations

import json

from hypothesis import given, settings
from hypothesis import strategies as st

from lightemma.runs.stored_prompts import MAX_TEMPLATES, PromptTemplates, call_prompt, frame_texts

INTENT = (
    "You drive the car. The scene: {scene} Its speeds were {speeds} m/s and its curvatures {curvatures} 1/m. "
    "Say what it should do next, in one sentence {{no numbers}}."
)
ACTIONS = "You drive. Scene: {scene} History: {speeds} / {curvatures}. Intent: {intent} Answer [(v1, c1), …, (v6, c6)]."


def store(frames):
    """Encode ``frames`` (stage, prompt, texts) in order through one run's templates; (stored calls, manifest templates)."""
    templates = PromptTemplates()
    stored = [({"stage": stage, **templates.encode(stage, prompt, texts)}, texts) for stage, prompt, texts in frames]
    return stored, json.loads(json.dumps(templates.to_manifest()))  # as a manifest holds them


def frame(i: int):
    scene = f"A wet road; {i} parked cars on the right and a cyclist ahead in the bike lane, the light is green."
    intent = f"Keep the lane and slow down a little for the cyclist number {i} ahead of us."
    speeds, curvatures = [round(3.1 + 0.37 * i, 3)] * 6, [round(-0.01 * i, 4)] * 6
    texts = {"scene": scene, "intent": intent}
    return [
        ("intent", INTENT.format(scene=scene, speeds=speeds, curvatures=curvatures), texts),
        ("actions", ACTIONS.format(scene=scene, speeds=speeds, curvatures=curvatures, intent=intent), texts),
    ]


def test_template_built_prompts_keep_only_the_history_per_frame_and_decode_exactly():
    frames = [call for i in range(30) for call in frame(i)]
    stored, templates = store(frames)
    assert [call_prompt(call, texts, templates) for call, texts in stored] == [prompt for _, prompt, _ in frames]
    whole = [call for call, _ in stored if call["prompt"] is not None]
    assert len(whole) == 2  # the first frame of each stage (nothing to share with yet); every later one is a template's
    assert set(templates) == {"intent", "actions"} and all(len(t) == 1 for t in templates.values())
    assert (
        "{scene}" in templates["intent"][0]
        and "{intent}" in templates["actions"][0]
        and "{{no numbers}}" in templates["intent"][0]
    )
    fills = [call["prompt_fill"] for call, _ in stored if call["prompt"] is None]
    assert all(
        "cyclist" not in f and "Say what" not in f for f in fills
    )  # the frame's texts and the fixed text are not repeated
    assert max(map(len, fills)) < 120
    # a number the two first frames begin alike (3.1…) is never cut: the fill holds whole numbers
    assert all(f[0].isdigit() or f[0] == "-" for f in fills if f)


def test_prompts_holding_the_marker_characters_or_fitting_no_template_are_stored_whole():
    texts = {"scene": "a scene text long enough to be referenced", "intent": None}
    odd = "\ue000 a prompt with a private-use character in it, " + texts["scene"]
    stored, templates = store(
        [("intent", odd, texts), ("intent", odd + " again", texts), ("scene", "", texts), ("scene", None, texts)]
    )
    assert [c["prompt"] for c, _ in stored] == [odd, odd + " again", "", None]
    assert templates == {}
    assert [call_prompt(c, t, templates) for c, t in stored] == [odd, odd + " again", "", None]


def test_unrelated_prompts_make_no_template_and_templates_per_stage_are_capped():
    distinct = [("scene", f"{i}" * 3 + chr(65 + i % 26) * 40, {}) for i in range(10)]
    stored, templates = store(distinct)
    assert all(c["prompt"] is not None for c, _ in stored) and templates == {}
    # many different shared texts: at most MAX_TEMPLATES, the rest stored whole, every one exact
    many = [
        ("scene", f"Template {k:03d} " + "x" * 60 + f" tail {k}" + " filler" * 10, {})
        for k in range(MAX_TEMPLATES + 5)
        for _ in range(2)
    ]
    stored, templates = store(many)
    assert len(templates["scene"]) == MAX_TEMPLATES
    assert [call_prompt(c, t, templates) for c, t in stored] == [p for _, p, _ in many]


def test_a_failed_calls_text_is_what_a_template_refers_to():
    calls = [
        {"stage": "scene", "text": None, "error_message": "Error generating response: 500"},
        {"stage": "intent", "text": "go on", "error_message": None},
        {"stage": "actions", "text": "[]"},
    ]
    assert frame_texts(calls) == {"scene": "Error generating response: 500", "intent": "go on"}


def test_a_template_the_manifest_does_not_hold_gives_no_prompt_never_a_wrong_one():
    stored, templates = store([call for i in range(3) for call in frame(i)])
    call, texts = stored[-1]
    assert call["prompt"] is None
    assert call_prompt({**call, "prompt_template": 7}, texts, templates) is None
    assert call_prompt(call, texts, None) is None
    assert call_prompt(call, texts, {"actions": ["{unknown} field"]}) is None
    assert call_prompt(call, texts, {"actions": [3]}) is None


pieces = st.text(st.sampled_from("ab {}0123456789.-+\n\ue000\ue001é"), max_size=30)


@settings(max_examples=300, deadline=None)
@given(
    st.lists(
        st.tuples(st.sampled_from(["scene", "intent", "actions"]), pieces, pieces, pieces, pieces, st.booleans()),
        min_size=1,
        max_size=12,
    ),
    st.text(st.sampled_from("ab {}1.\ue000"), min_size=0, max_size=40),
)
def test_any_prompt_decodes_to_itself(parts, fixed):
    """Whatever the prompts hold (braces, markers, numbers, the frame's own texts or not), what is stored gives each back."""
    frames = []
    for stage, scene, intent, fill, other, shared in parts:
        scene, intent = scene * 3, intent * 3  # long enough to be looked for, some of the time
        texts = {"scene": scene, "intent": intent}
        prompt = (fixed + scene + fill + intent + fixed) if shared else other + scene + other
        frames.append((stage, prompt, texts))
    stored, templates = store(frames)
    assert [call_prompt(c, t, templates) for c, t in stored] == [p for _, p, _ in frames]


def test_a_short_prompt_and_a_long_one_sharing_a_word_make_no_template():
    """What two prompts share is measured against the longer: "Scene: " alone is no shared text of a long prompt."""
    stored, templates = store(
        [("scene", "Scene: a road.", {}), ("scene", "Scene: " + "a long and unrelated text " * 20, {})]
    )
    assert templates == {} and all(c["prompt"] is not None for c, _ in stored)
