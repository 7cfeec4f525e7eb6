"""Image corruptions and history perturbations (--inputs corrupt:NAME@SEVERITY, history-noise@…, history-stale@K):
what the loopback server received, decoded and measured per severity; the same bytes in every run and every backend's
reader; the manifest; bad specs refused before any call."""

import asyncio
import base64
import hashlib
import io
import re
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from lightemma.backends.base import ChatResult
from lightemma.backends.local import load_image
from lightemma.cli import main as cli_main
from lightemma.corruptions import (
    CORRUPTIONS,
    NAMES,
    SEVERITIES,
    corruption_reference,
    corruption_seed,
    parse_corruption,
)
from lightemma.errors import UserError
from lightemma.inputs import read_image_bytes, request_image, shown_history
from lightemma.pipeline import run
from lightemma.pipeline.chain import ChainPolicy, run_frame
from lightemma.prompts import load_prompt_set
from lightemma.runs.store import read_run
from tests.support.fake_openai import FakeOpenAIServer
from tests.support.memframes import make_frames

FAST = dict(backoff_base=0.01, backoff_cap=0.05, timeout=10.0, progress=False)
W, H = 160, 90


def textured(path):
    """A gradient with ±40 pixel noise and no near-black pixel, saved as a quality-100 JPEG: what is blurred,
    darkened or covered shows."""
    rng = np.random.default_rng(7)
    y, x = np.mgrid[0:H, 0:W]
    base = np.stack([60 + x * 120 // W, 60 + y * 120 // H, 60 + (x + y) * 120 // (W + H)], -1)
    img = np.clip(base + rng.integers(-40, 41, (H, W, 3)), 0, 255).astype(np.uint8)
    Image.fromarray(img).save(path, quality=100)
    return np.asarray(Image.open(path).convert("RGB"))


def decode(data):
    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))


def luminance(rgb):
    return rgb.astype(np.float64) @ np.array([0.299, 0.587, 0.114])


def laplacian_var(rgb):
    """Variance of the 4-neighbour Laplacian of the luminance: high-frequency energy (sharpness, noise)."""
    g = luminance(rgb)
    return float((g[:-2, 1:-1] + g[2:, 1:-1] + g[1:-1, :-2] + g[1:-1, 2:] - 4 * g[1:-1, 1:-1]).var())


MEASURES = {
    "mean": lambda img, clean: float(luminance(img).mean()),
    "std": lambda img, clean: float(luminance(img).std()),
    "hf": lambda img, clean: laplacian_var(img),
    "mae": lambda img, clean: float(np.abs(img.astype(int) - clean).mean()),
    "black": lambda img, clean: float((img.max(axis=2) <= 10).mean()),
}
# what each corruption's definition says it does, as (measure, direction against the clean image, monotone over 1-5)
EXPECTED = {
    "brightness": [("mean", +1, True)],
    "dark": [("mean", -1, True)],
    "contrast": [("std", -1, True)],
    "fog": [("mean", +1, True), ("std", -1, True)],
    "rain": [("mae", +1, True)],
    "snow": [("mean", +1, True)],
    "motion-blur": [("hf", -1, False)],
    "defocus-blur": [("hf", -1, True)],
    "zoom-blur": [("hf", -1, False)],
    "gaussian-noise": [("hf", +1, True), ("std", +1, True)],
    "jpeg": [("hf", -1, True)],
    "pixelate": [("hf", -1, True)],
    "occlusion": [("black", +1, True), ("mean", -1, True)],
}


def test_every_corruption_has_a_definition_to_check():
    assert set(EXPECTED) == set(NAMES) and all(len(table) == 5 for _, table in CORRUPTIONS.values())


def sent_images(server):
    return [p["data"] for r in server.requests for _, turn in r.messages() for p in turn if p["kind"] == "image"]


def run_corrupted(tmp_path, frames, inputs, out):
    with FakeOpenAIServer() as server:
        result = run("openai/gpt-4o", api_base=server.url, frames=frames, output=tmp_path / out, inputs=inputs, **FAST)
    sent = sent_images(server)
    assert len(sent) == 3 * len(frames) and len(set(sent)) == len(frames)  # every stage the same corrupted image
    return result, sent


