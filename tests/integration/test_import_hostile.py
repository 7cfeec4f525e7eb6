"""``lightemma import`` against hostile folders and signals: special files, symlinks, deep or huge JSON, killed parents."""

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from lightemma.evaluation import evaluate_runs
from lightemma.evaluation.loading import load_run
from lightemma.runs import importer, reference
from lightemma.runs.importer import import_reference
from lightemma.runs.store import read_manifest, read_run
from tests.support.processes import still_running
from tests.support.reference_fixtures import make_frame, write_scene

PYTHON_ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}


def _scene(folder: Path, name: str, seed: int, frames: int = 3) -> Path:
    rng = np.random.default_rng(seed)
    return write_scene(folder, name, [make_frame(rng, name, i) for i in range(frames)])


def _import_in_subprocess(src: Path, out: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    """The real command, in its own process, with a deadline: a hang fails the test instead of stalling it."""
    return subprocess.run(
        [sys.executable, "-m", "lightemma", "import", str(src), "--output", str(out), "--quiet"],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=PYTHON_ENV,
    )


@pytest.mark.slow
def test_special_files_and_symlinks_leaving_the_folder_are_skipped_and_named_never_read(tmp_path):
    model = tmp_path / "res" / "gpt-4o"
    _scene(model, "scene-0001", 1)
    _scene(model, "scene-0002", 2)
    out = model / "output"
    outside = _scene(tmp_path / "elsewhere", "scene-0009", 9)
    (out / "scene-0003.json").symlink_to("/dev/zero")  # the source hash read forever before
    os.mkfifo(out / "scene-0004.json")  # opening it for reading blocked forever before
    (out / "scene-0005.json").symlink_to(outside)  # a symlink leaving the model folder
    (out / "scene-0006.json").symlink_to(out / "scene-0002.json")  # one that stays inside is read
    done = _import_in_subprocess(tmp_path / "res", tmp_path / "runs")
    assert done.returncode == 0, done.stderr
    warnings = [line for line in done.stderr.splitlines() if "warning" in line]
    for name, why in (
        ("scene-0003.json", "a symlink leading outside"),
        ("scene-0004.json", "not a regular file (a FIFO)"),
        ("scene-0005.json", "a symlink leading outside"),
    ):
        (line,) = [w for w in warnings if name in w]
        assert why in line and line.endswith("file skipped")
    run_dir = next((tmp_path / "runs" / "gpt-4o").iterdir())
    manifest = read_manifest(run_dir)
    assert sorted(manifest["imported"]["files_skipped"]) == ["scene-0003.json", "scene-0004.json", "scene-0005.json"]
    assert {r["source"]["file"] for r in read_run(run_dir).records.values()} == {"scene-0001.json", "scene-0002.json"}
    assert any("scene-0006.json" in w and "already read" in w for w in warnings)  # the in-folder link was read


def test_a_device_or_fifo_swapped_in_after_listing_is_refused_without_a_read(tmp_path):
    os.mkfifo(tmp_path / "fifo")
    for path, kind in ((tmp_path / "fifo", "a FIFO"), (Path("/dev/zero"), "a character device")):
        with pytest.raises(reference.ReferenceFileError, match=f"not a regular file \\({kind}\\)"):
            reference.read_regular_file(path)


def test_a_scene_file_above_the_size_limit_is_skipped_and_named(tmp_path, monkeypatch):
    model = tmp_path / "res" / "gpt-4o"
    small = _scene(model, "scene-0001", 1, frames=1)
    big = _scene(model, "scene-0002", 2, frames=8)
    monkeypatch.setattr(reference, "MAX_SCENE_FILE_BYTES", (small.stat().st_size + big.stat().st_size) // 2)
    warnings: list[str] = []
    (result,) = import_reference([tmp_path / "res"], tmp_path / "runs", warn=warnings.append)
    assert result.frames == 1
    (line,) = warnings
    assert str(big) in line and "above the limit" in line and line.endswith("file skipped")


def _deep_and_huge(model: Path) -> tuple[Path, Path]:
    """A scene file nested 10^6 deep and one whose token count has 400 digits."""
    deep = model / "output" / "scene-0007.json"
    deep.write_text('{"frames": ' + "[" * 10**6 + "]" * 10**6 + "}")
    rng = np.random.default_rng(3)
    frame = make_frame(rng, "scene-0008", 0)
    frame["token_usage"]["scene_prompt"]["input"] = 10**400 - 1  # json.dumps writes all 400 digits
    huge = model / "output" / "scene-0008.json"
    huge.write_text(json.dumps({"frames": [frame]}))
    return deep, huge


def test_deep_or_huge_json_in_a_scene_file_skips_that_file_only(tmp_path):
    model = tmp_path / "res" / "gpt-4o"
    _scene(model, "scene-0001", 1)
    deep, huge = _deep_and_huge(model)
    warnings: list[str] = []
    (result,) = import_reference([tmp_path / "res"], tmp_path / "runs", warn=warnings.append)
    assert result.outcome == "imported" and result.frames == 3 and result.files_skipped == 2
    (deep_line,) = [w for w in warnings if str(deep) in w]
    (huge_line,) = [w for w in warnings if str(huge) in w]
    assert "nested too deeply" in deep_line and deep_line.endswith("file skipped")
    assert "integer of 400 digits" in huge_line and huge_line.endswith("file skipped")


def test_deep_or_huge_lines_of_frames_jsonl_are_named_and_skipped_the_rest_evaluated(tmp_path):
    model = tmp_path / "res" / "gpt-4o"
    _scene(model, "scene-0001", 1, frames=4)
    (result,) = import_reference([tmp_path / "res"], tmp_path / "runs")
    frames = result.run_dir / "frames.jsonl"
    lines = frames.read_text().splitlines(keepends=True)
    record = json.loads(lines[1])
    record["input_tokens"] = 10**400  # json.dumps writes all 401 digits
    lines[1] = json.dumps(record) + "\n"
    lines[2] = '{"frame_id": "scene-0001/x", "deep": ' + "[" * 10**6 + "]" * 10**6 + "}\n"
    frames.write_text("".join(lines))
    data = load_run(result.run_dir)
    assert len(data) == 2 and data.corrupt_lines == 2
    assert any("skipped 2 corrupt line(s)" in w for w in data.warnings)
    ev = evaluate_runs([tmp_path / "runs"])  # the whole command goes on
    assert ev.accuracy_rows()


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_import_workers_die_with_their_parent(tmp_path, sig):
    """The pool import_reference builds (spawned workers, _die_with_parent) with workers busy when the parent is killed."""
    script = tmp_path / "parent.py"
    script.write_text(
        textwrap.dedent("""
        import multiprocessing, os, sys, time
        from concurrent.futures import ProcessPoolExecutor
        from lightemma.runs.importer import _die_with_parent

        if __name__ == "__main__":
            context = multiprocessing.get_context("spawn")
            with ProcessPoolExecutor(max_workers=2, mp_context=context, initializer=_die_with_parent,
                                     initargs=(os.getpid(),)) as pool:
                pids = set()
                while len(pids) < 2:
                    pids |= {f.result() for f in [pool.submit(os.getpid) for _ in range(4)]}
                busy = [pool.submit(time.sleep, 120) for _ in range(2)]
                print(" ".join(map(str, sorted(pids))), flush=True)
                time.sleep(120)
    """)
    )
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True, env=PYTHON_ENV)
    try:
        workers = [int(p) for p in parent.stdout.readline().split()]
        assert len(workers) == 2 and still_running(workers, 0) == workers  # they run
        os.kill(parent.pid, sig)
        parent.wait(timeout=30)
        assert still_running(workers, 10) == []
    finally:
        parent.kill()
        parent.wait()


def test_the_parallel_import_gives_its_workers_the_parent_watch(tmp_path, monkeypatch):
    from concurrent import futures

    seen = {}
    real = futures.ProcessPoolExecutor

    def spy(*args, **kw):
        seen.update(kw)
        return real(*args, **kw)

    monkeypatch.setattr(futures, "ProcessPoolExecutor", spy)
    for k in range(2):
        _scene(tmp_path / "res" / f"model-{k}", "scene-0001", k)
    results = import_reference([tmp_path / "res"], tmp_path / "runs", jobs=2)
    assert [r.outcome for r in results] == ["imported", "imported"]
    assert seen["initializer"] is importer._die_with_parent and seen["initargs"] == (os.getpid(),)


@pytest.mark.slow
def test_a_killed_import_leaves_no_partial_folder_at_the_next_import(tmp_path):
    model = tmp_path / "res" / "gpt-4o"
    _scene(model, "scene-0001", 1)
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    runs = tmp_path / "runs" / "gpt-4o"
    stale = runs / f".ref-0123456789ab.{dead.pid}.x1y2z3.partial"
    (stale / "frames.jsonl").parent.mkdir(parents=True)
    (stale / "frames.jsonl").write_text('{"frame_id": "half')
    live = runs / f".ref-0123456789ab.{os.getppid()}.abcdef.partial"  # an import still running elsewhere
    live.mkdir()
    warnings: list[str] = []
    (result,) = import_reference([tmp_path / "res"], tmp_path / "runs", warn=warnings.append)
    assert result.outcome == "imported"
    assert not stale.exists() and live.is_dir()
    assert any(str(stale) in w and "interrupted import" in w for w in warnings)
    assert sorted(p.name for p in runs.iterdir()) == sorted([result.run_dir.name, live.name])


@pytest.mark.slow
def test_a_killed_import_really_leaves_only_what_the_next_one_removes(tmp_path):
    """SIGKILL mid-import (one process, jobs 1), then import again: one run, no hidden folder."""
    model = tmp_path / "res" / "gpt-4o"
    for k in range(40):
        _scene(model, f"scene-{k:04d}", k, frames=40)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "lightemma",
            "import",
            str(tmp_path / "res"),
            "--output",
            str(tmp_path / "runs"),
            "--quiet",
            "--jobs",
            "1",
        ],
        env=PYTHON_ENV,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    runs = tmp_path / "runs" / "gpt-4o"
    deadline = time.monotonic() + 60
    while not (runs.is_dir() and any(p.name.endswith(".partial") for p in runs.iterdir())):
        if proc.poll() is not None or time.monotonic() > deadline:
            break
        time.sleep(0.005)
    proc.kill()
    proc.wait()
    done = _import_in_subprocess(tmp_path / "res", tmp_path / "runs")
    assert done.returncode == 0, done.stderr
    assert [p.name for p in runs.iterdir() if p.name.startswith(".")] == []
    assert len([p for p in runs.iterdir()]) == 1


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_parallel_import_leaves_no_child_process_behind(tmp_path):
    for k in range(2):
        _scene(tmp_path / "res" / f"model-{k}", "scene-0001", k)
    code = textwrap.dedent(f"""
        import glob, os
        from lightemma.runs.importer import import_reference
        if __name__ == "__main__":
            results = import_reference([{str(tmp_path / "res")!r}], {str(tmp_path / "runs")!r}, jobs=2)
            assert [r.outcome for r in results] == ["imported", "imported"]
            kids = [p for f in glob.glob(f"/proc/{{os.getpid()}}/task/*/children") for p in open(f).read().split()]
            print("children:", kids)
    """)
    script = tmp_path / "parent.py"
    script.write_text(code)
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, env=PYTHON_ENV, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "children: []" in done.stdout  # workers joined, the resource tracker stopped and reaped


