"""Prompt sets: shipped as data, hashed, rendered with plain-decimal history."""

import hashlib
import json
from importlib import resources

import numpy as np
import pytest

from lightemma.errors import UserError
from lightemma.frames import format_history
from lightemma.prompts import DEFAULT_PROMPT_SET, PromptSet, available_prompt_sets, content_hash, load_prompt_set


def test_default_set_is_shipped_as_package_data_and_hashed_over_its_content():
    assert DEFAULT_PROMPT_SET in available_prompt_sets()
    raw = (resources.files("lightemma.prompts") / f"{DEFAULT_PROMPT_SET}.json").read_text(encoding="utf-8")
    data = json.loads(raw)
    ps = load_prompt_set()
    variants = data.pop("variants")  # hashed apart: the set's hash covers the paper's chain, as before variants existed
    canonical = json.dumps(data, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    assert ps.hash == "sha256:" + hashlib.sha256(canonical.encode()).hexdigest()
    assert set(ps.stages) == {"scene", "intent", "actions"}
    settings = {
        "structured": ("independent", "structured"),
        "conversation": ("conversation", "text"),
        "conversation+structured": ("conversation", "structured"),
        "no-history": ("independent", "text", "no-history"),
        "no-history+structured": ("independent", "structured", "no-history"),
        "conversation+no-history": ("conversation", "text", "no-history"),
        "conversation+no-history+structured": ("conversation", "structured", "no-history"),
    }
    assert set(variants) == set(settings)
    for name, templates in variants.items():
        canonical = json.dumps(templates, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
        assert ps.select(*settings[name]).variant_hash == "sha256:" + hashlib.sha256(canonical.encode()).hexdigest()


def test_any_change_of_wording_changes_the_hash():
    data = json.loads((resources.files("lightemma.prompts") / f"{DEFAULT_PROMPT_SET}.json").read_text(encoding="utf-8"))
    base = content_hash(data)
    data["stages"]["scene"] += " "
    assert content_hash(data) != base


def test_semantics_of_spec_section_2_are_in_the_templates():
    ps = load_prompt_set()
    assert "front camera" in ps.stages["scene"] and "Do not infer" in ps.stages["scene"]
    assert "positive curvature means turning left" in ps.stages["intent"]
    assert "[(v1, c1), (v2, c2), (v3, c3), (v4, c4), (v5, c5), (v6, c6)]" in ps.stages["actions"]


def test_stage_texts_and_history_flow_into_later_stages():
    ps = load_prompt_set()
    history = format_history(np.array([[4.512, -0.0], [5.0, 0.012], [5.1, -0.003], [5.2, 0.0], [5.3, 0.0], [5.4, 0.0]]))
    intent = ps.render("intent", scene="SCENE-MARK", history=history)
    actions = ps.render("actions", scene="SCENE-MARK", history=history, intent="INTENT-MARK")
    assert "SCENE-MARK" in intent and history in intent
    assert "SCENE-MARK" in actions and "INTENT-MARK" in actions and history in actions
    assert "{" not in ps.render("scene") and "{scene}" not in actions and "{history}" not in actions


def test_history_is_plain_decimals_never_a_library_repr():
    text = format_history(np.array([[np.float64(4.512), np.float64(-0.0)]] * 6))
    assert text.startswith("[(4.512, 0.0), ")
    assert "np." not in text and "-0.0" not in text and "e-" not in text


def test_a_prompt_file_missing_a_placeholder_is_rejected(tmp_path):
    bad = {"name": "bad", "stages": {"scene": "s", "intent": "{scene} only", "actions": "{scene} {history} {intent}"}}
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(bad))
    with pytest.raises(UserError, match=r"'intent' template lacks placeholder\(s\) \{history\}"):
        load_prompt_set(str(path))


def test_a_custom_prompt_file_loads_and_unknown_names_list_the_known_ones(tmp_path):
    good = {
        "name": "mine",
        "stages": {"scene": "s", "intent": "{scene} {history}", "actions": "{scene} {history} {intent}"},
    }
    path = tmp_path / "mine.json"
    path.write_text(json.dumps(good))
    ps = load_prompt_set(str(path))
    assert isinstance(ps, PromptSet) and ps.name == "mine" and ps.hash == content_hash(good)
    with pytest.raises(UserError, match=DEFAULT_PROMPT_SET):
        load_prompt_set("no-such-set")


def test_a_prompt_file_is_read_afresh_on_each_load(tmp_path):
    """An edited file is what the next run gets (and what a resume's hash guard compares), even in the same process."""
    path = tmp_path / "mine.json"
    first = {
        "name": "mine",
        "stages": {"scene": "s", "intent": "{scene} {history}", "actions": "{scene} {history} {intent}"},
    }
    path.write_text(json.dumps(first))
    assert load_prompt_set(str(path)).hash == content_hash(first)
    edited = {**first, "stages": {**first["stages"], "scene": "describe the scene"}}
    path.write_text(json.dumps(edited))
    ps = load_prompt_set(str(path))
    assert ps.hash == content_hash(edited) and ps.stages["scene"] == "describe the scene"


def test_a_prompt_set_file_holding_half_an_emoji_is_refused_in_one_line(tmp_path):
    import json

    from lightemma.errors import UserError
    from lightemma.prompts import load_prompt_set

    path = tmp_path / "p.json"
    path.write_text(
        json.dumps(
            {
                "name": "p",
                "stages": {
                    "scene": "Look \ud83d.",
                    "intent": "{scene} {history}",
                    "actions": "{scene} {intent} {history}",
                },
            }
        )
    )
    with pytest.raises(UserError, match="lone surrogate"):
        load_prompt_set(str(path))
