"""Local models over Ray (``--replicas``, ``--ray-address``): routing, faults, resume — on CPU, offline.

One local Ray (2 CPUs, no dashboard, a small object store) is started for the whole module. It
declares two GPUs that this CPU machine does not have: Ray schedules by declared resources, so the
GPU paths (a GPU id per replica, a placement group for a tensor-parallel vLLM replica) run for real,
while torch finds no CUDA and the tiny models run on the CPU. The replicas are real Ray actors
holding the tiny random-weight Qwen2-VL of :mod:`local_models`; the router's logic is also tested
alone, on stand-in actor handles. These tests need the ``ray`` and ``hf`` extras and are never skipped.
"""

import asyncio
import json
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import lightemma.prompts
import lightemma.synth
from lightemma.backends.base import ChatRequest, ChatResult, GenerationParams
from lightemma.cli import main as cli_main
from lightemma.errors import RunFatalError
from lightemma.runs.store import FRAMES_FILE, read_run
from tests.support.local_models import build_tiny_model, teach_to_answer

os.environ["HF_HUB_OFFLINE"] = "1"
ROOT = Path(__file__).resolve().parents[2]
MAX_TOKENS = 24


@pytest.fixture(scope="module")
def ray_address():
    """One small local Ray for the module: its GCS address (drivers in other processes join it)."""
    import ray

    before = os.environ.get("PYTHONPATH")
    # the replicas' processes import tests.support.fake_vllm from here (they inherit this environment)
    os.environ["PYTHONPATH"] = os.pathsep.join([str(ROOT), *([before] if before else [])])
    context = ray.init(
        num_cpus=2,
        num_gpus=2,
        include_dashboard=False,
        object_store_memory=80 * 1024**2,
        log_to_driver=False,
        logging_level=logging.WARNING,
    )
    yield context.address_info["gcs_address"]
    ray.shutdown()
    if before is None:
        os.environ.pop("PYTHONPATH", None)
    else:
        os.environ["PYTHONPATH"] = before


@pytest.fixture(scope="module")
def dataroot(tmp_path_factory):
    """Four synthetic scenes (16 reference frames), each image replaced by noise of one of eight sizes, and a prompt
    set with a short scene prompt (``prompts_of(dataroot)``).

    A random-weight model barely looks at a rendered road under the long scene prompt; noise of different sizes
    (so different numbers of image tokens) under a short prompt makes its answers differ from frame to frame, so
    an answer delivered to the wrong frame would show.
    """
    root = tmp_path_factory.mktemp("synth")
    root = lightemma.synth.write_dataset(root, scenes=4, keyframes=18, image_size=(64, 48), sweeps=False)
    rng = np.random.default_rng(0)
    sizes = [(64, 48), (48, 64), (80, 48), (64, 64), (40, 40), (96, 56), (56, 40), (72, 72)]
    for i, frame in enumerate(lightemma.load_frames(root, "v1.0-mini", split="all")):
        w, h = sizes[i % len(sizes)]
        Image.fromarray(rng.integers(0, 256, (h, w, 3), dtype=np.uint8)).save(frame.image_path, quality=90)
    data = json.loads(
        (Path(lightemma.prompts.__file__).parent / f"{lightemma.prompts.DEFAULT_PROMPT_SET}.json").read_text()
    )
    data["name"], data["stages"]["scene"] = "short-scene", "Describe the scene."
    prompts_of(root).write_text(json.dumps(data))
    return root


def prompts_of(dataroot):
    return Path(dataroot) / "short-scene.json"


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    return build_tiny_model("qwen2_vl", tmp_path_factory.mktemp("qwen2_vl"))


