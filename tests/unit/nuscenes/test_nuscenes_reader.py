"""lightemma.nuscenes is the only reader of a dataroot (issue 31 item 6).

Every file under a dataroot that a frame load or an evaluation (ADE, safety, planning score) opens is opened by a
module of ``lightemma.nuscenes`` (the low-level bounded reader ``lightemma._files`` counts as its caller's); the
evaluation and the planning score receive what it parsed. Checked at run time, by wrapping ``open`` / ``io.open`` /
``os.open`` during the work, and statically, by scanning ``evaluation/`` and ``planning/`` for file reads of a
dataroot-derived name. The one table reader's refusals hold for every table any part reads.
"""

from __future__ import annotations

import ast
import builtins
import io
import json
import os
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

import lightemma
from lightemma.errors import DatasetError

VERSION = "v1.0-mini"
PACKAGE = Path(lightemma.__file__).parent


def _opener(stack_frame) -> str | None:
    """The lightemma module that asked for a file: the innermost lightemma frame that is not the bounded reader."""
    frame = stack_frame
    while frame is not None:
        name = frame.f_globals.get("__name__", "")
        if name.startswith("lightemma") and name != "lightemma._files":
            return name
        frame = frame.f_back
    return None


class _Opens:
    """Records (module, path) of every open of a path under ``root`` while active."""

    def __init__(self, root: Path) -> None:
        self.root = os.path.realpath(root)
        self.seen: list[tuple[str | None, str]] = []

    def _note(self, file) -> None:
        if isinstance(file, (str, bytes, os.PathLike)):
            path = os.fsdecode(os.fspath(file))
            real = os.path.realpath(path)
            if real == self.root or real.startswith(self.root + os.sep):
                self.seen.append((_opener(sys._getframe(2)), path))

    def __enter__(self) -> _Opens:
        self.saved = (builtins.open, io.open, os.open)
        real_open, real_io_open, real_os_open = self.saved

        def wrapped_open(file, *args, **kwargs):
            self._note(file)
            return real_open(file, *args, **kwargs)

        def wrapped_io_open(file, *args, **kwargs):
            self._note(file)
            return real_io_open(file, *args, **kwargs)

        def wrapped_os_open(path, *args, **kwargs):
            self._note(path)
            return real_os_open(path, *args, **kwargs)

        builtins.open, io.open, os.open = wrapped_open, wrapped_io_open, wrapped_os_open
        return self

    def __exit__(self, *exc) -> None:
        builtins.open, io.open, os.open = self.saved

    def outside(self) -> list[tuple[str | None, str]]:
        return [(m, p) for m, p in self.seen if not (m or "").startswith("lightemma.nuscenes")]


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    from lightemma.cli import main
    from lightemma.runs.store import find_run_dirs
    from lightemma.synth import write_dataset

    base = tmp_path_factory.mktemp("nuscenes_reader")
    root = write_dataset(base / "data", scenes=8, keyframes=22, image_size=(64, 36), sweeps=False)
    assert (
        main(
            [
                "run",
                "--model",
                "baseline:cv",
                "--dataroot",
                str(root),
                "--version",
                VERSION,
                "--split",
                "all",
                "--out",
                str(base / "runs"),
            ]
        )
        == 0
    )
    return base, Path(root), find_run_dirs(base / "runs")[0]


def _evaluate(run_dir: Path, root: Path):
    from lightemma.evaluation import evaluate_loaded, load_run
    from lightemma.evaluation.stats import Resampling

    return evaluate_loaded(
        [load_run(run_dir)],
        resampling=Resampling(n_resamples=0),
        dataroot=root,
        version=VERSION,
        safety=True,
        planning=True,
    )


def test_only_lightemma_nuscenes_opens_files_under_the_dataroot(world, tmp_path):
    base, root, run_dir = world
    masks_only = tmp_path / "masks"  # no map expansion: the drivable area comes from the base map masks (PNG)
    shutil.copytree(root, masks_only, ignore=shutil.ignore_patterns("samples", "sweeps"))
    shutil.rmtree(masks_only / "maps" / "expansion")
    from lightemma.nuscenes.can_bus import frame_can_readings

    for where in (root, masks_only):
        with _Opens(where) as opens:
            frames = lightemma.load_frames(where, VERSION, split="all", on_missing_image="keep")
            frame_can_readings(frames)
            ev = _evaluate(run_dir, where)
        row = ev.models[0]
        assert row.planning["planning_frames"] == len(frames)
        if where == root:  # the map expansion has the lanes: the planning score is computed
            assert row.planning["epdms"] is not None
        assert row.safety["lightemma"]["offroad"] is not None and row.safety["lightemma"]["collision"] is not None
        modules = {m for m, _ in opens.seen}
        # the work read tables, a map and CAN bus files, all through lightemma.nuscenes
        paths = [p for _, p in opens.seen]
        assert any(p.endswith("sample_annotation.json") for p in paths)
        assert any(p.endswith(f"{os.sep}can_bus{os.sep}" + Path(p).name) for p in paths)
        assert any(p.endswith(".png") for p in paths) == (where == masks_only)
        assert opens.outside() == [], opens.outside()
        assert modules <= {
            "lightemma.nuscenes.json_tables",
            "lightemma.nuscenes.frames",
            "lightemma.nuscenes.map_files",
            "lightemma.nuscenes.can_bus",
            "lightemma.nuscenes.annotations",
        }, modules


