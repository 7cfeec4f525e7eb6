"""The first hour on the command line: defaults that say what they took, errors that speak CLI.

Every error here is checked to be exactly one line on stderr, with a non-zero exit status,
and to name the flag to use (``--force``, ``--split all``), never a Python argument.
"""

from __future__ import annotations

import json
import re

import pytest

import lightemma
from lightemma.cli import main
from lightemma.errors import UserError

# what a Python-speaking message looks like: keyword=value of a Python call
PYTHON_SPEAK = re.compile(r"\b[a-z_]+=(True|False|None|'|\"|\[)")


@pytest.fixture(autouse=True)
def _no_debug(monkeypatch):
    monkeypatch.delenv("LIGHTEMMA_DEBUG", raising=False)


def one_error_line(capsys, command: str) -> str:
    """The single stderr line of a failed command, checked for CLI wording."""
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"lightemma {command}: error: "), lines[0]
    assert not PYTHON_SPEAK.search(lines[0]), f"Python, not CLI: {lines[0]}"
    return lines[0]


@pytest.fixture(scope="module")
def baseline_run(synth_root, tmp_path_factory):
    out = tmp_path_factory.mktemp("runs")
    return lightemma.run("baseline:cv", dataroot=synth_root, version="v1.0-mini", output=out, progress=False).run_dir


# --------------------------------------------------------------------------- defaults


def test_run_on_v1_0_mini_takes_every_scene_and_says_so(synth_root, tmp_path, capsys):
    assert (
        main(
            [
                "run",
                "--model",
                "baseline:cv",
                "--dataroot",
                str(synth_root),
                "--version",
                "v1.0-mini",
                "--output",
                str(tmp_path),
                "--no-progress",
            ]
        )
        == 0
    )
    err = capsys.readouterr().err
    assert "lightemma run: frames: v1.0-mini, split all: 2 scenes, 12 frames, reference window\n" in err
    (manifest,) = tmp_path.rglob("manifest.json")
    dataset = json.loads(manifest.read_text())["dataset"]
    assert (dataset["split"], len(dataset["scenes"]), dataset["n_frames"]) == ("all", 2, 12)


def test_run_with_a_limit_says_how_many_frames_it_took(synth_root, tmp_path, capsys):
    assert (
        main(
            [
                "run",
                "--model",
                "baseline:cv",
                "--dataroot",
                str(synth_root),
                "--version",
                "v1.0-mini",
                "--limit",
                "5",
                "--output",
                str(tmp_path),
                "--no-progress",
            ]
        )
        == 0
    )
    assert (
        "frames: v1.0-mini, split all: 1 scene, 5 frames, reference window (first 5 frames)" in capsys.readouterr().err
    )