@pytest.mark.parametrize("name", NAMES)
def test_each_corruption_at_each_severity_changes_the_sent_image_as_defined_and_the_same_frame_gives_the_same_bytes(
    tmp_path, name
):
    frames = make_frames(tmp_path, 1)
    clean = textured(frames[0].image_path)
    measured = []
    for severity in SEVERITIES:
        result, sent = run_corrupted(tmp_path, frames, f"corrupt:{name}@{severity}", f"s{severity}")
        img = decode(base64.b64decode(sent[0]))
        assert img.shape == clean.shape
        measured.append({m: MEASURES[m](img, clean) for m in MEASURES})
        corruption = result.manifest["params"]["corruption"]
        assert (corruption["name"], corruption["severity"]) == (name, severity)
        assert corruption["params"] and corruption["library"].startswith("albumentations 2.0.")
        assert result.manifest["config"]["inputs"] == f"corrupt:{name}@{severity}"
        assert all(rec["status"] == "ok" for rec in read_run(result.run_dir).records.values())
        if severity == 3:  # a second run: byte for byte the same image
            assert run_corrupted(tmp_path, frames, f"corrupt:{name}@3", "again")[1] == sent
    base = {m: MEASURES[m](clean, clean) for m in MEASURES}
    for measure, direction, monotone in EXPECTED[name]:
        values = [row[measure] for row in measured]
        assert all(direction * (v - base[measure]) > 0 for v in values), (measure, base[measure], values)
        if monotone:
            assert all(direction * (b - a) > 0 for a, b in zip(values, values[1:])), (measure, values)


def test_frames_get_their_own_seeds_and_the_seed_follows_the_sample_token(tmp_path):
    frames = make_frames(tmp_path, 2, image_size=(W, H))
    for f in frames:
        textured(f.image_path)  # the same picture for both frames
    refs = [request_image(f, "corrupt:gaussian-noise@2") for f in frames]
    assert refs[0] != refs[1] and read_image_bytes(refs[0]) != read_image_bytes(refs[1])
    seed = corruption_seed("token000", "gaussian-noise", 2)
    assert refs[0] == corruption_reference(frames[0].image_path, "gaussian-noise", 2, seed)
    assert seed == int.from_bytes(hashlib.sha256(b"lightemma-corrupt|gaussian-noise@2|token000").digest()[:4], "big")