# -- static: evaluation/ and planning/ never read a dataroot's files themselves ----------------------------------------

#: calls that open or read a file (open, io.open, os.open, json.load, Path.read_text / read_bytes, np.fromfile, …)
_READS = {"open", "load", "read_text", "read_bytes", "read_regular_file", "read_small_text", "fromfile", "loadtxt"}

#: every file evaluation/ and planning/ open: an evaluate JSON file the user names, the JSON schema beside it, and
#: frames.jsonl written into a run directory — never a dataroot's file (those come parsed from lightemma.nuscenes)
ALLOWED = {
    ("evaluation/descriptors.py", "path.read_text(encoding='utf-8')"),
    ("evaluation/descriptors.py", "Path(__file__).with_name('schema.json').read_text(encoding='utf-8')"),
    ("evaluation/study.py", "open(run_dir / FRAMES_FILE, 'w', encoding='utf-8')"),
    ("evaluation/synthetic.py", "open(run_dir / FRAMES_FILE, 'w', encoding='utf-8')"),
}


def _file_reads(path: Path, package: Path) -> set[tuple[str, str]]:
    """(module path, call) of every call in ``path`` whose function is named as one of :data:`_READS`."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Call):
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else ""
            if name in _READS:
                found.add((path.relative_to(package).as_posix(), ast.unparse(node)))
    return found


def test_evaluation_and_planning_open_no_dataroot_file():
    reads = set()
    for folder in ("evaluation", "planning"):
        for path in sorted((PACKAGE / folder).rglob("*.py")):
            reads |= _file_reads(path, PACKAGE)
    assert reads - ALLOWED == set(), "a new file read in evaluation/ or planning/ (a dataroot: lightemma.nuscenes)"
    assert ALLOWED - reads == set(), "an allowed read is gone: drop it from ALLOWED"


def test_the_static_scan_sees_the_readers_safety_held(tmp_path):
    """The scan above sees reads such as those evaluation/safety.py and planning/scores.py made before
    lightemma.nuscenes (a table opened with ``open``, a map expansion with ``json.load``): a test of the test."""
    (tmp_path / "evaluation").mkdir()
    sample = tmp_path / "evaluation" / "safety.py"
    sample.write_text(
        "import json\n\ndef _table(root, name):\n"
        "    with open(root / f'{name}.json', encoding='utf-8') as f:\n        return json.load(f)\n"
    )
    assert {call for _, call in _file_reads(sample, tmp_path)} == {
        "open(root / f'{name}.json', encoding='utf-8')",
        "json.load(f)",
    }


# -- the one table reader: every reader refuses alike ------------------------------------------------------------------


def _copy(root: Path, tmp_path: Path) -> Path:
    dest = tmp_path / "data"
    shutil.copytree(root, dest, ignore=shutil.ignore_patterns("samples", "sweeps"))
    return dest


def test_a_fifo_table_is_refused_by_every_reader_without_blocking(world, tmp_path):
    from lightemma.nuscenes.annotations import load_safety_data
    from lightemma.nuscenes.json_tables import read_table

    base, root, _ = world
    data = _copy(root, tmp_path)
    path = data / VERSION / "sensor.json"
    path.unlink()
    os.mkfifo(path)
    message = rf"nuScenes table {path} is not a regular file \(a FIFO\)"
    with pytest.raises(DatasetError, match=message):
        read_table(data, VERSION, "sensor")
    with pytest.raises(DatasetError, match=message):
        lightemma.load_frames(data, VERSION, split="all")
    with pytest.raises(DatasetError, match=message):
        load_safety_data(data, VERSION)


def test_a_table_over_the_limit_is_refused_before_it_is_read(world, tmp_path, monkeypatch):
    from lightemma.nuscenes import json_tables

    base, root, _ = world
    data = _copy(root, tmp_path)
    size = (data / VERSION / "sample.json").stat().st_size
    monkeypatch.setattr(json_tables, "MAX_TABLE_BYTES", size - 1)
    with pytest.raises(DatasetError, match=rf"sample\.json has {size} bytes, above the limit of {size - 1}"):
        json_tables.read_table(data, VERSION, "sample")


def test_the_safety_reader_now_needs_all_13_tables_as_the_frame_reader_does(world, tmp_path):
    """The safety and planning reader checked only the version folder; it now checks the dataroot as the frame reader
    does (all 13 tables, as the devkit requires): a missing table it never read is named, not ignored."""
    from lightemma.nuscenes.annotations import load_safety_data

    base, root, _ = world
    data = _copy(root, tmp_path)
    (data / VERSION / "attribute.json").unlink()
    with pytest.raises(DatasetError, match=r"attribute\.json is missing"):
        load_safety_data(data, VERSION)


def test_a_two_number_ego_pose_translation_is_refused_by_the_safety_reader_too(world, tmp_path):
    """The safety reader read the first two numbers of an ego pose's translation; it now applies the frame reader's
    rule (exactly 3 finite numbers), and the frame reader applies the safety reader's ±1e6 m bound."""
    from lightemma.nuscenes.annotations import load_safety_data

    base, root, _ = world
    data = _copy(root, tmp_path)
    frames = lightemma.load_frames(root, VERSION, split="all", on_missing_image="keep")
    token = frames.sample_tokens[0]
    sds = json.loads((data / VERSION / "sample_data.json").read_text())
    sensors = {s["token"]: s["channel"] for s in json.loads((data / VERSION / "sensor.json").read_text())}
    channel = {
        c["token"]: sensors[c["sensor_token"]]
        for c in json.loads((data / VERSION / "calibrated_sensor.json").read_text())
    }
    sd = next(
        r
        for r in sds
        if r["sample_token"] == token and r["is_key_frame"] and channel[r["calibrated_sensor_token"]] == "CAM_FRONT"
    )
    poses = json.loads((data / VERSION / "ego_pose.json").read_text())
    pose = next(p for p in poses if p["token"] == sd["ego_pose_token"])
    pose["translation"] = pose["translation"][:2]
    (data / VERSION / "ego_pose.json").write_text(json.dumps(poses))
    got = load_safety_data(data, VERSION)
    assert token not in got.poses
    assert (
        "has 2 value(s), needs 3 (x, y, z in metres)" in got.pose_reasons[token]
        and pose["token"] in got.pose_reasons[token]
    )
    # the frame reader's bound on x, y: beyond ±1e6 m is a bad record
    pose["translation"] = [2e6, 0.0, 0.0]
    (data / VERSION / "ego_pose.json").write_text(json.dumps(poses))
    loaded = lightemma.load_frames(data, VERSION, split="all", on_missing_image="keep")
    assert any("is beyond ±1e+06 m" in r and pose["token"] in r for r in loaded.bad_records)
    assert "is beyond ±1e+06 m" in load_safety_data(data, VERSION).pose_reasons[token]