def test_stage_times_whose_sum_overflows_are_an_unknown_total_not_a_crash(tmp_path):
    rng = np.random.default_rng(3)
    frames = [make_frame(rng, "scene-0001", i) for i in range(2)]
    frames[0]["time_usage"] = {k: 1e308 for k in frames[0]["time_usage"]}  # each finite, their sum is not
    write_scene(tmp_path / "res" / "gpt-4o", "scene-0001", frames)
    (result,) = import_reference([tmp_path / "res"], tmp_path / "runs")
    records = sorted(read_run(result.run_dir).records.values(), key=lambda r: r["source"]["frame_index"])
    assert records[0]["seconds"] is None and records[0]["attempts"][0]["seconds"] is None
    # no call takes 1e308 s: beyond a day (records.MAX_SECONDS) each stage's own time is unknown too
    assert [c["seconds"] for c in records[0]["attempts"][0]["calls"]] == [None] * 3
    assert records[1]["seconds"] == pytest.approx(sum(frames[1]["time_usage"].values()))


def test_lone_surrogates_in_a_reference_file_become_replacement_characters_and_every_reader_works(tmp_path, capsys):
    """json.dump writes half an emoji as the escape \\ud83d, which no UTF-8 file, figure or page can hold: the import
    reads it as U+FFFD (texts, prompts, the shared prompt text in the manifest, names), and evaluate, report and
    prompts check work on the run."""
    from lightemma.cli import main
    from lightemma.runs.stored_prompts import call_prompt, frame_texts

    rng = np.random.default_rng(5)
    frames = [make_frame(rng, "scene-0001", i) for i in range(3)]
    for frame in frames:
        inference = frame["inference"]
        inference["scene_description"] = [line + " \ud83d" for line in inference["scene_description"]]
        inference["pred_actions_str"] += " \udc80"
        for key in ("scene_prompt", "intent_prompt", "waypoint_prompt"):
            inference[key] = ["Half an emoji \ud83d here."] + inference[key]
    out = tmp_path / "res" / "gpt-4o" / "output"
    out.mkdir(parents=True)
    (out / "scene-0001.json").write_text(
        json.dumps({"scene_info": {"name": "scene-0001 \ud83d"}, "frames": frames}, indent=4)
    )
    (result,) = import_reference([tmp_path / "res"], tmp_path / "runs")
    contents = read_run(result.run_dir)
    templates = contents.manifest["prompt_set"]["templates"]
    assert "Half an emoji \ufffd here." in templates["scene"][0]  # the shared text, in the manifest
    clean = lambda text: text.replace("\ud83d", "\ufffd").replace("\udc80", "\ufffd")  # noqa: E731
    for frame in frames:
        record = next(r for r in contents.records.values() if r["sample_token"] == frame["sample_token"])
        calls = record["attempts"][0]["calls"]
        assert record["scene_name"] == "scene-0001 \ufffd" and record["answer"].endswith("\ufffd")
        assert record["scene_text"] == clean(" ".join(frame["inference"]["scene_description"]))
        for call, key in zip(calls, ("scene_prompt", "intent_prompt", "waypoint_prompt")):
            assert call_prompt(call, frame_texts(calls), templates) == clean(" ".join(frame["inference"][key]))
    assert (result.run_dir / "frames.jsonl").read_bytes().decode("utf-8")  # valid UTF-8 throughout
    prompts = tmp_path / "p.json"
    prompts.write_text(
        json.dumps(
            {
                "name": "p",
                "stages": {"scene": "x {0}", "intent": "{scene} {history}", "actions": "{scene} {intent} {history}"},
            }
        )
    )
    capsys.readouterr()
    assert main(["prompts", "check", str(prompts), str(result.run_dir)]) == 1  # differences, printed without a crash
    assert "first difference" in capsys.readouterr().out
    assert main(["evaluate", str(tmp_path / "runs")]) == 0
    assert main(["report", str(tmp_path / "runs"), "--out", str(tmp_path / "report"), "--top", "2"]) == 0, (
        capsys.readouterr().err
    )


