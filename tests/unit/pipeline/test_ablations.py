"""Input ablations (--inputs): what every stage's request holds, as the loopback server received it; the manifest,
the cache key and the resume refusal; prompt sets' no-history variants; the local backends' blank image."""

import base64
import io
import json
from importlib import resources

import numpy as np
import pytest
from PIL import Image

from lightemma.backends.local import load_image
from lightemma.cache import request_key
from lightemma.cli import main as cli_main
from lightemma.errors import UserError
from lightemma.inputs import BLANK_RGB, blank_reference, read_image_bytes, request_image
from lightemma.pipeline import resume, run
from lightemma.prompts import PromptSet, load_prompt_set
from lightemma.runs.store import FRAMES_FILE, read_run
from tests.support.fake_openai import FakeOpenAIServer
from tests.support.memframes import make_frames

FAST = dict(backoff_base=0.01, backoff_cap=0.05, timeout=10.0, progress=False)
VARIANTS = pytest.mark.parametrize(
    ("chain", "answer_format"),
    [("independent", "text"), ("conversation", "text"), ("independent", "structured"), ("conversation", "structured")],
)
# history numbers no prompt text holds otherwise
HISTORY = np.array([[7.31, 0.0137], [7.42, 0.0159], [7.53, 0.0171], [7.64, 0.0183], [7.75, 0.0195], [7.86, 0.0207]])
NUMBERS = ("7.31", "7.42", "7.53", "7.64", "7.75", "7.86", "0.0137", "0.0159", "0.0171", "0.0183", "0.0195", "0.0207")


def distinct_history(frames):
    for f in frames:
        f.history_actions = HISTORY.copy()
    return frames


def parts(req):
    return [p for _, turn in req.messages() for p in turn]


def texts(req):
    return "\n".join(p["text"] for p in parts(req) if p["kind"] == "text")


def images(req):
    return [p["data"] for p in parts(req) if p["kind"] == "image"]


def stages(server):
    return {r.stage for r in server.requests}


@VARIANTS
def test_no_image_sends_no_image_in_any_stage(tmp_path, chain, answer_format):
    frames = make_frames(tmp_path, 3)
    with FakeOpenAIServer() as server:
        result = run(
            "openai/gpt-4o",
            api_base=server.url,
            frames=frames,
            output=tmp_path / "runs",
            inputs="no-image",
            chain=chain,
            answer_format=answer_format,
            **FAST,
        )
    assert stages(server) == {"scene", "intent", "actions"} and len(server.requests) == 9
    assert all(images(r) == [] for r in server.requests)
    assert all(rec["status"] == "ok" for rec in read_run(result.run_dir).records.values())
    assert result.manifest["config"]["inputs"] == "no-image" and result.manifest["params"]["inputs"] == "no-image"
    # the image ablations keep the paper's wording (or the request variant's): only the image goes
    assert result.manifest["prompt_set"] == load_prompt_set().select(chain, answer_format).describe()


@VARIANTS
def test_blank_image_sends_a_uniform_grey_image_of_the_frames_size_in_every_stage(tmp_path, chain, answer_format):
    frames = make_frames(tmp_path, 2, image_size=(320, 180))
    with FakeOpenAIServer() as server:
        run(
            "openai/gpt-4o",
            api_base=server.url,
            frames=frames,
            output=tmp_path / "runs",
            inputs="blank-image",
            chain=chain,
            answer_format=answer_format,
            **FAST,
        )
    assert stages(server) == {"scene", "intent", "actions"}
    photos = {base64.b64encode(open(f.image_path, "rb").read()).decode() for f in frames}
    for req in server.requests:
        sent = images(req)
        assert len(sent) == 1 and sent[0] not in photos
        img = np.asarray(Image.open(io.BytesIO(base64.b64decode(sent[0]))).convert("RGB"))
        assert img.shape == (180, 320, 3)
        assert (img == np.array(BLANK_RGB, dtype=np.uint8)).all()  # uniform: exactly one grey, no information


