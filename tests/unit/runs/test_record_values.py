"""A record's numbers and kinds: bounded where they are written (import, response cache, store), checked where read.

A token count is a whole number 0..10^9, a time 0..30 days, a cost 0..10^9 cents, a ground-truth position within
10^5 m (lightemma.runs.records). Beyond: written as unknown (null) with one warning, never an integer the readers
refuse; a line of frames.jsonl of the wrong kinds is named in a warning and skipped, never a traceback.
"""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import numpy as np
import pytest

from lightemma.cache import ResponseCache
from lightemma.evaluation.loading import load_run
from lightemma.pipeline import run
from lightemma.runs import records
from lightemma.runs.columns import SIDECAR_FILE
from lightemma.runs.importer import import_reference
from lightemma.runs.store import FRAMES_FILE, RunWriter, encode_line, read_run
from tests.support.fake_openai import FakeOpenAIServer
from tests.support.memframes import make_frames
from tests.support.reference_fixtures import make_frame, write_scene

FAST = dict(backoff_base=0.01, backoff_cap=0.05, timeout=10.0, progress=False)


# -- A: import and the store write no number the readers refuse ------------------------------------------


def _import_huge_tokens(tmp_path: Path) -> tuple[Path, list[str]]:
    rng = np.random.default_rng(0)
    frames = [make_frame(rng, "scene-0001", i) for i in range(3)]
    frames[1]["token_usage"]["waypoint_prompt"]["input"] = 1e308
    frames[2]["token_usage"] = {
        "scene_prompt": {"input": -5, "output": "x"},
        "intent_prompt": [],
        "waypoint_prompt": {"input": 1e308, "output": float("inf")},
    }
    frames[0]["time_usage"]["waypoint_prompt"] = 1e300  # no call takes 10^300 s
    write_scene(tmp_path / "res" / "gpt-4o", "scene-0001", frames)
    warnings: list[str] = []
    (result,) = import_reference([tmp_path / "res"], tmp_path / "runs", warn=warnings.append)
    return result.run_dir, warnings


def test_import_records_a_token_count_of_1e308_as_unknown_with_one_warning_and_evaluate_keeps_every_frame(tmp_path):
    run_dir, warnings = _import_huge_tokens(tmp_path)
    lines = (run_dir / FRAMES_FILE).read_bytes().splitlines()
    assert len(lines) == 3
    for line in lines:
        record = records.loads_bounded(line)  # no 309-digit integer: the reader takes every line
        assert records.record_problem(record) is None
        for call in record["attempts"][0]["calls"]:
            assert call["input_tokens"] is None or 0 <= call["input_tokens"] <= records.MAX_TOKENS
            assert call["seconds"] is None or 0 <= call["seconds"] <= records.MAX_SECONDS
    by_frame = {r["frame_id"]: r for r in map(records.loads_bounded, lines)}
    assert sum(r["input_tokens"] is None for r in by_frame.values()) == 2
    assert sum(r["seconds"] is None for r in by_frame.values()) == 1
    (line,) = [w for w in warnings if "unreadable" in w]
    assert "scene-0001.json" in line and "recorded as unknown" in line
    # the sidecar written by the import and frames.jsonl read afresh agree: 3 frames, no corrupt line
    with_sidecar = load_run(run_dir)
    (run_dir / SIDECAR_FILE).unlink()
    fresh = load_run(run_dir, sidecar=False)
    for data in (with_sidecar, fresh):
        assert len(data) == 3 and data.corrupt_lines == 0, data.warnings
        assert np.nanmax(data.input_tokens) <= records.MAX_TOKENS
        assert np.nanmax(data.seconds) <= records.MAX_SECONDS


