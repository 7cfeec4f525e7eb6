"""The backend base class (:class:`lightemma.backends.base.Backend`) and the factory (lightemma.backends.factory).

Every kind the registry names is a :class:`Backend` subclass, and every backend-shaped class of
``lightemma.backends`` is registered; a subclass gets each optional capability's documented default;
the factory builds every kind offline (a loopback endpoint for ``api`` / ``batch``, the tiny local
model of :mod:`local_models` for ``hf`` and its Ray replicas, the stand-in ``fake_vllm`` for ``vllm``),
and refuses an unknown kind in one line; the runner calls capabilities, it never probes for them.
"""

import asyncio
import importlib
import inspect
import pkgutil
import re
import sys
from pathlib import Path

import pytest

import lightemma.backends
from lightemma.backends import BACKENDS, KINDS, Backend, ChatRequest, ChatResult, GenerationParams, backend_class
from lightemma.backends.factory import create_backend, run_backend
from lightemma.errors import UserError
from tests.support.local_models import build_tiny_model

ROOT = Path(__file__).resolve().parents[3]
PYTHON = ROOT / "python" / "lightemma"


class Minimal(Backend):
    """A backend with only what every backend implements."""

    name = "minimal"

    def __init__(self) -> None:
        self.closed = 0

    @property
    def info(self):
        return {"kind": "minimal"}

    async def generate(self, requests):
        return [ChatResult(text="ok") for _ in requests]

    async def aclose(self) -> None:
        self.closed += 1


def _backend_modules():
    """Every module of ``lightemma.backends``, imported (none imports torch, vllm or ray at import time)."""
    out = [lightemma.backends]
    for info in pkgutil.walk_packages(lightemma.backends.__path__, "lightemma.backends."):
        out.append(importlib.import_module(info.name))
    return out


# -- the registry ------------------------------------------------------------------------------------------------


def test_every_registered_kind_is_a_concrete_backend_subclass():
    assert set(BACKENDS) <= set(KINDS)
    assert set(KINDS) == {"api", "batch", "hf", "vllm", "ray", "baseline"}
    for kind in KINDS:
        cls = backend_class(kind)
        assert issubclass(cls, Backend), kind
        assert not inspect.isabstract(cls), f"{kind}: {cls.__abstractmethods__}"


def test_every_backend_class_of_the_package_is_registered():
    """A class that looks like a backend (``generate`` and ``info``) is a Backend subclass in the registry."""
    registered = {backend_class(kind) for kind in KINDS}
    shaped = {
        obj
        for module in _backend_modules()
        for obj in vars(module).values()
        if inspect.isclass(obj)
        and obj.__module__.startswith("lightemma.backends")
        and hasattr(obj, "generate")
        and hasattr(obj, "info")
        and obj is not Backend
    }
    assert shaped == registered


def test_an_unknown_kind_is_a_one_line_error():
    kinds = "api, batch, hf, vllm, ray, baseline"
    with pytest.raises(UserError, match=rf"^unknown backend kind 'tpu'; the kinds are {kinds}$"):
        backend_class("tpu")
    with pytest.raises(UserError, match=r"^unknown backend 'tpu'; choose one of api, hf, vllm, baseline$"):
        create_backend("gpt-4o", backend="tpu")


def test_a_kind_whose_extra_is_missing_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "lightemma.backends.ray", None)  # import fails
    with pytest.raises(UserError, match=r"RayBackend backend is not available.*pip install 'lightemma\[ray\]'"):
        backend_class("ray")


# -- the base class: required members, defaults, the context manager --------------------------------------------


def test_a_backend_must_implement_info_generate_and_aclose():
    assert Backend.__abstractmethods__ == {"info", "generate", "aclose"}

    class NoClose(Backend):
        info = {"kind": "x"}

        async def generate(self, requests):
            return []

    with pytest.raises(TypeError, match="aclose"):
        NoClose()