@VARIANTS
def test_no_history_prompts_hold_none_of_the_history_numbers_in_any_stage(tmp_path, chain, answer_format):
    with FakeOpenAIServer() as server:
        run(
            "openai/gpt-4o",
            api_base=server.url,
            frames=distinct_history(make_frames(tmp_path, 2)),
            output=tmp_path / "full",
            chain=chain,
            answer_format=answer_format,
            **FAST,
        )
    full = list(server.requests)
    assert any(n in texts(r) for r in full for n in NUMBERS)  # the full prompts do carry them: the check can fail
    with FakeOpenAIServer() as server:
        result = run(
            "openai/gpt-4o",
            api_base=server.url,
            frames=distinct_history(make_frames(tmp_path, 2)),
            output=tmp_path / "ablated",
            inputs="no-history",
            chain=chain,
            answer_format=answer_format,
            **FAST,
        )
    assert stages(server) == {"scene", "intent", "actions"} and len(server.requests) == 6
    for req in server.requests:
        text = texts(req)
        assert not any(n in text for n in NUMBERS), text
        assert "past 3 seconds" not in text and "{history}" not in text
        assert len(images(req)) == 1  # the image stays
    described = result.manifest["prompt_set"]
    expected = load_prompt_set().select(chain, answer_format, "no-history").describe()
    assert described == expected and "no-history" in described["variant"]


def test_each_ablation_has_its_own_cache_key_and_a_full_request_keeps_its_old_one():
    params = {"temperature": 0}
    old = request_key("m", None, params, "text", "digest")
    assert request_key("m", None, params, "text", "digest", inputs="full") == old
    keys = {
        request_key("m", None, params, "text", "digest", inputs=i)
        for i in ("full", "no-image", "blank-image", "no-history")
    }
    assert len(keys) == 4


def test_an_ablated_run_never_replays_a_full_runs_cached_answers(tmp_path):
    frames = make_frames(tmp_path, 2)
    cache = tmp_path / "cache.sqlite"
    with FakeOpenAIServer() as server:
        run("openai/gpt-4o", api_base=server.url, frames=frames, output=tmp_path / "a", cache=str(cache), **FAST)
        first = len(server.requests)
        run("openai/gpt-4o", api_base=server.url, frames=frames, output=tmp_path / "b", cache=str(cache), **FAST)
        assert len(server.requests) == first  # the same full run: every answer from the cache
        result = run(
            "openai/gpt-4o",
            api_base=server.url,
            frames=frames,
            output=tmp_path / "c",
            cache=str(cache),
            inputs="no-image",
            **FAST,
        )
    # the scene prompt is the same text in both: without an image (and the inputs in the key) it reaches the provider
    assert len(server.requests) == 2 * first
    assert not any(rec["cached"] for rec in read_run(result.run_dir).records.values())


def test_resume_keeps_the_inputs_and_refuses_a_changed_one(tmp_path, capsys):
    frames = make_frames(tmp_path, 3)
    with FakeOpenAIServer() as server:
        result = run(
            "openai/gpt-4o", api_base=server.url, frames=frames, output=tmp_path / "runs", inputs="no-image", **FAST
        )
        path = result.run_dir / FRAMES_FILE
        lines = path.read_text().splitlines()
        path.write_text(lines[0] + "\n")  # two frames lost: a resume runs them again
        before = len(server.requests)
        resume(result.run_dir, frames=frames, progress=False, api_base=server.url)
        assert len(server.requests) == before + 6 and all(images(r) == [] for r in server.requests[before:])
    assert len(read_run(result.run_dir).records) == 3
    code = cli_main(["run", "--resume", str(result.run_dir), "--inputs", "full"])
    assert code == 2 and "--inputs" in capsys.readouterr().err


def test_a_baseline_is_shown_nothing_so_inputs_are_refused(tmp_path):
    with pytest.raises(UserError, match="--inputs no-image"):
        run("baseline:cv", frames=make_frames(tmp_path, 2), output=tmp_path, inputs="no-image", progress=False)


def test_unknown_inputs_are_refused_before_any_work(tmp_path):
    with pytest.raises(UserError, match="inputs must be one of"):
        run("baseline:cv", frames=make_frames(tmp_path, 2), output=tmp_path, inputs="no-scene", progress=False)