def test_the_store_never_writes_an_integer_the_reader_refuses(tmp_path):
    big = 9223372036854775807 * 3  # three int64-max counts summed: 20 digits
    record = {
        "frame_id": "s/a",
        "status": "ok",
        "input_tokens": big,
        "output_tokens": -4,
        "seconds": float("1e300"),
        "cost_cents": 1.5,
        "timestamp": 10**30,
        "attempts": [
            {
                "status": "ok",
                "answer": "x",
                "input_tokens": big,
                "calls": [{"output_tokens": 2**63 - 1, "seconds": 2.0}],
            }
        ],
    }
    problems: list[str] = []
    line = encode_line(record, problems)
    back = records.loads_bounded(line)
    assert records.record_problem(back) is None
    assert (back["input_tokens"], back["output_tokens"], back["seconds"], back["cost_cents"]) == (None, None, None, 1.5)
    assert back["timestamp"] is None and back["attempts"][0]["input_tokens"] is None
    assert back["attempts"][0]["calls"][0] == {"output_tokens": None, "seconds": 2.0}
    assert record["input_tokens"] == big  # the caller's record is left as it was
    assert any("input_tokens" in p for p in problems) and any("digits" in p for p in problems)
    # a writer says so once, naming the file and the frame
    (tmp_path / FRAMES_FILE).touch()
    said: list[str] = []
    with RunWriter(tmp_path, log=said.append) as writer:
        writer.append(record)
        writer.append({**record, "frame_id": "s/b"})
    assert len(said) == 1 and "'s/a'" in said[0] and FRAMES_FILE in said[0] and writer.unknown_values == 2
    assert len(read_run_records(tmp_path)) == 2


def read_run_records(run_dir: Path) -> list[dict]:
    return [records.loads_bounded(line) for line in (run_dir / FRAMES_FILE).read_bytes().splitlines()]


def test_an_ordinary_record_is_written_unchanged():
    record = {
        "frame_id": "s/a",
        "status": "ok",
        "input_tokens": 1200,
        "seconds": 3.25,
        "cost_cents": 0.4,
        "timestamp": 1533151603547590,
        "attempts": [
            {"status": "ok", "answer": "x", "calls": [{"input_tokens": 400, "seconds": 1.0, "cost_cents": None}]}
        ],
    }
    assert records.bounded_values(record) is record
    assert json.loads(encode_line(record)) == record


# -- B: a response-cache row of the wrong kind or out of range is a miss --------------------------------


@pytest.mark.parametrize(
    "update",
    [
        "text = X'FFFE00'",  # a BLOB: AttributeError: 'bytes' object has no attribute 'encode' before
        "text = CAST(X'FFFE00' AS TEXT)",  # TEXT that is not UTF-8
        "input_tokens = 9223372036854775807, output_tokens = 9223372036854775807",  # records the run could not read back
        "output_tokens = -7",  # replayed as it was before
        "input_tokens = 'many'",
        "cost_cents = -1.0",
    ],
)
def test_a_bad_cache_row_is_a_miss_said_once_and_replaced(tmp_path, update):
    frames = make_frames(tmp_path, 2)
    path = tmp_path / "cache.sqlite"
    lines: list[str] = []
    with FakeOpenAIServer() as server:  # one server: its address is part of the cache key
        seeded = run(
            "openai/test-model", frames=frames, api_base=server.url, output=tmp_path / "seed", cache=str(path), **FAST
        )
        assert seeded.summary["ok"] == 2 and len(server.requests) == 6
        db = sqlite3.connect(path)
        db.execute(f"UPDATE responses SET {update}")
        db.commit()
        db.close()
        result = run(
            "openai/test-model",
            frames=frames,
            api_base=server.url,
            output=tmp_path / "out",
            cache=str(path),
            log=lines.append,
            **FAST,
        )
        asked = len(server.requests) - 6
        again = run(
            "openai/test-model", frames=frames, api_base=server.url, output=tmp_path / "again", cache=str(path), **FAST
        )
        assert len(server.requests) - 6 == asked  # the rows were replaced: the third run is served from the cache
    assert asked == 6  # every call made again (2 frames × 3 stages)
    warned = [line for line in lines if "response cache" in line]
    assert len(warned) == 1 and "no answer" in warned[0], lines
    assert result.summary["frames"] == 2 and result.summary["ok"] == 2
    contents = read_run(result.run_dir)
    assert not contents.corrupt_lines and len(contents.records) == 2
    for record in contents.records.values():
        assert 0 <= record["input_tokens"] <= records.MAX_TOKENS and 0 <= record["output_tokens"] <= records.MAX_TOKENS
        assert not record["cached"]
    assert again.summary["ok"] == 2 and all(r["cached"] for r in read_run(again.run_dir).records.values())


def test_a_cache_row_read_directly_is_checked(tmp_path):
    cache = ResponseCache(tmp_path / "c.sqlite", log=lambda line: None)
    cache.put("good", "m", "text", 10, 5, 0.1)
    cache.put("blob", "m", "text", 10, 5, 0.1)
    cache.put("huge", "m", "text", 2**63 - 1, 5, 0.1)
    cache._db.execute("UPDATE responses SET text = X'00FF' WHERE key = 'blob'")
    assert cache.get("good") == {"text": "text", "input_tokens": 10, "output_tokens": 5, "cost_cents": 0.1}
    assert cache.get("blob") is None and cache.get("huge") is None and cache.bad_rows == 2
    cache.close()