def test_each_optional_capability_has_its_documented_default():
    backend = Minimal()
    assert (backend.name, backend.provider) == ("minimal", None)
    assert (backend.served_elsewhere, backend.api_base_shown) == (False, None)
    assert list(backend.notices) == [] and backend.wants_all_frames is False
    assert backend.effective_params(GenerationParams()) is None
    assert backend.check_endpoint() is None
    assert backend.prepare([], {}) is None and backend.attach("/nowhere", None, budget=None) is None
    for report in ("replica_report", "batch_report", "image_report", "cache_failure", "stats"):
        assert getattr(backend, report) is None, report
    with pytest.raises(
        UserError,
        match=r"^--answer-format structured: the minimal backend cannot constrain answers "
        r"to a JSON schema; use --answer-format text$",
    ):
        backend.structured_output()
    for name in (
        "structured_output",
        "effective_params",
        "check_endpoint",
        "prepare",
        "attach",
        "replica_report",
        "batch_report",
        "image_report",
        "cache_failure",
        "stats",
        "notices",
        "wants_all_frames",
    ):
        assert inspect.getdoc(getattr(Backend, name)) or name in ("notices", "wants_all_frames"), name


def test_a_backend_is_an_async_context_manager_that_closes_once():
    backend = Minimal()

    async def use():
        async with backend as entered:
            assert entered is backend
            (result,) = await entered.generate([ChatRequest(text="hi", stage="scene", frame_id="f")])
            assert result.text == "ok" and backend.closed == 0
        assert backend.closed == 1
        with pytest.raises(RuntimeError, match="boom"):
            async with backend:
                raise RuntimeError("boom")
        assert backend.closed == 2  # closed on the way out of a failure too

    asyncio.run(use())


def test_the_runner_and_the_backends_never_probe_a_backend_for_a_member():
    """Capabilities are called, never looked for: no getattr/hasattr on a backend in the pipeline or the backends."""
    probe = re.compile(r"\b(getattr|hasattr)\((self\._)?(backend|instance|check|guard)\b")
    for path in sorted([*(PYTHON / "pipeline").rglob("*.py"), *(PYTHON / "backends").rglob("*.py")]):
        found = [line.strip() for line in path.read_text().splitlines() if probe.search(line)]
        assert found == [], f"{path.name}: {found}"
    runner = importlib.import_module("lightemma.pipeline.runner")
    assert not hasattr(runner, "_make_backend")  # backends are built by the factory alone


# -- the factory builds every kind ------------------------------------------------------------------------------


def test_the_factory_builds_the_api_kind_and_a_runs_settings_reach_it(tmp_path, monkeypatch):
    monkeypatch.setenv("MY_KEY_FOR_TESTS", "sk-test")
    backend = create_backend("openai/test-model", api_base="http://127.0.0.1:9/v1")
    assert type(backend) is backend_class("api") and backend.info["kind"] == "api"
    asyncio.run(backend.aclose())
    shown: list[str] = []
    backend = run_backend(
        "openai/test-model",
        backend=None,
        api_base="http://192.0.2.7:8000/v1",
        output=tmp_path,
        timeout=7.0,
        rpm=60.0,
        tpm=None,
        max_retries=2,
        backoff_base=0.5,
        backoff_cap=4.0,
        api_key_env="MY_KEY_FOR_TESTS",
        cache="responses.sqlite",
        log=shown.append,
    )
    try:
        info = backend.info
        assert type(backend) is backend_class("api")
        assert (info["timeout_s"], info["rate_limit"]["rpm"], info["retry"]["max_retries"]) == (7.0, 60.0, 2)
        assert (info["retry"]["base_s"], info["retry"]["cap_s"]) == (0.5, 4.0)
        assert backend.cache.path == tmp_path / "responses.sqlite"  # a relative cache: under the output directory
        assert backend.cache_failure is None
        assert backend.served_elsewhere and backend.api_base_shown == "http://192.0.2.7:8000/v1"
        assert len(shown) == 1 and "http://192.0.2.7:8000/v1" in shown[0]  # plain http to another host, said once
    finally:
        asyncio.run(backend.aclose())