@pytest.mark.slow
def test_local_backends_and_ray_replicas_read_the_bytes_the_api_sends(tmp_path):
    """hf and vLLM read images through load_image, Ray replicas too (in their own processes, from the reference the
    driver's request carries): every reader decodes the one corrupted JPEG that read_image_bytes makes."""
    frame = make_frames(tmp_path, 1)[0]
    textured(frame.image_path)
    ref = request_image(frame, "corrupt:motion-blur@4")
    data = read_image_bytes(ref)
    assert (np.asarray(load_image(ref)) == decode(data)).all()
    assert load_image(ref, max_pixels=W * H // 4).size == (W // 2, H // 2)  # the local backends' cap still applies
    # a fresh interpreter (as a replica is) makes the same bytes
    code = (
        "import hashlib, sys; from lightemma.inputs import read_image_bytes; "
        "print(hashlib.sha256(read_image_bytes(sys.argv[1])).hexdigest())"
    )
    out = subprocess.run([sys.executable, "-c", code, ref], capture_output=True, text=True, check=True, timeout=120)
    assert out.stdout.strip() == hashlib.sha256(data).hexdigest()
    # the requests the chain hands to any backend (the Ray router included) carry the reference, not pixels
    seen = []

    class Recording:
        name = "recording"

        async def generate(self, requests):
            seen.extend(requests)
            text = "[(5.0, 0.0), (5.0, 0.0), (5.0, 0.0), (5.0, 0.0), (5.0, 0.0), (5.0, 0.0)]"
            return [ChatResult(text=text) for _ in requests]

    policy = ChainPolicy(inputs="corrupt:motion-blur@4")
    asyncio.run(run_frame(frame, Recording(), load_prompt_set().select(inputs=policy.inputs), policy))
    assert [r.image_path for r in seen] == [ref] * 3


def test_a_corrupted_image_of_an_unreadable_file_fails_the_call_never_sends_the_clean_one(tmp_path):
    frame = make_frames(tmp_path, 1)[0]
    frame.image_path = str(tmp_path / "gone.jpg")
    with pytest.raises(OSError, match="cannot read image"):
        read_image_bytes(request_image(frame, "corrupt:fog@1"))
    with pytest.raises(OSError, match="malformed corruption reference"):
        read_image_bytes("corrupt:fog@9:1:" + str(tmp_path / "cam0.jpg"))


BAD = [
    "corrupt:haze@3",
    "corrupt:fog@0",
    "corrupt:fog@6",
    "corrupt:fog@2.5",
    "corrupt:fog",
    "corrupt:Fog@2",
    "history-noise@-1",
    "history-noise@abc",
    "history-noise@0",
    "history-noise@0,0",
    "history-noise@nan",
    "history-noise@99",
    "history-stale@0",
    "history-stale@6",
    "history-stale@1.5",
    "history-stale@",
]


@pytest.mark.parametrize("inputs", BAD)
def test_a_bad_spec_is_one_line_before_any_call(tmp_path, capsys, inputs):
    frames = make_frames(tmp_path, 1)
    with FakeOpenAIServer() as server:
        with pytest.raises(UserError) as info:
            run("openai/gpt-4o", api_base=server.url, frames=frames, output=tmp_path / "runs", inputs=inputs, **FAST)
        with pytest.raises(SystemExit) as exited:  # argparse refuses it
            cli_main(
                [
                    "run",
                    "--model",
                    "openai/gpt-4o",
                    "--api-base",
                    server.url,
                    "--dataroot",
                    str(tmp_path),
                    "--inputs",
                    inputs,
                    "--output",
                    str(tmp_path / "cli"),
                ]
            )
    assert server.requests == [] and not (tmp_path / "runs").exists() and not (tmp_path / "cli").exists()
    message = str(info.value)
    assert "\n" not in message and inputs in message
    err = capsys.readouterr().err.strip().splitlines()
    assert exited.value.code == 2 and len(err) == 1 and inputs in err[0] and "--inputs" in err[0], err
    if inputs.startswith("corrupt:haze"):
        assert "unknown corruption 'haze'" in message and "fog" in message


def test_parse_corruption_reads_name_and_severity():
    assert parse_corruption("corrupt:zoom-blur@5") == ("zoom-blur", 5) and parse_corruption("full") is None


# -- history perturbations ------------------------------------------------------------------------------

HISTORY = np.array([[7.31, 0.0137], [7.42, 0.0159], [7.53, 0.0171], [7.64, 0.0183], [7.75, 0.0195], [7.86, 0.0207]])


def printed_pairs(text):
    """The six (speed, curvature) pairs of the history paragraph the intent prompt printed."""
    pairs = re.findall(r"\((-?[\d.]+), (-?[\d.]+)\)", text)
    return np.array([[float(a), float(b)] for a, b in pairs[:6]])


def intent_texts(server):
    return [r.text for r in server.requests if r.stage == "intent"]


def run_history(tmp_path, inputs, out, n=2):
    frames = make_frames(tmp_path, n)
    for f in frames:
        f.history_actions = HISTORY.copy()
    with FakeOpenAIServer() as server:
        result = run("openai/gpt-4o", api_base=server.url, frames=frames, output=tmp_path / out, inputs=inputs, **FAST)
    return result, intent_texts(server), frames


def test_stale_history_prints_the_pairs_k_steps_late_and_the_record_keeps_the_truth(tmp_path):
    full = run_history(tmp_path, "full", "full")[1]
    assert np.allclose(printed_pairs(full[0]), HISTORY)  # the measure reads the printed history: it can fail
    result, texts, frames = run_history(tmp_path, "history-stale@2", "stale")
    expected = HISTORY[[0, 0, 0, 1, 2, 3]]
    assert all(np.allclose(printed_pairs(t), expected) for t in texts)
    assert result.manifest["params"]["history_perturbation"] == {"kind": "stale", "steps": 2, "delay_s": 1.0}
    assert all(np.allclose(rec["history_actions"], HISTORY) for rec in read_run(result.run_dir).records.values())


def test_history_noise_has_the_documented_sigma_per_frame_seeds_and_is_the_same_in_every_run(tmp_path):
    result, texts, frames = run_history(tmp_path, "history-noise@0.5,0.01", "a", n=4)
    again = run_history(tmp_path, "history-noise@0.5,0.01", "b", n=4)[1]
    assert sorted(texts) == sorted(again)  # the same numbers in a second run
    printed = {t: printed_pairs(t) for t in texts}
    assert len({p.tobytes() for p in printed.values()}) == 4  # each frame its own draw
    for f in frames:
        shown = shown_history(f, "history-noise@0.5,0.01")
        assert any(np.allclose(p, shown, atol=1e-3) for p in printed.values())
        assert np.array_equal(shown, np.round(shown, 3))  # the history's own 3 decimals, never 16 digits
    assert not any(re.search(r"\d\.\d{4,}", t) for t in texts)  # no noisy value prints beyond 3 decimals
    perturbation = result.manifest["params"]["history_perturbation"]
    assert (perturbation["sigma_speed_m_s"], perturbation["sigma_curvature_per_m"]) == (0.5, 0.01)
    # the draw's spread is the documented sigma (2,000 frames' worth of noise)
    many = [SimpleNamespace(frame_id=f"s/t{i}", sample_token=f"t{i}", history_actions=HISTORY) for i in range(2000)]
    diffs = np.array([shown_history(f, "history-noise@0.5,0.01") - HISTORY for f in many])
    assert diffs[..., 0].std() == pytest.approx(0.5, rel=0.03) and diffs[..., 1].std() == pytest.approx(0.01, rel=0.03)
    assert abs(diffs[..., 0].mean()) < 0.02
    speeds_only = shown_history(many[0], "history-noise@0.5") - HISTORY
    assert (speeds_only[:, 1] == 0).all() and (speeds_only[:, 0] != 0).all()


def test_a_batch_run_sends_the_bytes_the_direct_api_run_sends(tmp_path, monkeypatch):
    import lightemma.backends.batch as batch_module
    from tests.support.fake_batch import FakeBatchServer

    monkeypatch.setattr(batch_module, "IDLE_SECONDS", 0.15)
    monkeypatch.setenv("OPENAI_API_KEY", "sk-test-openai")
    frames = make_frames(tmp_path, 2, image_size=(W, H))
    direct = run_corrupted(tmp_path, frames, "corrupt:rain@4", "direct")[1]
    with FakeBatchServer(steps=1) as server:
        result = run(
            "openai/gpt-4o",
            api_base=server.url,
            frames=frames,
            output=tmp_path / "batch",
            batch=True,
            batch_poll=0.01,
            inputs="corrupt:rain@4",
            progress=False,
        )
    assert all(rec["status"] == "ok" for rec in read_run(result.run_dir).records.values())
    urls = [
        p["image_url"]["url"]
        for b in server.batches.values()
        for _, body in b.requests
        for m in body["messages"]
        if isinstance(m["content"], list)
        for p in m["content"]
        if p.get("type") == "image_url"
    ]
    assert len(urls) == 6 and {u.split(",", 1)[1] for u in urls} == set(direct)


def test_a_corrupted_run_is_paired_with_its_full_run_like_an_ablation(tmp_path):
    from lightemma.evaluation import evaluate_runs
    from lightemma.evaluation.stats import Resampling

    frames = make_frames(tmp_path, 4)
    out = tmp_path / "runs"
    with FakeOpenAIServer() as server:
        for inputs in ("full", "corrupt:fog@2", "history-stale@1"):
            run("openai/gpt-4o", api_base=server.url, frames=frames, output=out, inputs=inputs, **FAST)
    evaluation = evaluate_runs([out], resampling=Resampling(n_resamples=100))
    rows = {r["ablation"]: r for r in evaluation.input_ablations}
    assert set(rows) == {"corrupt:fog@2", "history-stale@1"}
    assert all(r["model"] == "openai/gpt-4o" and r["frames"] == 4 for r in rows.values())


def test_a_corrupted_png_is_sent_as_the_jpeg_it_is(tmp_path):
    frames = make_frames(tmp_path, 1)
    png = tmp_path / "cam.png"
    Image.fromarray(textured(frames[0].image_path)).save(png)
    frames[0].image_path = str(png)
    with FakeOpenAIServer() as server:
        run(
            "openai/gpt-4o",
            api_base=server.url,
            frames=frames,
            output=tmp_path / "runs",
            inputs="corrupt:pixelate@2",
            **FAST,
        )
    urls = [
        p["image_url"]["url"]
        for r in server.requests
        for m in r.body["messages"]
        if isinstance(m["content"], list)
        for p in m["content"]
        if p.get("type") == "image_url"
    ]
    assert len(urls) == 3 and all(u.startswith("data:image/jpeg;base64,") for u in urls)
    assert Image.open(io.BytesIO(base64.b64decode(urls[0].split(",", 1)[1]))).format == "JPEG"


@pytest.mark.slow
def test_the_hf_backend_hands_the_model_the_pixels_of_the_bytes_the_api_sends(tmp_path, monkeypatch):
    """A tiny Qwen2-VL through the real hf backend: the image its processor gets is the one corrupted JPEG decoded."""
    import lightemma.backends.hf as hf_module
    from lightemma.backends.base import ChatRequest, GenerationParams
    from lightemma.backends.hf import HFBackend
    from tests.support.local_models import build_tiny_model

    frame = make_frames(tmp_path, 1)[0]
    textured(frame.image_path)
    ref = request_image(frame, "corrupt:snow@3")
    given = []

    def spy(path, max_pixels=None):
        image = load_image(path, max_pixels)
        given.append((path, np.asarray(image)))
        return image

    monkeypatch.setattr(hf_module, "load_image", spy)
    backend = HFBackend(str(build_tiny_model("qwen2_vl", tmp_path / "qwen")), dtype="float32", device="cpu")

    async def ask():
        try:
            return await backend.generate(
                [
                    ChatRequest(
                        text="Describe.",
                        stage="scene",
                        frame_id=frame.frame_id,
                        image_path=ref,
                        params=GenerationParams(max_tokens=2),
                    )
                ]
            )
        finally:
            await backend.aclose()

    assert asyncio.run(ask())[0].ok
    assert [p for p, _ in given] == [ref] and (given[0][1] == decode(read_image_bytes(ref))).all()


def test_the_vllm_backend_hands_the_engine_the_pixels_of_the_bytes_the_api_sends(tmp_path, monkeypatch):
    """vLLM's chat call (a stand-in ``vllm.LLM`` recording what it gets) receives the one corrupted JPEG decoded."""
    from lightemma.backends.base import ChatRequest, GenerationParams
    from lightemma.backends.vllm import VLLMBackend
    from tests.unit.backends.test_local_backends import FakeLLM, FakeSamplingParams, FakeStructuredOutputsParams

    module = type(sys)("vllm")
    module.LLM, module.SamplingParams, module.__version__ = FakeLLM, FakeSamplingParams, "0.32.0-fake"
    module.sampling_params = type(sys)("vllm.sampling_params")
    module.sampling_params.StructuredOutputsParams = FakeStructuredOutputsParams
    FakeLLM.instances.clear()
    monkeypatch.setitem(sys.modules, "vllm", module)
    frame = make_frames(tmp_path, 1)[0]
    textured(frame.image_path)
    ref = request_image(frame, "corrupt:jpeg@5")
    backend = VLLMBackend("Qwen/Qwen2.5-VL-7B-Instruct", batch_size=1)

    async def ask():
        try:
            return await backend.generate(
                [
                    ChatRequest(
                        text="Describe.",
                        stage="scene",
                        frame_id=frame.frame_id,
                        image_path=ref,
                        params=GenerationParams(max_tokens=4),
                    )
                ]
            )
        finally:
            await backend.aclose()

    assert asyncio.run(ask())[0].ok
    (llm,) = FakeLLM.instances
    (conversation,) = llm.calls[0][0]
    image = conversation[0]["content"][0]["image_pil"]
    assert (np.asarray(image) == decode(read_image_bytes(ref))).all()
    assert not (np.asarray(image) == decode(open(frame.image_path, "rb").read())).all()  # not the clean photo