def _custom_set(**variants):
    data = json.loads((resources.files("lightemma.prompts") / "lightemma-v1.json").read_text(encoding="utf-8"))
    data["variants"] = variants
    return data


def test_a_custom_set_declares_its_own_no_history_variant_and_is_checked():
    data = _custom_set()
    with pytest.raises(UserError, match="no 'no-history' variant, which --inputs no-history needs"):
        PromptSet.from_dict(data).select(inputs="no-history")
    data = _custom_set(
        **{
            "no-history": {
                "intent": "Scene: {scene}. Intent?",
                "actions": "Scene {scene}, intent {intent}: [(v1, c1), …]",
            }
        }
    )
    ps = PromptSet.from_dict(data).select(inputs="no-history")
    assert ps.variant == "no-history" and "{history}" not in ps.render("actions", scene="s", intent="i")
    with pytest.raises(UserError, match="holds a history placeholder"):
        PromptSet.from_dict(_custom_set(**{"no-history": {"intent": "{scene} {history}"}}))
    # a variant that leaves a history-holding stage of the paper's in place is refused when selected
    partial = PromptSet.from_dict(_custom_set(**{"no-history": {"intent": "Scene: {scene}. Intent?"}}))
    with pytest.raises(UserError, match="no 'actions' template"):
        partial.select(inputs="no-history")


def test_local_backends_make_the_blank_image_themselves(tmp_path):
    img = load_image(blank_reference(48, 27))
    assert img.size == (48, 27) and (np.asarray(img) == np.array(BLANK_RGB, dtype=np.uint8)).all()
    frame = make_frames(tmp_path, 1, image_size=(64, 36))[0]
    assert request_image(frame, "blank-image") == "blank-image:64x36"
    assert request_image(frame, "no-image") is None and request_image(frame, "full") == frame.image_path
    assert request_image(frame, "no-history") == frame.image_path
    decoded = np.asarray(Image.open(io.BytesIO(read_image_bytes("blank-image:64x36"))))
    assert decoded.shape == (36, 64, 3) and (decoded == 128).all()
    frame.image_path = str(
        tmp_path / "gone.jpg"
    )  # unreadable: the call fails as a full run's would, never a guessed size
    with pytest.raises(OSError):
        read_image_bytes(request_image(frame, "blank-image"))


# -- evaluate: "does the image matter?" ------------------------------------------------------------------

BAD_ACTIONS = "[(1.0, 0.0), (1.0, 0.0), (1.0, 0.0), (1.0, 0.0), (1.0, 0.0), (1.0, 0.0)]"


def sees_the_road(req):
    """Good actions when an image (any image) is sent, poor ones without."""
    from tests.support.fake_openai import GOOD_ACTIONS, Reply, default_reply

    if req.stage == "actions":
        return Reply(GOOD_ACTIONS if req.has_image or any(p["kind"] == "image" for p in parts(req)) else BAD_ACTIONS)
    return default_reply(req)


def per_frame_ade(run_dir):
    from lightemma import displacement_errors

    return {
        fid: float(displacement_errors(np.array(r["trajectory"]), np.array(r["gt_positions"])).mean())
        for fid, r in read_run(run_dir).records.items()
    }


