"""RunConfig: one typed, frozen run config, validated once; the manifest's settings as runs have always written them."""

import dataclasses
import json

import pytest

import lightemma
from lightemma.errors import UserError
from lightemma.pipeline.config import SETTINGS, InvalidSetting, RunConfig
from tests.support.memframes import make_frames
from tests.support.run_config_scenarios import GOLDEN, scenarios


def test_the_manifests_of_the_same_runs_are_byte_identical_to_the_runner_before_run_config(tmp_path, synth_root):
    """The golden was written by the runner that held its settings as a plain dict (tests/support/run_config_scenarios.py)."""
    want = json.loads(GOLDEN.read_text())
    got = scenarios(tmp_path / "runs", synth_root)
    assert sorted(got) == sorted(want)
    for name in want:
        assert got[name] == want[name], name


def test_every_recorded_config_block_round_trips_through_run_config_key_for_key_in_order():
    for name, text in json.loads(GOLDEN.read_text()).items():
        block = json.loads(text)["config"]
        again = RunConfig.from_manifest(block, "run").to_manifest()
        assert json.dumps(again) == json.dumps(block), name  # same keys, same order, same values (1000 stays an int)


@pytest.mark.parametrize(
    ("group", "keywords", "message"),
    [
        ("run", {"concurrency": 0}, "concurrency must be at least 1, got 0"),
        ("run", {"timeout": float("inf")}, "timeout must be a finite number, got inf"),
        ("run", {"max_cost_cents": 0.0}, "max_cost_cents must be greater than 0, got 0"),
        ("run", {"name": "a\nb"}, "name must be 1 to 80 printable characters of UTF-8 text, got 'a\\nb'"),
        ("dataset", {"limit": 0}, "limit must be at least 1, got 0"),
        ("dataset", {"scenes": [1]}, "scenes must be a list of scene names, got [1]"),
        ("dataset", {"sample": 0}, "sample must be at least 1, got 0"),
        ("prompting", {"max_tokens": 2_000_000}, "max_tokens must be between 1 and 1e+06, got 2e+06"),
        ("prompting", {"temperature": -1}, "temperature must be at least 0, got -1"),
        (
            "prompting",
            {"speed_range": (5, 1)},
            "speed_range must be two finite numbers (low, high) with low < high, got [5.0, 1.0]",
        ),
        ("api", {"rpm": 1e-300}, "rpm must be between 1 and 1e+09, got 1e-300"),
        ("api", {"max_retries": "6"}, "max_retries must be a whole number, got '6'"),
        (
            "api",
            {"price": (1.0, -2.0)},
            "price must be two numbers (input, output USD per million tokens), each 0..1e+06",
        ),
        ("local", {"replicas": 0}, "replicas must be at least 1, got 0"),
        ("local", {"backend_options": {"batch_size": 0}}, "batch_size must be at least 1, got 0"),
        ("batch", {"batch": True, "batch_poll": 0}, "batch_poll must be greater than 0, got 0"),
    ],
)
def test_a_setting_out_of_its_kind_or_range_is_refused_naming_the_parameter_not_a_flag(group, keywords, message):
    with pytest.raises(InvalidSetting) as refused:
        RunConfig.of("baseline:cv", **keywords)
    assert str(refused.value).startswith(message), (group, str(refused.value))
    assert "--" not in str(refused.value)
    assert isinstance(refused.value, UserError) and isinstance(refused.value, ValueError)


def test_the_library_refuses_before_any_work_naming_the_parameter(tmp_path):
    frames = make_frames(tmp_path, 2)
    with pytest.raises(InvalidSetting, match="^concurrency must be at least 1, got 0$"):
        lightemma.run(model="baseline:cv", frames=frames, output=tmp_path / "out", concurrency=0, progress=False)
    with pytest.raises(InvalidSetting, match="^timeout must be greater than 0, got 0$"):
        lightemma.run("baseline:cv", frames=frames, output=tmp_path / "out", timeout=0, progress=False)
    with pytest.raises(TypeError, match="unexpected keyword argument 'concurrancy'"):
        lightemma.run("baseline:cv", frames=frames, output=tmp_path / "out", concurrancy=4, progress=False)
    assert not (tmp_path / "out").exists()