def test_the_factory_builds_the_batch_kind_and_refuses_what_a_batch_ignores(tmp_path):
    backend = create_backend(
        "openai/gpt-4o", api_base="http://127.0.0.1:9/v1", batch=True, timeout=3.0, poll_seconds=5.0
    )
    assert type(backend) is backend_class("batch") and backend.wants_all_frames is True
    assert backend.info["mode"] == "batch" and backend.info["batch"]["poll_s"] == 5.0
    asyncio.run(backend.aclose())
    settings = dict(
        backend=None,
        api_base="http://127.0.0.1:9/v1",
        output=tmp_path,
        timeout=3.0,
        max_retries=1,
        backoff_base=1.0,
        backoff_cap=1.0,
        batch=True,
    )
    backend = run_backend("openai/gpt-4o", rpm=None, tpm=None, batch_poll=2.0, **settings)
    assert type(backend) is backend_class("batch") and backend.poll_seconds == 2.0
    asyncio.run(backend.aclose())
    with pytest.raises(UserError, match=r"^--cache, --rpm do\(es\) not apply to --batch"):
        run_backend("openai/gpt-4o", rpm=10.0, tpm=None, cache="c.sqlite", **settings)
    assert not (tmp_path / "c.sqlite").exists()  # refused before the cache was opened
    with pytest.raises(
        UserError,
        match=r"^--batch is for models behind a provider's API; baseline:cv runs on the "
        r"baseline backend$",
    ):
        create_backend("baseline:cv", batch=True)


@pytest.mark.parametrize("kind", ["constant", "cv", "oracle", "ego"])
def test_the_factory_builds_each_baseline(kind):
    backend = create_backend(f"baseline:{kind}")
    assert type(backend) is backend_class("baseline") and backend.name == f"baseline:{kind}"
    assert backend.structured_output()["pair_count_enforced"] is True  # overrides the refusing default


def test_the_factory_refuses_a_price_for_a_backend_that_bills_none(tmp_path):
    with pytest.raises(UserError, match=r"^--price is the price of a provider's tokens; baseline:cv runs on the "):
        run_backend(
            "baseline:cv",
            backend=None,
            api_base=None,
            output=tmp_path,
            timeout=1.0,
            rpm=None,
            tpm=None,
            max_retries=0,
            backoff_base=1.0,
            backoff_cap=1.0,
            price=(1.0, 2.0),
        )


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """The tiny random-weight Qwen2-VL checkpoint the local-backend tests use."""
    return build_tiny_model("qwen2_vl", tmp_path_factory.mktemp("models") / "qwen2-vl")


@pytest.mark.slow
def test_the_factory_builds_the_hf_kind_with_the_runs_deadline(tiny, tmp_path):
    backend = run_backend(
        str(tiny),
        backend="hf",
        api_base=None,
        output=tmp_path,
        timeout=9.0,
        rpm=None,
        tpm=None,
        max_retries=0,
        backoff_base=1.0,
        backoff_cap=1.0,
        backend_options={"dtype": "float32", "device": "cpu"},
    )
    try:
        assert type(backend) is backend_class("hf")
        assert backend.info["timeout_s"] == 9.0 and backend.stats is not None
    finally:
        asyncio.run(backend.aclose())


def test_the_factory_builds_the_vllm_kind():
    backend = create_backend("Qwen/Qwen2.5-VL-7B-Instruct", backend="vllm", vllm="tests.support.fake_vllm")
    try:
        assert type(backend) is backend_class("vllm") and backend.info["backend"] == "vllm"
        assert backend.info["vllm"] == "0.32.0-fake" and backend.stats is not None
    finally:
        asyncio.run(backend.aclose())


@pytest.mark.slow
def test_the_factory_builds_the_ray_kind_from_replicas(tiny, monkeypatch):
    monkeypatch.setenv("PYTHONPATH", str(ROOT))
    backend = create_backend(str(tiny), backend="hf", replicas=2, dtype="float32", device="cpu")

    async def use():
        async with backend:
            assert type(backend) is backend_class("ray")
            assert backend.info["replicas"] == 2 and backend.info["replica_backend"] == "hf"
            request = ChatRequest(text="hi", stage="scene", frame_id="f", params=GenerationParams(max_tokens=4))
            (result,) = await backend.generate([request])
            assert result.error is None, result.error_message
        return backend.replica_report

    report = asyncio.run(use())
    assert report is not None and len(report["batching"]) == 2  # each replica's statistics, collected at close