def test_ablation_and_full_runs_of_one_model_are_paired_on_common_frames_and_each_model_meets_the_best_baseline(
    tmp_path,
):
    from lightemma.evaluation import evaluate_runs
    from lightemma.evaluation.stats import Resampling
    from lightemma.report.evaluation_tables import evaluation_tables
    from lightemma.report.tables import to_markdown

    frames = make_frames(tmp_path, 9)
    for i, f in enumerate(frames):
        f.scene_name = f"scene-{i % 3:04d}"
        f.frame_id = f"{f.scene_name}/token{i:03d}"
        f.gt_actions = np.column_stack([np.full(6, 5.0), np.zeros(6)])
    out = tmp_path / "runs"
    with FakeOpenAIServer(sees_the_road) as server:
        full = run("openai/gpt-4o", api_base=server.url, frames=frames, output=out, **FAST).run_dir
        blind = run(
            "openai/gpt-4o", api_base=server.url, frames=frames[:6], output=out, inputs="no-image", **FAST
        ).run_dir
        blank = run(
            "openai/gpt-4o", api_base=server.url, frames=frames, output=out, inputs="blank-image", **FAST
        ).run_dir
    bases = {
        kind: run(f"baseline:{kind}", frames=frames, output=out, progress=False).run_dir
        for kind in ("constant", "cv", "ego")
    }
    evaluation = evaluate_runs([out], resampling=Resampling(n_resamples=2000))
    rows = {r["ablation"]: r for r in evaluation.input_ablations}
    assert set(rows) == {"no-image", "blank-image"}
    ade_full, ade_blind, ade_blank = per_frame_ade(full), per_frame_ade(blind), per_frame_ade(blank)
    common = sorted(ade_blind)  # the no-image run covers 6 of the 9 frames: paired on those only
    r = rows["no-image"]
    assert (r["model"], r["frames"], r["scenes"]) == ("openai/gpt-4o", 6, 3)
    assert r["ade_avg_full"] == pytest.approx(np.mean([ade_full[f] for f in common]))
    assert r["ade_avg_diff"] == pytest.approx(np.mean([ade_full[f] - ade_blind[f] for f in common]))
    assert r["ade_avg_diff"] < -1 and r["ade_avg_ci95"][1] < 0  # it uses the image
    assert r["ade_avg_p_holm"] >= r["ade_avg_p"] and r["ade_avg_significant"] in (True, False)
    b = rows["blank-image"]
    assert b["frames"] == 9 and b["ade_avg_diff"] == pytest.approx(
        np.mean([ade_full[f] - ade_blank[f] for f in ade_full])
    )
    assert (
        abs(b["ade_avg_diff"]) < 1e-9 and b["ade_avg_significant"] is False
    )  # a grey image does as well: no image use shown
    # every model run against the best of constant, cv and ego on the frames scored in both
    gains = {g["model"]: g for g in evaluation.baseline_gains}
    assert set(gains) == {"openai/gpt-4o", "openai/gpt-4o [no-image]", "openai/gpt-4o [blank-image]"}
    base_ade = {kind: per_frame_ade(d) for kind, d in bases.items()}
    for label, ade, ids in (
        ("openai/gpt-4o", ade_full, sorted(ade_full)),
        ("openai/gpt-4o [no-image]", ade_blind, common),
    ):
        means = {kind: np.mean([v[f] for f in ids]) for kind, v in base_ade.items()}
        best = min(means, key=means.get)
        g = gains[label]
        assert (
            g["baseline"]
            == f"Baseline ({ {'constant': 'constant actions', 'cv': 'constant velocity', 'ego': 'ego status'}[best] })"
        )
        assert g["frames"] == len(ids)
        assert g["ade_avg_gain"] == pytest.approx(means[best] - np.mean([ade[f] for f in ids]))
    names = [t.name for t in evaluation_tables(evaluation)]
    assert names[-2:] == ["input_ablations", "baseline_gains"]
    text = to_markdown(evaluation_tables(evaluation)[-2])
    assert "Does the image matter?" in text and "no-image" in text and "full − ablated" in text
    assert evaluation.to_dict()["input_ablations"] == evaluation.input_ablations


def test_an_ablation_with_two_full_runs_to_pair_with_is_left_out_with_a_warning(tmp_path):
    from lightemma.evaluation import evaluate_runs
    from lightemma.evaluation.stats import Resampling

    frames = make_frames(tmp_path, 4)
    out = tmp_path / "runs"
    with FakeOpenAIServer() as server:
        for inputs in ("full", "full", "no-image"):
            run("openai/gpt-4o", api_base=server.url, frames=frames, output=out, inputs=inputs, **FAST)
    evaluation = evaluate_runs([out], resampling=Resampling(n_resamples=100))
    assert evaluation.input_ablations == []
    assert any("2 full runs" in w and "left out" in w for w in evaluation.warnings)