def test_the_command_line_names_the_flag_for_the_same_refusal(tmp_path, synth_root, capsys, monkeypatch):
    from lightemma.cli import main

    monkeypatch.delenv("LIGHTEMMA_DEBUG", raising=False)
    base = [
        "run",
        "--model",
        "baseline:cv",
        "--dataroot",
        str(synth_root),
        "--version",
        "v1.0-mini",
        "--split",
        "all",
        "--output",
        str(tmp_path),
        "--no-progress",
    ]
    for flags, message in (
        (["--concurrency", "0"], "--concurrency must be at least 1, got 0"),
        (["--backoff", "601"], "--backoff must be between 0 and 600, got 601"),
        (["--max-cost", "0"], "--max-cost must be greater than 0, got 0"),
        (["--batch-size", "0"], "--batch-size must be at least 1, got 0"),
        # checked by the library (RunConfig), translated by the CLI
        (["--name", "a\nb"], "--name must be 1 to 80 printable characters of UTF-8 text"),
    ):
        assert main([*base, *flags]) == 2
        err = capsys.readouterr().err
        assert f"lightemma run: error: {message}" in err and len(err.strip().splitlines()) == 1, err
    assert not list(tmp_path.iterdir())


def test_every_setting_has_one_flag_and_every_flag_one_setting():
    import argparse

    from lightemma.cli.run import FLAGS, add_parser
    from lightemma.pipeline.config import BACKEND_OPTION_SETTINGS, DATASET_SETTINGS

    parser = add_parser(argparse.ArgumentParser().add_subparsers())
    known = {flag for action in parser._actions for flag in action.option_strings}
    assert set(FLAGS.values()) <= known
    rows = {row.name for row in (*SETTINGS, *DATASET_SETTINGS, *BACKEND_OPTION_SETTINGS)}
    assert rows - set(FLAGS) == {"backoff_cap", "backend_options"}  # no flag of their own
    assert set(FLAGS) - rows == {"name"}


def test_run_takes_a_run_config_and_records_the_same_settings_as_keywords(tmp_path):
    frames = make_frames(tmp_path, 2)
    keywords = dict(concurrency=2, max_attempts=3, speed_range=(-5, 30), name="typed")
    by_keywords = lightemma.run("baseline:cv", frames=frames, output=tmp_path / "a", progress=False, **keywords)
    config = lightemma.RunConfig.of("baseline:cv", **keywords)
    by_config = lightemma.run(config=config, frames=frames, output=tmp_path / "b", progress=False)
    assert by_config.manifest["config"] == by_keywords.manifest["config"] == config.to_manifest()
    assert by_config.manifest["name"] == "typed" and by_config.manifest["config"]["speed_range"] == [-5.0, 30.0]
    with pytest.raises(TypeError, match="takes every setting from the config"):
        lightemma.run(config=config, frames=frames, output=tmp_path / "c", concurrency=3)


def test_run_config_is_frozen_and_a_replaced_copy_is_validated_again():
    config = RunConfig.of("baseline:cv")
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.concurrency = 3  # type: ignore[misc]
    with pytest.raises(TypeError):
        config.local.backend_options["seed"] = 1  # type: ignore[index]
    assert config.replace(concurrency=3, rpm=60.0).api.rpm == 60.0
    with pytest.raises(InvalidSetting, match="^rpm must be between 1 and 1e\\+09, got 0.5$"):
        config.replace(rpm=0.5)


def test_a_manifest_config_is_refused_naming_the_manifest_setting():
    block = RunConfig.of("baseline:cv").to_manifest()
    for changes, words in (
        ({"concurrency": 0}, "run: the manifest's config.concurrency is 0, not a whole number"),
        ({"rpm": -1.0}, "config.rpm is -1.0, not a number greater than 0"),
        ({"backend_options": {"batch_size": 0}}, "config.backend_options.batch_size is 0, not at least 1"),
        ({"chain": 3}, "config.chain is 3, not text"),
    ):
        with pytest.raises(UserError) as refused:
            RunConfig.from_manifest({**block, **changes}, "run")
        text = str(refused.value)
        assert words in text and text.endswith("; start a new run"), text
    legacy = {k: v for k, v in block.items() if k not in ("chain", "answer_format", "inputs", "batch", "transport")}
    old = RunConfig.from_manifest(legacy, "run")  # written before those settings existed: what they meant then
    assert (old.prompting.chain, old.prompting.inputs, old.batch.enabled, old.api.transport) == (
        "independent",
        "full",
        False,
        "litellm",
    )
