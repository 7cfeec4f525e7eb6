"""Local models over a Ray cluster: N replicas of one checkpoint, one driver.

``lightemma run --backend hf|vllm --replicas N [--ray-address ADDRESS]`` builds a
:class:`RayBackend`. It starts (or joins) Ray and creates N Ray actors, each owning
one replica of the model: the actor builds the ordinary
:class:`~lightemma.backends.hf.HFBackend` or :class:`~lightemma.backends.vllm.VLLMBackend`
in its own process, so every replica runs the same stage-synchronous micro-batching
(:class:`~lightemma.backends.batching.MicroBatcher`) as a single-process run.

The driver keeps everything else — the one run store, the chain, re-asks,
accounting, the manifest — and this object is the driver's backend: it
implements the :class:`~lightemma.backends.base.Backend` interface and sends each
request to one replica:

* **Routing.** A frame is homed on one replica at its first request (the replica
  with the fewest requests in flight, then the fewest frames so far) and its later
  stages and re-asks go to the same replica. Frames move through the chain in
  lockstep, so balancing at a frame's first stage balances the stages after it, and
  a frame's image and chat header — the common prefix of its three stages — stay
  in one engine, where vLLM's prefix cache (and its multimodal encoder cache) reuse
  them; a replica never sees another replica's cache.
* **Resources.** A replica asks Ray for ``gpus_per_replica`` GPUs (hf: default 1
  where the cluster has GPUs, else 0 = CPU) and one CPU. A vLLM replica sharded over
  ``tensor_parallel_size × pipeline_parallel_size`` > 1 GPUs gets a placement group
  of one ``{GPU: 1, CPU: 1}`` bundle per shard (``STRICT_PACK`` on one node, ``PACK``
  when pipeline-parallel); the replica's actor (1 CPU, no GPU) runs in it and vLLM's
  own Ray workers (``distributed_executor_backend="ray"``) take its GPUs — the
  pattern of vLLM's Ray Data example.
* **Faults.** Actors are created with ``max_restarts`` (Ray restarts a dead
  replica's process and rebuilds its model) and ``max_task_retries=0``: a request
  whose replica died (killed actor, crashed process, lost node) is not retried on
  the restarting replica but re-dispatched at once to a live one, at most
  :data:`MAX_SENDS` times in all (then it is answered with an error result
  ``ReplicaDied``, which the chain re-asks like any failed call). The replica comes
  back when Ray has restarted it. Records are written by the driver alone, one per
  finished frame, so a replica's death never loses or duplicates a frame. When every
  replica is dead for good (restarts used up) the run stops with a run-fatal line;
  a replica whose model fails every batch identically turns run-fatal through the
  micro-batcher's own rule, as in one process.

Ray is imported when a backend is built, never when this module is imported.
Docs: docs/local.md ("Replicas over Ray").
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from lightemma.backends import local_backend
from lightemma.backends.base import Backend, ChatRequest, ChatResult
from lightemma.backends.retry import short_message
from lightemma.errors import InputError, RunFatalError, UserError

#: Ray restarts a dead replica this many times (``max_restarts``) before it is out of the run
DEFAULT_MAX_RESTARTS = 3
#: a request is sent to at most this many replicas when the ones holding it die
MAX_SENDS = 3
#: object store of a local Ray started by lightemma: requests and answers are a few kB
LOCAL_OBJECT_STORE_BYTES = 256 * 1024**2
#: seconds between checks of whether a dead replica has been restarted
PROBE_INTERVAL = 0.25
ROUTING = (
    "a frame's stages and re-asks go to one replica (its home), chosen at the frame's first request: "
    "the replica with the fewest requests in flight, then the fewest frames so far"
)


def import_ray() -> Any:
    """The ``ray`` module, or a :class:`UserError` naming the extra that provides it."""
    try:
        import ray
    except ImportError as exc:
        raise UserError(
            f"--replicas and --ray-address need Ray ({exc}); install it with: pip install 'lightemma[ray]'"
        ) from None
    return ray


# -- inside each Ray actor ------------------------------------------------------------------------


@dataclass(frozen=True)
class _Fatal:
    """A replica's run-fatal answer (its micro-batcher found the model unable to generate), sent back as data."""

    message: str
    cause: str
    error: str | None