@pytest.fixture(scope="module")
def taught(tmp_path_factory, dataroot):
    """A tiny Qwen2-VL taught to answer the short-scene prompts with "Keep the lane." and its end-of-turn token
    (so that its chains reach stage 3 instead of being cut off at stage 1)."""
    from lightemma.prompts import load_prompt_set

    prompts = load_prompt_set(str(prompts_of(dataroot)))
    frame = lightemma.load_frames(dataroot, "v1.0-mini", split="all")[0]
    history = lightemma.frames.format_history(frame.history_actions)
    said = "Keep the lane."
    texts = [
        prompts.render("scene"),
        prompts.render("intent", scene=said, history=history),
        prompts.render("actions", scene=said, history=history, intent=said),
    ]
    path = build_tiny_model("qwen2_vl", tmp_path_factory.mktemp("qwen2_vl_taught"))
    return teach_to_answer(path, said, prompts=texts, image=frame.image_path)


def frames_args(dataroot, output, limit, attempts=2):
    return [
        "--dataroot",
        str(dataroot),
        "--version",
        "v1.0-mini",
        "--split",
        "all",
        "--limit",
        str(limit),
        "--output",
        str(output),
        "--max-tokens",
        str(MAX_TOKENS),
        "--max-attempts",
        str(attempts),
        "--prompt-set",
        str(prompts_of(dataroot)),
        "--no-progress",
    ]


def answers(run_dir):
    """frame id -> every call's (stage, text, input tokens, output tokens, finish reason), in order."""
    return {
        fid: [
            (c["stage"], c["text"], c["input_tokens"], c["output_tokens"], c["finish_reason"])
            for a in r["attempts"]
            for c in a["calls"]
        ]
        for fid, r in read_run(run_dir).records.items()
    }


def only_run(output):
    (run_dir,) = [p.parent for p in Path(output).glob("*/*/manifest.json")]
    return run_dir


@pytest.fixture(scope="module")
def reference(tiny, dataroot, tmp_path_factory):
    """The same 16 frames through one in-process replica (no Ray): the answers every replica count must give."""
    output = tmp_path_factory.mktemp("reference")
    assert (
        cli_main(
            [
                "run",
                "--backend",
                "hf",
                "--model",
                str(tiny),
                "--batch-size",
                "4",
                "--dtype",
                "float32",
                *frames_args(dataroot, output, 16),
            ]
        )
        == 1
    )  # random weights: every text is cut off
    run_dir = only_run(output)
    manifest = read_run(run_dir).manifest
    assert "replicas" not in manifest["backend"] and manifest["sessions"][-1].get("replicas") is None
    got = answers(run_dir)
    assert len(got) == 16 and len({tuple(calls) for calls in got.values()}) >= 12  # frames' answers differ
    return got


# -- two replicas answer as one does --------------------------------------------------------------


@pytest.mark.slow
def test_two_replicas_give_the_same_answers_as_one_under_greedy_decoding(
    ray_address, tiny, dataroot, reference, tmp_path, capsys
):
    code = cli_main(
        [
            "run",
            "--backend",
            "hf",
            "--model",
            str(tiny),
            "--batch-size",
            "4",
            "--dtype",
            "float32",
            "--replicas",
            "2",
            "--gpus-per-replica",
            "0",
            *frames_args(dataroot, tmp_path, 16),
        ]
    )
    assert code == 1, capsys.readouterr().err
    run_dir = only_run(tmp_path)
    contents = read_run(run_dir)
    assert answers(run_dir) == reference
    assert contents.complete and contents.duplicates == 0
    assert len((run_dir / FRAMES_FILE).read_text().splitlines()) == 16
    info = contents.manifest["backend"]
    assert (info["backend"], info["replicas"], info["gpus_per_replica"], info["gpus"], info["device"]) == (
        "hf",
        2,
        0,
        0,
        "cpu",
    )
    assert info["devices_per_replica"] == {"GPU": 0, "CPU": 1}
    assert info["ray"]["version"] == __import__("ray").__version__ and len(info["ray"]["nodes"]) == 2
    assert len({n["pid"] for n in info["ray"]["nodes"]}) == 2 and os.getpid() not in {
        n["pid"] for n in info["ray"]["nodes"]
    }
    config = contents.manifest["config"]
    assert (config["replicas"], config["ray_address"], config["concurrency"]) == (2, None, 32)  # 16 frames per replica
    report = contents.manifest["sessions"][-1]["replicas"]
    assert report["frames"] == [8, 8]  # frames spread evenly...
    assert sum(report["requests"]) == sum(len(calls) for calls in reference.values())
    assert all(n > 0 for n in report["requests"])
    assert (report["deaths"], report["redispatched"], report["given_up"]) == ([0, 0], 0, 0)
    # ...and each replica batched its frames' stages: 8 frames, batches of up to 4
    assert [b["max_batch_size"] for b in report["batching"]] == [4, 4]