# -- C: a line of frames.jsonl of the wrong kinds is named and skipped ---------------------------------------


@pytest.fixture
def imported_run(tmp_path) -> Path:
    rng = np.random.default_rng(3)
    write_scene(tmp_path / "res" / "gpt-4o", "scene-0001", [make_frame(rng, "scene-0001", i) for i in range(3)])
    (result,) = import_reference([tmp_path / "res"], tmp_path / "runs", warn=lambda line: None)
    return result.run_dir


def _rewrite_second(run_dir: Path, **fields) -> None:
    path = run_dir / FRAMES_FILE
    lines = path.read_bytes().splitlines()
    record = json.loads(lines[1])
    record.update(fields)
    lines[1] = json.dumps(record).encode()
    path.write_bytes(b"\n".join(lines) + b"\n")
    (run_dir / SIDECAR_FILE).unlink(missing_ok=True)


@pytest.mark.parametrize(
    "fields, named",
    [
        ({"status": ["ok"]}, "status"),  # TypeError: unhashable type: 'list' before
        ({"first_status": {"a": 1}}, "first_status"),
        ({"seconds": -1e308}, "seconds"),  # report: math domain error before
        ({"seconds": "fast"}, "seconds"),
        ({"input_tokens": 1e300}, "input_tokens"),
        ({"cost_cents": -2}, "cost_cents"),
        ({"failure": [1]}, "failure"),
    ],
)
def test_a_record_of_the_wrong_kinds_is_named_and_skipped(imported_run, fields, named):
    _rewrite_second(imported_run, **fields)
    for sidecar in (True, False, True):  # written from frames.jsonl, then read back from the sidecar: the same
        data = load_run(imported_run, sidecar=sidecar)
        assert len(data) == 2 and data.corrupt_lines == 1
        (line,) = [w for w in data.warnings if "corrupt line" in w]
        assert "line 2" in line and named in line
    contents = read_run(imported_run)
    assert len(contents.records) == 2 and any("line 2" in w and named in w for w in contents.warnings())


def test_evaluate_and_report_of_a_bad_status_and_a_huge_negative_time_say_so_without_a_traceback(
    imported_run, tmp_path, capsys
):
    from lightemma.cli import main

    _rewrite_second(imported_run, status=["ok"], seconds=-1e308)
    assert main(["evaluate", str(imported_run)]) == 0
    err = capsys.readouterr().err
    assert "Traceback" not in err and "skipped 1 corrupt line(s)" in err


def test_ground_truth_beyond_the_position_bound_is_no_usable_ground_truth_and_warns_nothing_from_numpy(imported_run):
    _rewrite_second(imported_run, gt_positions=[[1e308, 1e308]] * 6)
    with np.errstate(all="raise"):  # an overflow (1e308 squared) would raise here
        from lightemma.evaluation import evaluate_runs

        data = load_run(imported_run, sidecar=False)
        assert data.bad_records == 1 and not data.valid[1]
        assert any("without usable ground truth" in w for w in data.warnings)
        evaluate_runs([imported_run])


def test_a_line_longer_than_the_limit_is_skipped_unread_and_named(imported_run, monkeypatch):
    """A line of frames.jsonl over MAX_LINE_BYTES (an 8 GB line of NUL bytes was read whole: MemoryError) is skipped
    a chunk at a time and named; the lines after it are read."""
    from lightemma.runs import store

    path = imported_run / FRAMES_FILE
    lines = path.read_bytes().splitlines(keepends=True)
    limit = max(len(line) for line in lines) + 10
    monkeypatch.setattr(store, "MAX_LINE_BYTES", limit)
    path.write_bytes(lines[0] + b"\0" * (3 * limit) + b"\n" + b"".join(lines[1:]))
    contents = read_run(imported_run)
    assert len(contents.records) == 3 and contents.corrupt_lines == [2] and not contents.truncated_tail
    assert any(f"line 2: longer than {limit:,} bytes" in w for w in contents.warnings())
    path.write_bytes(b"".join(lines) + b"\0" * (3 * limit))  # a last line that long, without its newline: a cut tail
    contents = read_run(imported_run)
    assert len(contents.records) == 3 and contents.truncated_tail and not contents.corrupt_lines