class ReplicaServer:
    """What runs in each replica's Ray actor: one local backend (hf or vllm), built in the actor's process.

    A model that cannot be built is not raised from ``__init__`` (Ray would report it as a dead actor with a
    traceback): ``ready`` returns it, and the driver turns it into one line.
    """

    def __init__(self, kind: str, model: str, options: Mapping[str, Any]) -> None:
        self._backend: Backend | None = None
        self._failure: dict[str, Any] | None = None
        try:
            self._backend = local_backend(kind, model, **dict(options))
        except BaseException as exc:  # noqa: BLE001 - reported by ready(), never lost in a traceback
            self._failure = {
                "error": type(exc).__name__,
                "message": str(exc) or type(exc).__name__,
                "user_error": isinstance(exc, UserError),
            }

    def _built(self) -> Backend:
        """The replica's backend; asked only of a replica that is ready (the driver never uses one that is not)."""
        if self._backend is None:
            raise RuntimeError(f"this replica has no backend: {self._failure}")
        return self._backend

    @staticmethod
    def where() -> dict[str, Any]:
        """Where this replica runs: Ray node, IP, process, the GPU ids Ray gave it, its placement group."""
        import ray

        context = ray.get_runtime_context()
        group = ray.util.get_current_placement_group()
        return {
            "node_id": context.get_node_id(),
            "ip": ray.util.get_node_ip_address(),
            "pid": os.getpid(),
            "gpu_ids": [str(g) for g in context.get_accelerator_ids().get("GPU", [])],
            "placement_group": group.id.hex() if group is not None else None,
        }

    async def ready(self) -> dict[str, Any]:
        """The backend's ``info`` and where it runs, or why it could not be built."""
        if self._failure is not None:
            return {"ok": False, **self._failure, "where": self.where()}
        return {"ok": True, "info": dict(self._built().info), "where": self.where()}

    async def generate(self, requests: Sequence[ChatRequest]) -> list[ChatResult] | _Fatal:
        """The backend's answers; a run-fatal finding comes back as :class:`_Fatal` (never raised through Ray)."""
        try:
            return await self._built().generate(requests)
        except RunFatalError as exc:
            return _Fatal(str(exc), exc.cause, exc.error)

    async def structured_output(self) -> dict[str, Any]:
        """How this replica's backend constrains answers to a JSON schema, or why it cannot (as data, never raised)."""
        try:
            return {"ok": True, "how": self._built().structured_output()}
        except UserError as exc:
            return {"ok": False, "message": str(exc)}

    async def stats(self) -> dict[str, Any] | None:
        """The backend's batching statistics (this incarnation of the replica)."""
        stats = self._backend.stats if self._backend is not None else None
        return dict(stats) if stats is not None else None


# -- the driver -----------------------------------------------------------------------------------


@dataclass
class Replica:
    """The driver's view of one replica: its actor handle, state and counters."""

    index: int
    handle: Any
    placement_group: Any = None
    state: str = "up"  # up | down (dead, Ray is restarting it) | dead (for good)
    inflight: int = 0
    requests: int = 0  # answered by this replica
    frames: int = 0  # frames homed here
    deaths: int = 0
    restarts: int = 0
    where: dict[str, Any] = field(default_factory=dict)
    last_error: str | None = None