def test_a_frames_stages_stay_on_one_replica_and_new_frames_go_to_the_least_busy():
    router, replicas = fake_router(2)

    async def chain(frame):
        for stage in ("scene", "intent", "actions"):
            await router.answer(request(frame, stage))

    async def main():
        await asyncio.gather(*(chain(f"f{i}") for i in range(6)))

    asyncio.run(asyncio.wait_for(main(), 10))
    for replica in replicas:  # every request of a frame went to the replica that took its first
        frames = {r.frame_id for r in replica.seen}
        assert all(sum(r.frame_id == f for r in replica.seen) == 3 for f in frames)
    assert [len({r.frame_id for r in rep.seen}) for rep in replicas] == [3, 3]
    assert router.report()["frames"] == [3, 3] and router.report()["requests"] == [9, 9]


# -- faults ---------------------------------------------------------------------------------------


@pytest.mark.slow
def test_a_replica_killed_mid_run_loses_no_frame_and_duplicates_none(
    ray_address, tiny, dataroot, reference, tmp_path, monkeypatch
):
    """Replica 0 dies while it holds requests; they are re-dispatched, Ray restarts it, every frame is written once."""
    from lightemma.backends import ray as ray_backend
    from lightemma.pipeline import run

    killed = {}
    pick = ray_backend.Router._pick

    async def pick_and_kill(self, frame_id):
        replica = await pick(self, frame_id)
        zero = self.replicas[0]
        if not killed and zero.inflight >= 2:  # two requests sent to replica 0 and waiting in its batch window
            killed.update(pid=zero.where["pid"], inflight=zero.inflight)
            os.kill(zero.where["pid"], signal.SIGKILL)  # the replica's process dies, as in a crash or on a lost node
        return replica

    close = ray_backend.RayBackend.aclose

    async def close_once_restarted(self):  # wait (bounded) for Ray's restart, so the report shows it
        deadline = time.monotonic() + 120
        while self.replicas[0].state != "up" and time.monotonic() < deadline:
            await asyncio.sleep(0.2)
        await close(self)

    monkeypatch.setattr(ray_backend.Router, "_pick", pick_and_kill)
    monkeypatch.setattr(ray_backend.RayBackend, "aclose", close_once_restarted)
    result = run(
        str(tiny),
        backend="hf",
        dataroot=dataroot,
        version="v1.0-mini",
        split="all",
        limit=16,
        output=tmp_path,
        concurrency=8,
        max_tokens=MAX_TOKENS,
        max_attempts=2,
        prompt_set=str(prompts_of(dataroot)),
        progress=False,
        replicas=2,
        backend_options={"batch_size": 4, "batch_window": 0.5, "dtype": "float32"},
    )
    assert killed, "replica 0 was never killed"
    contents = read_run(result.run_dir)
    assert contents.complete and contents.duplicates == 0 and result.frames_run == 16
    assert len((result.run_dir / FRAMES_FILE).read_text().splitlines()) == 16
    assert answers(result.run_dir) == reference  # re-dispatched requests were answered as if nothing happened
    report = contents.manifest["sessions"][-1]["replicas"]
    assert report["deaths"] == [1, 0] and report["dead"] == []
    assert report["redispatched"] >= killed["inflight"] and report["given_up"] == 0
    assert report["restarts"] == [1, 0], report["events"]
    assert [e["event"] for e in report["events"]] == ["died", "restarted"]
    calls = [c for r in contents.records.values() for a in r["attempts"] for c in a["calls"]]
    assert sum(c["retries"] for c in calls) == report["redispatched"]  # each re-dispatch is on its call's record
    assert (
        contents.manifest["backend"]["ray"]["nodes"][0]["gpu_ids"]
        != contents.manifest["backend"]["ray"]["nodes"][1]["gpu_ids"]
    )


