"""Start-up imports only what the chosen command and backend use (litellm takes seconds to import, the devkit too)."""

import json
import os
import subprocess
import sys

import pytest

from tests.support.fake_openai import FakeOpenAIServer

pytestmark = pytest.mark.slow  # every test here is heavy (the slow marker: pyproject.toml)

ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
HEAVY = ("litellm", "nuscenes", "sklearn", "matplotlib", "cv2", "torch", "transformers", "scipy")


def imported_after(code: str, *argv: str) -> dict:
    """Run ``code`` in a fresh interpreter; which heavy modules it left in sys.modules (and its exit status)."""
    probe = f"""
import json, sys
rc = None
{code}
print("\\n" + json.dumps({{"rc": rc, "modules": sorted(m for m in {HEAVY!r} if m in sys.modules)}}))
"""
    done = subprocess.run([sys.executable, "-c", probe, *argv], capture_output=True, text=True, env=ENV, timeout=300)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_import_lightemma_cli_imports_neither_litellm_nor_the_devkit():
    got = imported_after("import lightemma.cli\nimport lightemma\nlightemma.cli.build_parser()")
    assert got["modules"] == []


def test_help_imports_nothing_heavy():
    got = imported_after(
        "from lightemma.cli import main\ntry:\n    main(['--help'])\nexcept SystemExit as e:\n    rc = e.code"
    )
    assert got["rc"] == 0 and got["modules"] == []


def test_evaluate_imports_nothing_heavy(tmp_path):
    from lightemma.evaluation.synthetic import write_synthetic_run

    write_synthetic_run(tmp_path, "m/a", 30, seed=1)
    got = imported_after("from lightemma.cli import main\nrc = main(['evaluate', sys.argv[1]])", str(tmp_path))
    assert got["rc"] == 0 and "litellm" not in got["modules"] and "nuscenes" not in got["modules"]


@pytest.mark.parametrize("model", ["openai/test-model", "baseline:constant"])
def test_a_run_with_the_direct_transport_or_a_baseline_never_imports_litellm(tmp_path, synth_root, model):
    with FakeOpenAIServer() as server:
        argv = [
            "run",
            "--model",
            model,
            "--dataroot",
            str(synth_root),
            "--version",
            "v1.0-mini",
            "--split",
            "all",
            "--limit",
            "3",
            "--output",
            str(tmp_path / "runs"),
            "--no-progress",
        ]
        if model.startswith("openai/"):
            argv += ["--api-base", server.url, "--transport", "direct"]
        got = imported_after("from lightemma.cli import main\nrc = main(json.loads(sys.argv[1]))", json.dumps(argv))
        assert got["rc"] == 0 and "litellm" not in got["modules"]
        if model.startswith("openai/"):
            assert len(server.requests) == 9  # three frames, three stages: the run really called the server
    records = [
        json.loads(line) for p in (tmp_path / "runs").rglob("frames.jsonl") for line in p.read_text().splitlines()
    ]
    assert len(records) == 3 and all(r["status"] == "ok" for r in records)