class Router:
    """Sends each request to one replica (frame affinity, fewest in flight) and re-dispatches on a replica's death.

    Works on any handles with Ray's actor-method shape (``handle.generate.remote(requests)`` and
    ``handle.ready.remote()`` returning awaitables); ray is imported for its exception classes only.
    """

    def __init__(
        self, replicas: list[Replica], *, max_sends: int = MAX_SENDS, probe_interval: float = PROBE_INTERVAL
    ) -> None:
        from ray import exceptions

        self._errors = exceptions
        self.replicas = replicas
        self.max_sends = max_sends
        self.probe_interval = probe_interval
        self.redispatched = 0  # requests sent again after their replica died
        self.given_up = 0  # requests answered with ReplicaDied after max_sends deaths
        self.events: list[dict[str, Any]] = []
        self._home: dict[str, int] = {}
        self._watchers: set[asyncio.Task[None]] = set()
        self._start = time.monotonic()

    async def answer(self, request: ChatRequest) -> ChatResult:
        """One request's result from a live replica; raises :class:`RunFatalError` when the run cannot go on."""
        sends = 0
        while True:
            replica = await self._pick(request.frame_id)
            sends += 1
            replica.inflight += 1
            try:
                out = await replica.handle.generate.remote([request])
            except self._errors.RayActorError as exc:
                self._lost(replica, exc)
                if sends >= self.max_sends:
                    self.given_up += 1
                    return ChatResult(
                        text=None,
                        retries=sends - 1,
                        error="ReplicaDied",
                        error_message=f"the replicas answering this request died {sends} times "
                        f"(last: {_actor_error(exc)})",
                    )
                self.redispatched += 1
                continue
            except self._errors.RayTaskError as exc:  # a bug in the replica, not a dead replica: this request fails
                cause = exc.cause if isinstance(getattr(exc, "cause", None), BaseException) else exc
                return ChatResult(
                    text=None,
                    retries=sends - 1,
                    error=type(cause).__name__,
                    error_message=short_message(cause) or type(cause).__name__,
                )
            finally:
                replica.inflight -= 1
            if isinstance(out, _Fatal):
                raise RunFatalError(out.message, cause=out.cause, error=out.error)
            (result,) = out
            replica.requests += 1
            if sends > 1:
                result.retries += sends - 1
            return result

    async def _pick(self, frame_id: str) -> Replica:
        """The frame's home replica while it is up, else the least busy live one (which becomes its home)."""
        while True:
            home = self._home.get(frame_id)
            if home is not None and self.replicas[home].state == "up":
                return self.replicas[home]
            up = [r for r in self.replicas if r.state == "up"]
            if up:
                best = min(up, key=lambda r: (r.inflight, r.frames, r.index))
                self._home[frame_id] = best.index
                best.frames += 1
                return best
            if all(r.state == "dead" for r in self.replicas):
                last = next((r.last_error for r in reversed(self.replicas) if r.last_error), "unknown")
                raise RunFatalError(
                    f"all {len(self.replicas)} model replicas died and Ray has no restarts left for them "
                    f"(last: {last}); see the Ray logs of the failed actors (docs/local.md#replicas-over-ray)",
                    cause="local-model",
                    error="ActorDiedError",
                )
            await asyncio.sleep(self.probe_interval)  # every live replica is restarting: wait for one

    def _lost(self, replica: Replica, exc: BaseException) -> None:
        """A call to ``replica`` failed because its actor died: mark it down and watch for Ray's restart."""
        replica.last_error = _actor_error(exc)
        if replica.state != "up":
            return
        replica.state = "down"
        replica.deaths += 1
        self._event(replica, "died", replica.last_error)
        task = asyncio.get_running_loop().create_task(self._watch(replica))
        self._watchers.add(task)
        task.add_done_callback(self._watchers.discard)

    async def _watch(self, replica: Replica) -> None:
        """Poll the replica until Ray has restarted it (up again) or says it is dead for good."""
        while True:
            try:
                status = await replica.handle.ready.remote()
            except self._errors.ActorDiedError as exc:
                replica.state, replica.last_error = "dead", _actor_error(exc)
                self._event(replica, "dead", replica.last_error)
                return
            except self._errors.RayActorError:  # unavailable while Ray restarts it
                await asyncio.sleep(self.probe_interval)
                continue
            if status.get("ok"):
                replica.state, replica.where = "up", dict(status.get("where") or {})
                replica.restarts += 1
                self._event(replica, "restarted", None)
            else:
                replica.state = "dead"
                replica.last_error = f"{status.get('error')}: {short_message(status.get('message'))}"
                self._event(replica, "dead", replica.last_error)
            return

    def _event(self, replica: Replica, what: str, error: str | None) -> None:
        self.events.append(
            {
                "replica": replica.index,
                "event": what,
                "after_s": round(time.monotonic() - self._start, 3),
                **({"error": error} if error else {}),
            }
        )

    async def stop(self) -> None:
        for task in list(self._watchers):
            task.cancel()
        await asyncio.gather(*self._watchers, return_exceptions=True)

    def report(self) -> dict[str, Any]:
        """What the replicas did in this session (recorded in the manifest's session entry)."""
        return {
            "replicas": len(self.replicas),
            "requests": [r.requests for r in self.replicas],
            "frames": [r.frames for r in self.replicas],
            "deaths": [r.deaths for r in self.replicas],
            "restarts": [r.restarts for r in self.replicas],
            "dead": [r.index for r in self.replicas if r.state == "dead"],
            "redispatched": self.redispatched,
            "given_up": self.given_up,
            "events": self.events[:100],
        }