@pytest.mark.slow
def test_resume_after_the_driver_is_killed_finishes_the_run_as_before(ray_address, tiny, dataroot, reference, tmp_path):
    """A driver (2 replicas on a running cluster) is SIGKILLed mid-run; --resume finishes it, each frame written once."""
    args = [
        "--backend",
        "hf",
        "--model",
        str(tiny),
        "--batch-size",
        "4",
        "--dtype",
        "float32",
        "--replicas",
        "2",
        "--ray-address",
        ray_address,
        "--concurrency",
        "1",
        *frames_args(dataroot, tmp_path, 16),
    ]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p)}
    driver = subprocess.Popen(
        [sys.executable, "-m", "lightemma", "run", *args],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 300
        frames_file = None
        while time.monotonic() < deadline and driver.poll() is None:
            found = list(tmp_path.glob(f"*/*/{FRAMES_FILE}"))
            if found and found[0].read_text().count("\n") >= 1:
                frames_file = found[0]
                break
            time.sleep(0.02)
        os.kill(driver.pid, signal.SIGKILL)
    finally:
        driver.kill()
        err = driver.communicate()[1].decode(errors="replace")
    assert frames_file is not None, err
    run_dir = frames_file.parent
    before = read_run(run_dir)
    assert 1 <= len(before.records) < 16 and not before.complete, "the driver finished before it was killed"
    # the run's cluster is joined again only when the user names one (a manifest does not choose where the model runs)
    assert cli_main(["run", "--resume", str(run_dir), "--replicas", "1", "--no-progress"]) == 2
    assert read_run(run_dir).records == before.records
    # the same cluster, named; with one replica this time (where the model runs may change on a resume)
    assert (
        cli_main(["run", "--resume", str(run_dir), "--replicas", "1", "--ray-address", ray_address, "--no-progress"])
        == 1
    )
    after = read_run(run_dir)
    assert after.complete and after.duplicates == 0 and len(after.records) == 16
    assert answers(run_dir) == reference
    for fid, record in before.records.items():  # what the killed driver wrote stays as it was
        assert after.records[fid] == record
    sessions = after.manifest["sessions"]
    assert [s["kind"] for s in sessions] == ["run", "resume"] and sessions[-1]["frames_run"] == 16 - len(before.records)
    assert after.manifest["backend"]["ray"]["cluster"] == "joined" and after.manifest["config"]["replicas"] == 2
    assert sessions[-1]["replicas"]["replicas"] == 1 and sum(sessions[-1]["replicas"]["frames"]) == 16 - len(
        before.records
    )


@pytest.mark.slow
def test_a_replica_whose_model_fails_every_batch_identically_stops_the_run_in_one_line(
    ray_address, tiny, dataroot, tmp_path, capsys
):
    """A broken checkpoint (no chat template) fails each batch the same way: the replica's run-fatal rule stops the run."""
    import shutil

    broken = shutil.copytree(tiny, tmp_path / "broken")
    (broken / "chat_template.jinja").unlink()
    code = cli_main(
        [
            "run",
            "--backend",
            "hf",
            "--model",
            str(broken),
            "--batch-size",
            "1",
            "--dtype",
            "float32",
            "--ray-address",
            ray_address,
            *frames_args(dataroot, tmp_path / "out", 4),
        ]
    )  # one replica, on Ray
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "error:" in line]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert "cannot generate with qwen2_vl: ValueError: Cannot use apply_chat_template" in lines[0]
    assert "--resume" in lines[0]
    stopped = read_run(only_run(tmp_path / "out"))
    assert stopped.records == {} and stopped.manifest["sessions"][-1]["stopped"]["cause"] == "local-model"