def test_lane_nodes_are_checked_as_drivable_area_nodes(world, tmp_path):
    """The planning map's lane layer converted node coordinates with NumPy (text such as "12.5" and bools passed);
    it now applies the drivable area's rule: a finite number within ±1e6 m."""
    from lightemma.planning.scores import read_planning_map

    base, root, _ = world
    (path,) = sorted((root / "maps" / "expansion").glob("boston*.json"))
    doc = json.loads(path.read_text())
    lane_nodes = {
        t
        for lane in doc["lane"]
        for t in next(p for p in doc["polygon"] if p["token"] == lane["polygon_token"])["exterior_node_tokens"]
    }
    drivable_nodes = {
        t
        for rec in doc["drivable_area"]
        for p in doc["polygon"]
        if p["token"] in rec["polygon_tokens"]
        for t in p["exterior_node_tokens"]
    }
    target = sorted(lane_nodes - drivable_nodes)[0]
    node = next(n for n in doc["node"] if n["token"] == target)
    node["x"] = str(node["x"])
    bad = tmp_path / path.name
    bad.write_text(json.dumps(doc))
    with pytest.raises(DatasetError, match=rf"node {target} has x = '.*'; a coordinate must be a finite number"):
        read_planning_map(bad)
    assert np.isfinite(read_planning_map(path).lanes.xy).all()


# -- the one bounded file reader -------------------------------------------------------------------------------------


def test_the_bounded_reader_refuses_devices_fifos_and_growth(tmp_path):
    from lightemma._files import FileRefused, read_regular_file

    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(FileRefused, match=r"is not a regular file \(a FIFO\)"):
        read_regular_file(fifo, 10)
    with pytest.raises(FileRefused, match=r"is not a regular file \(a character device\)"):
        read_regular_file("/dev/zero", 10)
    big = tmp_path / "big"
    big.write_bytes(b"x" * 11)
    with pytest.raises(FileRefused, match="has 11 bytes, above the limit of 10") as info:
        read_regular_file(big, 10)
    assert info.value.kind == "too-large" and info.value.size == 11
    assert read_regular_file(big, 11) == b"x" * 11
    with pytest.raises(FileRefused, match=r"is unreadable \(No such file or directory\)"):
        read_regular_file(tmp_path / "absent", 10)