def _actor_error(exc: BaseException) -> str:
    """A dead actor's error as one short line (Ray's messages run over many lines)."""
    first = (str(exc).strip().splitlines() or [""])[0]
    return f"{type(exc).__name__}: {short_message(first, 200)}"


class RayBackend(Backend):
    """N replicas of a local model (``kind`` ``hf`` or ``vllm``) as Ray actors, behind one backend.

    ``model`` is the checkpoint (hub id or path; every node must be able to load it, and read the frames'
    images at the same paths). ``options`` are the local backend's own (``batch_size``, ``dtype``,
    ``tensor_parallel_size``, …), given to each replica. ``address``: a running cluster to join
    (``auto``, ``HOST:PORT``, ``ray://HOST:PORT``); without it a local Ray is started, sized to the
    replicas, and shut down by :meth:`aclose`; a Ray already initialised in this process is used as it is.
    ``gpus_per_replica``: hf only (vllm: tensor × pipeline parallel size). ``max_restarts``: Ray's
    restarts per replica. ``runtime_env``: Ray's runtime environment for the replicas (e.g. to install
    lightemma on a cluster's nodes). Raises :class:`UserError` (one line) when Ray, the cluster's resources
    or a replica's model are not as needed.
    """

    def __init__(
        self,
        kind: str,
        model: str,
        *,
        replicas: int,
        address: str | None = None,
        gpus_per_replica: float | None = None,
        max_restarts: int = DEFAULT_MAX_RESTARTS,
        runtime_env: Mapping[str, Any] | None = None,
        max_sends: int = MAX_SENDS,
        **options: Any,
    ) -> None:
        if kind not in ("hf", "vllm"):
            raise UserError(f"--replicas runs local models (--backend hf or vllm), not the {kind} backend")
        if replicas < 1:
            raise UserError(f"--replicas must be at least 1, got {replicas}")
        if gpus_per_replica is not None and kind != "hf":
            raise UserError(
                "--gpus-per-replica is for --backend hf; a vLLM replica uses "
                "--tensor-parallel-size × --pipeline-parallel-size GPUs"
            )
        if gpus_per_replica is not None and not gpus_per_replica >= 0:
            raise UserError(f"--gpus-per-replica must be at least 0, got {gpus_per_replica:g}")
        if max_restarts < 0:
            raise InputError(f"max_restarts must be >= 0, got {max_restarts}")
        self.name = kind
        self.kind = kind
        self.model_id = model
        self._ray = ray = import_ray()
        self._closed = False
        self._batching: list[Any] | None = None  # each replica's batching statistics, collected at close
        self._placement_groups: list[Any] = []
        shards = int(options.get("tensor_parallel_size", 1) or 1) * int(options.get("pipeline_parallel_size", 1) or 1)
        sharded = kind == "vllm" and shards > 1
        self._owns_ray, self._cluster = self._connect(address, cpus=replicas * (shards if sharded else 1))
        handles: list[Any] = []
        try:
            gpus_total = float(ray.cluster_resources().get("GPU", 0))
            if kind == "vllm":
                gpus = float(shards)
                if gpus_total < 1:
                    raise UserError(
                        f"vLLM replicas need GPUs, and the Ray cluster ({self._cluster['address']}) has none; "
                        "use --backend hf for CPU replicas"
                    )
            else:
                gpus = float(gpus_per_replica) if gpus_per_replica is not None else (1.0 if gpus_total >= 1 else 0.0)
            self._check_resources(replicas, gpus, gpus_total, cpus=shards if sharded else 1)
            self.gpus_per_replica = gpus
            actor_options: dict[str, Any] = {
                "max_restarts": max_restarts,
                "max_task_retries": 0,
                "num_cpus": 1,
                "num_gpus": 0 if sharded else gpus,
            }
            if runtime_env:
                actor_options["runtime_env"] = dict(runtime_env)
            replica_options = dict(options)
            if sharded:
                engine = dict(replica_options.get("engine_options") or {})
                engine.setdefault("distributed_executor_backend", "ray")  # vLLM's workers join the replica's group
                replica_options["engine_options"] = engine
            actor_class = ray.remote(ReplicaServer)
            handles = []
            for _ in range(replicas):
                options_i = dict(actor_options)
                if sharded:
                    options_i["scheduling_strategy"] = self._placement(
                        ray, shards, pipeline=int(options.get("pipeline_parallel_size", 1) or 1) > 1
                    )
                handles.append(actor_class.options(**options_i).remote(kind, model, replica_options))
            try:
                statuses = ray.get([h.ready.remote() for h in handles])
            except ray.exceptions.RayActorError as exc:  # a replica's process died while loading the model
                raise UserError(
                    f"a replica of {model} died while loading the model: {_actor_error(exc)}; "
                    "see the Ray logs of the failed actor"
                ) from None
        except BaseException:
            self._teardown(handles)
            raise
        failed = [(i, s) for i, s in enumerate(statuses) if not s["ok"]]
        if failed:
            self._teardown(handles)
            i, status = failed[0]
            message = status["message"]
            raise UserError(
                message
                if status["user_error"]
                else f"replica {i} of {model} could not start on Ray node {status['where'].get('ip')}: "
                f"{status['error']}: {short_message(message, 400)}"
            )
        self.replicas = [
            Replica(i, h, self._placement_groups[i] if sharded else None, where=dict(s["where"]))
            for i, (h, s) in enumerate(zip(handles, statuses))
        ]
        self.router = Router(self.replicas, max_sends=max_sends)
        self.max_restarts = max_restarts
        first = dict(statuses[0]["info"])
        self._info = {
            **first,
            "gpus": sum(int(s["info"].get("gpus") or 0) for s in statuses),  # all replicas together
            "replicas": replicas,
            "gpus_per_replica": gpus,
            "devices_per_replica": {"GPU": gpus, "CPU": shards if sharded else 1},
            "replica_backend": first.get("backend"),
            "ray": {
                "version": ray.__version__,
                **self._cluster,
                "placement": (
                    f"one placement group per replica, {shards} × {{GPU: 1, CPU: 1}}: the replica's actor (1 CPU) "
                    "and vLLM's Ray workers (1 GPU each)"
                    if sharded
                    else f"one actor per replica, num_gpus={gpus:g}, num_cpus=1"
                ),
                "max_restarts": max_restarts,
                "max_task_retries": 0,
                "max_sends": max_sends,
                "routing": ROUTING,
                "nodes": [s["where"] for s in statuses],
            },
        }

    # -- Ray: connect, resources, placement ---------------------------------------------------------

    def _connect(self, address: str | None, *, cpus: int) -> tuple[bool, dict[str, Any]]:
        """Join ``address``, or start a local Ray sized to the replicas; (whether we own it, what we joined)."""
        ray = self._ray
        if ray.is_initialized():
            return False, {"cluster": "the Ray already initialised in this process", "address": _gcs_address(ray)}
        quiet = {"logging_level": logging.WARNING, "include_dashboard": False}
        if address:
            try:
                ray.init(address=address, **quiet)
            except (ConnectionError, RuntimeError, ValueError) as exc:
                raise UserError(
                    f"cannot join the Ray cluster at --ray-address {address}: {short_message(exc, 300)}"
                ) from None
            return True, {"cluster": "joined", "address": _gcs_address(ray), "given_address": address}
        ray.init(address="local", num_cpus=cpus, object_store_memory=LOCAL_OBJECT_STORE_BYTES, **quiet)
        return True, {"cluster": "started locally", "address": _gcs_address(ray), "num_cpus": cpus}

    def _check_resources(self, replicas: int, gpus: float, gpus_total: float, *, cpus: int) -> None:
        """Refuse at once what the cluster can never place (it would wait forever)."""
        cpus_total = float(self._ray.cluster_resources().get("CPU", 0))
        for what, each, total in (("GPU", gpus, gpus_total), ("CPU", cpus, cpus_total)):
            need = replicas * each
            if need > total + 1e-9:
                raise UserError(
                    f"--replicas {replicas} × {each:g} {what}(s) per replica needs {need:g} {what}s; the Ray "
                    f"cluster ({self._cluster['address']}) has {total:g}"
                )

    def _placement(self, ray: Any, shards: int, *, pipeline: bool) -> Any:
        """A placement group for one sharded vLLM replica, as a scheduling strategy for its actor."""
        from ray.util.placement_group import placement_group
        from ray.util.scheduling_strategies import PlacementGroupSchedulingStrategy

        group = placement_group([{"GPU": 1, "CPU": 1}] * shards, strategy="PACK" if pipeline else "STRICT_PACK")
        self._placement_groups.append(group)
        return PlacementGroupSchedulingStrategy(placement_group=group, placement_group_capture_child_tasks=True)

    def _teardown(self, handles: Sequence[Any]) -> None:
        ray = self._ray
        for handle in handles:
            try:
                ray.kill(handle, no_restart=True)
            except Exception:  # noqa: BLE001 - already gone
                pass
        for group in self._placement_groups:
            try:
                ray.util.remove_placement_group(group)
            except Exception:  # noqa: BLE001 - already gone
                pass
        self._placement_groups = []
        if self._owns_ray:
            ray.shutdown()
            self._owns_ray = False

    # -- the Backend interface ----------------------------------------------------------------------

    @property
    def info(self) -> Mapping[str, Any]:
        """The first replica's backend ``info``, plus replicas, devices per replica, GPUs in all, Ray version and nodes."""
        return self._info

    @property
    def replica_report(self) -> dict[str, Any]:
        """Requests, frames, deaths, restarts and re-dispatches per replica in this session."""
        return {**self.router.report(), **({"batching": self._batching} if self._batching else {})}

    def sampling(self) -> str | None:
        """``--samples K``: K requests, spread over the replicas like any others."""
        return "calls"

    def structured_output(self) -> dict[str, Any]:
        """How every replica constrains stage 3 to the actions JSON schema (asked of each), or a :class:`UserError`."""
        ray = self._ray
        answers = ray.get([r.handle.structured_output.remote() for r in self.replicas])
        refused = next((a for a in answers if not a["ok"]), None)
        if refused is not None:
            raise UserError(refused["message"])
        return {**answers[0]["how"], "replicas": f"each of the {len(answers)} replicas constrains its own answers"}

    async def generate(self, requests: Sequence[ChatRequest]) -> list[ChatResult]:
        """Answer ``requests`` (in order), each on its frame's replica; raises only :class:`RunFatalError`."""
        if self._closed:
            raise RuntimeError("the backend is closed")
        # the frame object is for backends without a model; the replicas need the text, image path and params
        slim = [dataclasses.replace(r, frame=None) if r.frame is not None else r for r in requests]
        return list(await asyncio.gather(*(self.router.answer(r) for r in slim)))

    async def aclose(self) -> None:
        """Collect each live replica's batching statistics, kill the actors, remove placement groups, stop our Ray."""
        if self._closed:
            return
        self._closed = True
        await self.router.stop()
        live = [r for r in self.replicas if r.state == "up"]
        if live:
            tasks = [asyncio.ensure_future(_stats(r)) for r in live]
            done, pending = await asyncio.wait(tasks, timeout=10)
            for task in pending:
                task.cancel()
            stats = dict(t.result() for t in done if t.exception() is None)
            self._batching = [stats.get(r.index) for r in self.replicas]
        self._teardown([r.handle for r in self.replicas])


async def _stats(replica: Replica) -> tuple[int, Any]:
    """(index, the replica's batching statistics since its last start)."""
    return replica.index, await replica.handle.stats.remote()


def _gcs_address(ray: Any) -> str | None:
    try:
        return str(ray.get_runtime_context().gcs_address)
    except Exception:  # noqa: BLE001 - Ray Client has no GCS address here
        return None