@pytest.mark.slow
def test_timeout_reaches_every_replica_and_a_model_past_it_stops_the_run_in_one_line(
    ray_address, tiny, dataroot, tmp_path, capsys
):
    """--timeout is each replica's deadline per batch: a random-weight model asked for 10^6 tokens never ends its answer,
    so every batch of every replica stops at the deadline (``Timeout``) and the replicas' run-fatal rule stops the run."""
    args = frames_args(dataroot, tmp_path / "out", 4)
    args[args.index("--max-tokens") + 1] = "1000000"
    start = time.monotonic()
    code = cli_main(
        [
            "run",
            "--backend",
            "hf",
            "--model",
            str(tiny),
            "--batch-size",
            "1",
            "--dtype",
            "float32",
            "--replicas",
            "2",
            "--gpus-per-replica",
            "0",
            "--ray-address",
            ray_address,
            "--timeout",
            "1",
            *args,
        ]
    )
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "error:" in line]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert "runs past --timeout 1 s" in lines[0] and "--resume" in lines[0], lines
    assert time.monotonic() - start < 300  # stopped, not generating 10^6 tokens
    stopped = read_run(only_run(tmp_path / "out"))
    assert stopped.manifest["sessions"][-1]["stopped"]["error"] == "Timeout"
    calls = [c for r in stopped.records.values() for a in r["attempts"] for c in a["calls"]]
    assert all(c["error"] == "Timeout" for c in calls)


@pytest.mark.slow
def test_replicas_that_cannot_build_the_model_are_one_line_before_any_run_directory(
    ray_address, dataroot, tmp_path, capsys
):
    code = cli_main(
        [
            "run",
            "--backend",
            "vllm",
            "--model",
            "Qwen/Qwen2.5-VL-7B-Instruct",
            "--replicas",
            "2",
            *frames_args(dataroot, tmp_path / "out", 4),
        ]
    )
    err = capsys.readouterr().err  # vLLM is not installed here: the replicas say so, in one line
    assert code == 2 and "pip install 'lightemma[vllm]'" in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "out").exists()


def test_requests_of_a_dead_replica_go_to_the_others_and_it_returns_after_its_restart():
    router, (zero, one) = fake_router(2)
    zero.die_on_call = 1  # its first request finds it dead; Ray restarts it after two "unavailable" probes
    zero.unavailable_probes = 2

    async def main():
        first = await router.answer(request("a", "scene"))
        while zero.state_seen != "restarted":
            await asyncio.sleep(0.01)
        await asyncio.sleep(0.05)
        later = [await router.answer(request(f, "scene")) for f in ("b", "c")]
        await router.stop()
        return first, later

    first, later = asyncio.run(asyncio.wait_for(main(), 10))
    assert (first.text, first.retries) == ("one:a:scene", 1)  # answered by replica 1, one re-dispatch on the record
    assert {r.text.split(":")[0] for r in later} == {"zero", "one"}  # replica 0 takes frames again once restarted
    report = router.report()
    assert (report["deaths"], report["restarts"], report["redispatched"]) == ([1, 0], [1, 0], 1)
    assert [e["event"] for e in report["events"]] == ["died", "restarted"]


def test_a_request_whose_replicas_keep_dying_fails_alone_and_all_replicas_dead_stops_the_run():
    from lightemma.backends.ray import MAX_SENDS

    router, replicas = fake_router(3)
    for replica in replicas:
        replica.die_on_call = 1
        replica.unavailable_probes = 10**6  # restarting for ever
    result = asyncio.run(asyncio.wait_for(_answer_and_stop(router, request("poison", "scene")), 10))
    assert (result.ok, result.error, result.retries) == (False, "ReplicaDied", MAX_SENDS - 1)
    assert "died 3 times" in result.error_message and router.report()["given_up"] == 1

    router, replicas = fake_router(2)
    for replica in replicas:
        replica.die_on_call, replica.dead_for_good = 1, True
    with pytest.raises(RunFatalError, match="all 2 model replicas died") as caught:
        asyncio.run(asyncio.wait_for(_answer_and_stop(router, request("a", "scene")), 10))
    assert caught.value.cause == "local-model"