def test_folder_and_file_names_that_are_not_utf8_are_imported_with_replacement_characters(tmp_path, capsys):
    from lightemma.cli import main

    rng = np.random.default_rng(6)
    root = tmp_path / "res"
    model = Path(os.fsdecode(bytes(root) + b"/my-model-\xe9"))  # a Latin-1 name: not UTF-8
    out = model / "output"
    out.mkdir(parents=True)
    scene = Path(os.fsdecode(bytes(out) + b"/scene-\xff01.json"))
    scene.write_text(json.dumps({"frames": [make_frame(rng, "scene-0001", i) for i in range(2)]}, indent=4))
    (result,) = import_reference([root], tmp_path / "runs")
    assert result.model == "my-model-\ufffd" and result.frames == 2
    records = read_run(result.run_dir).records.values()
    assert {r["source"]["file"] for r in records} == {"scene-\ufffd01.json"} and {r["scene_name"] for r in records} == {
        "scene-\ufffd01"
    }
    assert read_manifest(result.run_dir)["imported"]["source_model"] == "my-model-\ufffd"
    capsys.readouterr()
    assert main(["evaluate", str(tmp_path / "runs")]) == 0 and "my-model-\ufffd" in capsys.readouterr().out


def test_a_file_repeating_many_frames_is_one_warning_line_with_its_count(tmp_path):
    model = tmp_path / "res" / "gpt-4o"
    original = _scene(model, "scene-0001", 1, frames=12)
    (original.parent / "scene-0002.json").write_bytes(original.read_bytes())  # a copy: every frame already read
    warnings: list[str] = []
    (folder,) = reference.find_model_folders(tmp_path / "res")
    result = importer.import_folder(folder, tmp_path / "runs", warn=warnings.append)
    repeated = [w for w in warnings if "already read" in w]
    assert len(repeated) == 1, repeated
    (line,) = repeated
    assert "scene-0002.json" in line and "12 frame(s) already read from another file (first 3:" in line
    assert result.frames == 12 and result.frames_skipped == 12
