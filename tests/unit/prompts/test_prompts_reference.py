"""Prompt sets that say what the reference said: {speeds} / {curvatures}, and `lightemma prompts check`."""

import asyncio
import json

import numpy as np
import pytest

from lightemma.backends.base import ChatResult
from lightemma.cli import main
from lightemma.errors import UserError
from lightemma.frames import format_python_list, history_placeholders
from lightemma.pipeline.chain import ChainPolicy, run_frame
from lightemma.prompts import PromptSet, load_prompt_set
from lightemma.prompts.check import check_prompts, first_difference
from lightemma.runs.importer import import_reference
from tests.support.memframes import make_frames
from tests.support.reference_fixtures import PROMPT_SET, write_results


def test_speeds_and_curvatures_print_as_python_printed_the_lists():
    assert format_python_list([1.299, 1.845, 2.68]) == "[1.299, 1.845, 2.68]"
    assert format_python_list([-0.0, 0.0, 0, 1e-05]) == "[-0.0, 0.0, 0, 1e-05]"  # -0.0 kept; an int stays an int
    assert format_python_list(np.array([np.float64(4.512), -0.0])) == "[4.512, -0.0]"  # never np.float64(...)
    assert format_python_list([]) == "[]"
    with pytest.raises(ValueError, match="non-finite"):
        format_python_list([1.0, float("nan")])
    values = history_placeholders([[4.512, -0.0], [5, 0.012]])
    assert values == {"history": "[(4.512, 0.0), (5.0, 0.012)]", "speeds": "[4.512, 5]", "curvatures": "[-0.0, 0.012]"}


def test_a_template_may_give_the_history_as_two_lists_but_not_as_one():
    base = {
        "name": "t",
        "stages": {"scene": "s", "intent": "{scene} v{speeds} c{curvatures}", "actions": "{scene} {history} {intent}"},
    }
    ps = PromptSet.from_dict(base)
    text = ps.render("intent", scene="S", **history_placeholders(np.array([[1.5, -0.0]] * 6)))
    assert text == "S v[1.5, 1.5, 1.5, 1.5, 1.5, 1.5] c[-0.0, -0.0, -0.0, -0.0, -0.0, -0.0]"
    half = {**base, "stages": {**base["stages"], "intent": "{scene} v{speeds}"}}
    with pytest.raises(
        UserError, match=r"'intent' template lacks placeholder\(s\) \{history\} \(or \{speeds\} and \{curvatures\}\)"
    ):
        PromptSet.from_dict(half)


class Recorder:
    """An in-process backend that keeps every prompt and answers like a good model."""

    info = {"kind": "recorder"}

    def __init__(self):
        self.texts = []

    async def generate(self, requests):
        out = []
        for req in requests:
            self.texts.append((req.stage, req.text))
            answer = {
                "scene": "A quiet street.",
                "intent": "Keep going.",
                "actions": "[" + ", ".join(["(5.0, 0.0)"] * 6) + "]",
            }[req.stage]
            out.append(ChatResult(text=answer, input_tokens=10, output_tokens=5, seconds=0.0))
        return out

    async def aclose(self):
        pass


def test_the_chain_fills_speeds_and_curvatures(tmp_path):
    (frame,) = make_frames(tmp_path, 1)
    backend = Recorder()
    record = asyncio.run(run_frame(frame, backend, PromptSet.from_dict(PROMPT_SET), ChainPolicy()))
    assert record["status"] == "ok"
    intent = dict(backend.texts)["intent"]
    speeds = repr([float(v) for v in frame.history_actions[:, 0]])
    assert f"was{speeds} m/s" in intent and "A quiet street." in intent


@pytest.fixture(scope="module")
def imported_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("prompts")
    write_results(root / "results")
    (result,) = import_reference([root / "results" / "qwen-2.5-7b"], root / "runs")
    path = root / "fixture.json"
    path.write_text(json.dumps(PROMPT_SET))
    return result.run_dir, path


def test_a_prompt_set_with_the_references_wording_matches_every_stored_prompt(imported_run, capsys):
    run_dir, path = imported_run
    checks = check_prompts(load_prompt_set(str(path)), run_dir)
    assert [(c.stage, c.compared, c.identical) for c in checks] == [
        ("scene", 21, 21),
        ("intent", 21, 21),
        ("actions", 21, 21),
    ]
    assert main(["prompts", "check", str(path), str(run_dir)]) == 0
    assert "21/21 frame(s) identical" in capsys.readouterr().out


def test_the_first_differing_character_is_reported_per_stage(imported_run, tmp_path, capsys):
    run_dir, path = imported_run
    changed = json.loads(path.read_text())
    changed["stages"]["intent"] = changed["stages"]["intent"].replace("was{speeds}", "was {speeds}")
    changed["stages"]["actions"] = changed["stages"]["actions"].replace("{history}", "").replace("The plan:", "Plan:")
    mine = tmp_path / "mine.json"
    mine.write_text(json.dumps(changed))
    checks = {c.stage: c for c in check_prompts(load_prompt_set(str(mine)), run_dir)}
    assert checks["scene"].ok and not checks["intent"].ok and checks["intent"].identical == 0
    diff = checks["intent"].first
    assert diff.stored[: diff.position] == diff.rendered[: diff.position]
    assert diff.stored[diff.position] == "[" and diff.rendered[diff.position] == " "
    assert diff.stored[diff.position - 3 : diff.position] == "was"
    assert main(["prompts", "check", str(mine), str(run_dir)]) == 1
    out = capsys.readouterr().out
    assert f"first difference in {diff.frame_id} at character {diff.position + 1}:" in out
    assert "run:      " in out and "rendered: " in out


def test_first_difference():
    assert first_difference("abc", "abc") is None
    assert first_difference("abc", "abd") == 2
    assert first_difference("ab", "abc") == 2


def test_prompts_check_needs_an_imported_run(tmp_path, capsys):
    from lightemma.runs.store import create_run_dir

    run_dir = create_run_dir(tmp_path, "openai/x", {"model": "openai/x"})
    assert main(["prompts", "check", "lightemma-v1", str(run_dir)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("lightemma prompts: error:") and "not imported" in err