def test_a_replicas_run_fatal_finding_is_raised_on_the_driver():
    from lightemma.backends.ray import _Fatal

    router, (zero,) = fake_router(1)
    zero.fatal = _Fatal("transformers 9 cannot generate with qwen2_vl: ValueError: x", "local-model", "ValueError")
    with pytest.raises(RunFatalError, match="cannot generate with qwen2_vl") as caught:
        asyncio.run(_answer_and_stop(router, request("a", "scene")))
    assert (caught.value.cause, caught.value.error) == ("local-model", "ValueError")


@pytest.mark.slow
def test_more_replicas_than_the_cluster_can_place_are_refused_at_once(ray_address, tiny, dataroot, tmp_path, capsys):
    """The module's cluster has 2 CPUs and 2 GPUs: 3 one-GPU replicas, or 3 one-CPU ones, can never be placed."""
    for extra, what in (
        (["--replicas", "3"], "needs 3 GPUs; the Ray cluster"),
        (["--replicas", "3", "--gpus-per-replica", "0"], "needs 3 CPUs; the Ray cluster"),
    ):
        code = cli_main(
            ["run", "--backend", "hf", "--model", str(tiny), *extra, *frames_args(dataroot, tmp_path / "out", 4)]
        )
        err = capsys.readouterr().err
        assert code == 2 and what in err and f"{ray_address}) has 2" in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_structured_answers_run_through_replicas(ray_address, taught, dataroot, tmp_path, capsys):
    """Each replica constrains stage 3 with its own xgrammar processor; the manifest says how, and the answers obey."""
    code = cli_main(
        [
            "run",
            "--backend",
            "hf",
            "--model",
            str(taught),
            "--batch-size",
            "4",
            "--dtype",
            "float32",
            "--replicas",
            "2",
            "--gpus-per-replica",
            "0",
            "--answer-format",
            "structured",
            *frames_args(dataroot, tmp_path, 4, attempts=1),
            "--max-tokens",
            "160",
        ]
    )
    err = capsys.readouterr().err
    assert code in (0, 1), err
    (run_dir,) = [p.parent for p in tmp_path.glob("*/*/manifest.json")]
    contents = read_run(run_dir)
    how = contents.manifest["structured_output"]
    assert (
        how["mechanism"].startswith("xgrammar")
        and how["replicas"] == "each of the 2 replicas constrains its own answers"
    )
    assert len(contents.records) == 4
    stage3 = [
        a["answer"]
        for r in contents.records.values()
        for a in r["attempts"]
        if a["answer"] is not None and a["calls"][-1]["stage"] == "actions"
    ]
    assert stage3
    for answer in stage3:
        assert len(json.loads(answer)["actions"]) == 6, answer