def test_resume_loads_the_split_the_run_started_with_not_todays_default(synth_root, tmp_path, monkeypatch, capsys):
    result = lightemma.run(
        "baseline:constant", dataroot=synth_root, version="v1.0-mini", output=tmp_path, progress=False
    )
    assert result.manifest["config"]["dataset"]["split"] is None  # the request named no split
    # were the default for v1.0-mini to change (it was mini_val), the run still resumes its own frames
    monkeypatch.setitem(lightemma.nuscenes.frames.DEFAULT_SPLITS, "v1.0-mini", "mini_val")
    assert main(["run", "--resume", str(result.run_dir), "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "frames: v1.0-mini, split all: 2 scenes, 12 frames, reference window" in err
    assert "12 frame(s) recorded, 0 to run" in err


# --------------------------------------------------------------------------- errors that speak CLI


@pytest.mark.parametrize(
    ("flag", "value", "message"),
    [
        ("--max-attempts", "0", "--max-attempts must be at least 1, got 0"),
        ("--concurrency", "0", "--concurrency must be at least 1, got 0"),  # was silently 16
        ("--limit", "0", "--limit must be at least 1, got 0"),
        ("--max-tokens", "-3", "--max-tokens must be at least 1, got -3"),
        ("--timeout", "0", "--timeout must be greater than 0, got 0"),
        ("--max-retries", "-1", "--max-retries must be at least 0, got -1"),
        ("--rpm", "0", "--rpm must be greater than 0, got 0"),
        ("--temperature", "-0.5", "--temperature must be at least 0, got -0.5"),
        ("--timeout", "nan", "--timeout must be greater than 0, got nan"),
        ("--timeout", "1e-300", "--timeout must be between 0.001 and 86400, got 1e-300"),
        ("--rpm", "1e-300", "--rpm must be between 1 and 1e+09, got 1e-300"),
        ("--max-retries", "1000000000", "--max-retries must be between 0 and 100, got 1e+09"),
    ],
)
def test_run_refuses_an_option_out_of_range_by_its_flag(synth_root, tmp_path, capsys, flag, value, message):
    assert (
        main(
            [
                "run",
                "--model",
                "baseline:cv",
                "--dataroot",
                str(synth_root),
                "--version",
                "v1.0-mini",
                "--output",
                str(tmp_path / "out"),
                flag,
                value,
            ]
        )
        == 2
    )
    assert one_error_line(capsys, "run").endswith(message)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "model, backend", [("baseline:cv", None), ("Qwen/Qwen2.5-VL-7B-Instruct", "hf"), ("qwen-2.5-vl-7b", "vllm")]
)
def test_an_api_base_that_the_backend_would_ignore_is_refused(synth_root, tmp_path, capsys, model, backend):
    extra = ["--backend", backend] if backend else []
    assert (
        main(
            [
                "run",
                "--model",
                model,
                *extra,
                "--api-base",
                "http://127.0.0.1:9/v1",
                "--dataroot",
                str(synth_root),
                "--version",
                "v1.0-mini",
                "--output",
                str(tmp_path / "out"),
                "--no-progress",
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert "--api-base is for models behind an API" in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "out").exists()


def test_a_named_split_missing_from_synthetic_data_points_to_split_all(synth_root, tmp_path, capsys):
    assert (
        main(
            [
                "run",
                "--model",
                "baseline:cv",
                "--dataroot",
                str(synth_root),
                "--version",
                "v1.0-mini",
                "--split",
                "mini_val",
                "--output",
                str(tmp_path),
            ]
        )
        == 2
    )
    line = one_error_line(capsys, "run")
    assert "2 of the 2 scenes of split 'mini_val' are not in version v1.0-mini" in line
    assert line.endswith("a synthetic dataset is loaded with --split all or --scenes NAME ...")


def test_a_version_without_a_default_split_points_to_split_all(tmp_path, capsys):
    from lightemma.synth import write_dataset

    root = write_dataset(tmp_path / "d", scenes=1, keyframes=15, version="v9-custom", images=False, sweeps=False)
    assert (
        main(
            [
                "run",
                "--model",
                "baseline:cv",
                "--dataroot",
                str(root),
                "--version",
                "v9-custom",
                "--output",
                str(tmp_path / "out"),
            ]
        )
        == 2
    )
    assert "add --split all to use every scene of it, or --scenes NAME ..." in one_error_line(capsys, "run")


def test_synth_onto_a_file_is_one_line(tmp_path, capsys):
    target = tmp_path / "notes.txt"
    target.write_text("mine")
    for outdir in (target, target / "sub"):
        assert main(["synth", str(outdir), "--scenes", "1", "--no-images"]) == 2
        assert f"{target} is a file, not a folder" in one_error_line(capsys, "synth")
    assert target.read_text() == "mine"
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "v1.0-mini").write_text("")
    assert main(["synth", str(tmp_path / "d"), "--scenes", "1", "--no-images"]) == 2
    assert "is a file, not a folder" in one_error_line(capsys, "synth")


def test_synth_onto_an_existing_dataset_names_force(tmp_path, capsys):
    assert main(["synth", str(tmp_path), "--scenes", "1", "--keyframes", "15", "--no-images"]) == 0
    capsys.readouterr()
    assert main(["synth", str(tmp_path), "--scenes", "1", "--keyframes", "15", "--no-images"]) == 2
    assert one_error_line(capsys, "synth").endswith("already exists; add --force to replace it")
    # the Python API names its own argument
    from lightemma.synth import write_dataset

    with pytest.raises(UserError, match="pass overwrite=True"):
        write_dataset(tmp_path, scenes=1, keyframes=15, images=False)


@pytest.mark.parametrize("kind", ["missing", "file"])
def test_report_with_a_dataroot_that_is_not_a_folder_is_an_error(baseline_run, tmp_path, capsys, kind):
    dataroot = tmp_path / "nowhere"
    if kind == "file":
        dataroot.write_text("")
    out = tmp_path / "report"
    assert main(["report", str(baseline_run), "--out", str(out), "--dataroot", str(dataroot)]) == 2
    what = "does not exist" if kind == "missing" else "is not a folder"
    assert one_error_line(capsys, "report").endswith(f"--dataroot {dataroot} {what}")
    assert not out.exists()
    with pytest.raises(UserError, match=f"dataroot {re.escape(str(dataroot))} {what}"):
        lightemma.write_report([baseline_run], out, dataroot=str(dataroot))


def test_os_errors_are_one_line_too(tmp_path, capsys):
    # evaluate -o into a path under a file: an OSError from open(), not a traceback
    blocker = tmp_path / "file"
    blocker.write_text("")
    run_dir = lightemma.run(
        "baseline:oracle",
        frames=lightemma.load_frames(_synth(tmp_path), "v1.0-mini"),
        output=tmp_path / "runs",
        progress=False,
    ).run_dir
    assert main(["evaluate", str(run_dir), "-o", str(blocker / "x.md")]) == 2
    one_error_line(capsys, "evaluate")


def _synth(tmp_path):
    from lightemma.synth import write_dataset

    return write_dataset(tmp_path / "synth", scenes=1, keyframes=15, image_size=(32, 18), sweeps=False)


def test_resume_of_a_run_from_frames_in_memory_says_it_needs_python(synth_root, tmp_path, capsys):
    frames = lightemma.load_frames(synth_root, "v1.0-mini").head(2)
    run_dir = lightemma.run("baseline:cv", frames=frames, output=tmp_path, progress=False).run_dir
    assert main(["run", "--resume", str(run_dir)]) == 2
    assert one_error_line(capsys, "run").endswith(
        "made from frames passed in memory, not from a dataset; resume it from Python: lightemma.resume(RUN_DIR, frames=FRAMES)"
    )


@pytest.mark.parametrize(
    "argv, message",
    [
        (
            ["run", "--concurrency", "x"],
            "lightemma run: error: argument --concurrency: invalid int value: 'x' (see lightemma run --help)",
        ),
        (
            ["evaluate", "runs", "--format", "yaml"],
            "lightemma evaluate: error: argument --format: invalid choice: 'yaml'",
        ),
        (["frobnicate"], "lightemma: error: argument COMMAND: invalid choice: 'frobnicate'"),
        # an unknown flag is named by the subcommand that got it, with that subcommand's help
        (["run", "--bogus"], "lightemma run: error: unrecognized arguments: --bogus (see lightemma run --help)"),
        (
            ["models", "--bogus", "x"],
            "lightemma models: error: unrecognized arguments: --bogus x (see lightemma models --help)",
        ),
        (
            ["prompts", "check", "set", "run", "extra"],
            "lightemma prompts check: error: unrecognized arguments: extra (see lightemma prompts check --help)",
        ),
        (["--bogus"], "lightemma: error: unrecognized arguments: --bogus (see lightemma --help)"),
    ],
)
def test_a_usage_error_is_one_line_naming_the_flag(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.startswith(message) and len(err.strip().splitlines()) == 1, err