@pytest.mark.slow
def test_structured_answers_are_refused_before_any_run_when_a_replica_cannot_constrain(
    ray_address, tiny, dataroot, tmp_path, capsys, monkeypatch
):
    from lightemma.backends import ray as ray_backend

    async def refuse(self):
        return {"ok": False, "message": "--answer-format structured: xgrammar is not installed on this node"}

    monkeypatch.setattr(ray_backend.ReplicaServer, "structured_output", refuse)
    code = cli_main(
        [
            "run",
            "--backend",
            "hf",
            "--model",
            str(tiny),
            "--replicas",
            "2",
            "--gpus-per-replica",
            "0",
            "--answer-format",
            "structured",
            *frames_args(dataroot, tmp_path / "out", 4),
        ]
    )
    err = capsys.readouterr().err
    assert code == 2 and "xgrammar is not installed on this node" in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").glob("*/*/records.jsonl"))


# -- vLLM replicas: tensor parallel through a placement group --------------------------------------


@pytest.mark.slow
def test_a_tensor_parallel_vllm_replica_gets_a_placement_group_and_vllms_ray_executor(ray_address, dataroot, tmp_path):
    from lightemma.pipeline import run

    result = run(
        "Qwen/Qwen2.5-VL-7B-Instruct",
        backend="vllm",
        dataroot=dataroot,
        version="v1.0-mini",
        split="all",
        limit=4,
        output=tmp_path / "out",
        progress=False,
        ray_address=ray_address,
        backend_options={"vllm": "tests.support.fake_vllm", "tensor_parallel_size": 2, "batch_size": 4},
    )  # a stand-in engine
    contents = read_run(result.run_dir)
    assert contents.complete and all(r["status"] == "ok" for r in contents.records.values())
    info = contents.manifest["backend"]
    assert (info["backend"], info["replicas"], info["gpus"], info["gpus_per_replica"]) == ("vllm", 1, 2, 2)
    assert info["engine"]["distributed_executor_backend"] == "ray" and info["engine"]["tensor_parallel_size"] == 2
    assert info["devices_per_replica"] == {"GPU": 2, "CPU": 2}
    (node,) = info["ray"]["nodes"]
    assert (
        node["placement_group"] and node["gpu_ids"] == []
    )  # the replica sits in its group; vLLM's workers take the GPUs
    assert (
        "placement group" in info["ray"]["placement"]
        and info["ray"]["cluster"] == "the Ray already initialised in this process"
    )


# -- the command line -----------------------------------------------------------------------------


@pytest.mark.parametrize("model", ["baseline:cv", "openai/gpt-4o"])
def test_replicas_are_refused_for_api_models_and_baselines_in_one_line(model, dataroot, tmp_path, capsys):
    extra = ["--api-base", "http://127.0.0.1:9/v1"] if model.startswith("openai") else []
    code = cli_main(["run", "--model", model, *extra, "--replicas", "2", *frames_args(dataroot, tmp_path, 4)])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "--replicas" in err and "--backend hf or vllm" in err and not list(tmp_path.iterdir())


@pytest.mark.slow
def test_one_replica_without_an_address_runs_in_process_and_needs_no_ray(tiny, dataroot, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # as if the ray extra were not installed
    assert (
        cli_main(
            [
                "run",
                "--backend",
                "hf",
                "--model",
                str(tiny),
                "--replicas",
                "1",
                "--dtype",
                "float32",
                *frames_args(dataroot, tmp_path / "one", 4, attempts=1),
            ]
        )
        == 1
    )
    assert "replicas" not in read_run(only_run(tmp_path / "one")).manifest["backend"]
    capsys.readouterr()
    code = cli_main(
        ["run", "--backend", "hf", "--model", str(tiny), "--replicas", "2", *frames_args(dataroot, tmp_path / "two", 4)]
    )
    err = capsys.readouterr().err
    assert code == 2 and "pip install 'lightemma[ray]'" in err and len(err.strip().splitlines()) == 1, err


def test_replica_flags_are_checked_and_resume_takes_them(dataroot, tmp_path, capsys):
    assert (
        cli_main(["run", "--backend", "hf", "--model", "m", "--replicas", "0", *frames_args(dataroot, tmp_path, 4)])
        == 2
    )
    assert "--replicas must be at least 1" in capsys.readouterr().err
    assert (
        cli_main(
            [
                "run",
                "--backend",
                "vllm",
                "--model",
                "m",
                "--replicas",
                "2",
                "--gpus-per-replica",
                "1",
                *frames_args(dataroot, tmp_path, 4),
            ]
        )
        == 2
    )
    assert "--gpus-per-replica is for --backend hf" in capsys.readouterr().err
    assert (
        cli_main(
            ["run", "--backend", "hf", "--model", "m", "--gpus-per-replica", "1", *frames_args(dataroot, tmp_path, 4)]
        )
        == 2
    )
    assert "goes with --replicas" in capsys.readouterr().err
    # --resume refuses run settings, but takes where the model runs
    assert cli_main(["run", "--resume", str(tmp_path / "nope"), "--replicas", "2", "--max-tokens", "5"]) == 2
    err = capsys.readouterr().err
    assert "drop --max-tokens" in err and "--replicas" not in err


# -- stand-in actor handles for the router --------------------------------------------------------


def request(frame, stage):
    return ChatRequest(text=f"{stage} of {frame}", stage=stage, frame_id=frame, params=GenerationParams(max_tokens=4))


class _Method:
    def __init__(self, fn):
        self._fn = fn

    def remote(self, *args):
        return asyncio.ensure_future(self._fn(*args))


class FakeHandle:
    """Answers like a replica ("<name>:<frame>:<stage>"); can die on its Nth call and come back after some probes."""

    def __init__(self, name):
        from ray import exceptions

        self.name, self.errors, self.seen, self.calls = name, exceptions, [], 0
        self.die_on_call, self.unavailable_probes, self.dead_for_good = None, 0, False
        self.fatal, self.down, self.state_seen = None, False, "up"
        self.generate, self.ready = _Method(self._generate), _Method(self._ready)

    async def _generate(self, requests):
        await asyncio.sleep(0.01)
        self.calls += 1
        if self.down or self.calls == self.die_on_call:
            self.down = True
            raise self.errors.ActorUnavailableError(f"replica {self.name} is restarting", None)
        if self.fatal is not None:
            return self.fatal
        self.seen.extend(requests)
        return [ChatResult(text=f"{self.name}:{r.frame_id}:{r.stage}", finish_reason="stop") for r in requests]

    async def _ready(self):
        await asyncio.sleep(0.01)
        if self.dead_for_good:
            raise self.errors.ActorDiedError()
        if self.unavailable_probes > 0:
            self.unavailable_probes -= 1
            raise self.errors.ActorUnavailableError("restarting", None)
        self.down, self.state_seen = False, "restarted"
        return {"ok": True, "where": {"pid": 2}}


def fake_router(n):
    from lightemma.backends.ray import Replica, Router

    names = ["zero", "one", "two", "three"][:n]
    handles = [FakeHandle(name) for name in names]
    return Router([Replica(i, h) for i, h in enumerate(handles)], probe_interval=0.01), handles


async def _answer_and_stop(router, req):
    try:
        return await router.answer(req)
    finally:
        await router.stop()


def test_vllm_pipeline_parallelism_passes_through_and_counts_its_gpus(dataroot, tmp_path, capsys):
    from lightemma.backends.vllm import VLLMBackend

    backend = VLLMBackend(
        "Qwen/Qwen2.5-VL-7B-Instruct", vllm="tests.support.fake_vllm", tensor_parallel_size=2, pipeline_parallel_size=2
    )
    assert (
        backend._llm.engine_kwargs["pipeline_parallel_size"] == 2
        and backend._llm.engine_kwargs["tensor_parallel_size"] == 2
    )
    assert (backend.info["gpus"], backend.info["pipeline_parallel_size"]) == (4, 2)
    asyncio.run(backend.aclose())
    assert (
        cli_main(
            [
                "run",
                "--backend",
                "hf",
                "--model",
                "m",
                "--pipeline-parallel-size",
                "2",
                *frames_args(dataroot, tmp_path, 4),
            ]
        )
        == 2
    )
    assert "--pipeline-parallel-size do(es) not apply to the hf backend" in capsys.readouterr().err


@pytest.mark.slow
def test_replicas_make_each_frames_blank_image_themselves(ray_address, tiny, dataroot, reference, tmp_path, capsys):
    """--inputs blank-image through replicas: each replica draws the grey image from the frame's size (no file sent), so
    a frame's image costs the tokens its photo does, while what the model sees (and says) changes."""
    code = cli_main(
        [
            "run",
            "--backend",
            "hf",
            "--model",
            str(tiny),
            "--batch-size",
            "4",
            "--dtype",
            "float32",
            "--replicas",
            "2",
            "--gpus-per-replica",
            "0",
            "--inputs",
            "blank-image",
            *frames_args(dataroot, tmp_path, 4, attempts=1),
        ]
    )
    assert code == 1, capsys.readouterr().err  # random weights: every text is cut off
    run_dir = only_run(tmp_path)
    assert read_run(run_dir).manifest["config"]["inputs"] == "blank-image"
    got = answers(run_dir)
    assert len(got) == 4
    for fid, calls in got.items():
        assert calls[0][0] == "scene" and calls[0][2] == reference[fid][0][2]  # the same image tokens as the photo
    assert any(calls[0][1] != reference[fid][0][1] for fid, calls in got.items())  # but not the photo
