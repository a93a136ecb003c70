"""Ray plumbing shared by ``ldlmap prepare --ray`` and ``ldlloc run --ray``.

Imported only when ``--ray`` is given; Ray itself is imported inside :func:`import_ray`, so a
missing Ray is one clear error, not a traceback. What is here:

- :func:`ray_session`: start a local Ray cluster (``local``, ``local:N``) or join one (``auto``,
  ``HOST:PORT``, ``ray://HOST:PORT``) for the duration of a ``with`` block, with the toolkit's
  source folder on the workers' ``PYTHONPATH`` (so the workers import the same code as the
  driver: a shared filesystem, or the same install on every node). A session that is already
  connected (tests, notebooks) is reused and left open.
- :func:`as_completed`: the results of submitted tasks in arrival order, failures as exceptions.
- :func:`stop`: cancel outstanding work and kill actors (Ctrl-C, errors).
- :class:`ThroughputBar`: one Rich progress bar over all tasks, with each worker's throughput.
"""

from __future__ import annotations

import contextlib
import os
import socket
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from ldlmap.core.errors import InputError, LdlError
from ldlmap.core.lazy import lazy_module

ray = lazy_module("ray")

ADDRESS_HELP = ("local (start a Ray cluster on this machine with all its cores), local:N (N CPUs), auto (join "
                "the cluster started here with `ray start`), HOST:PORT (its head node) or ray://HOST:PORT (Ray Client)")
RETRIES = 3  # Ray re-runs a task (or restarts an actor) this many times when its worker process dies


def import_ray():
    """The ``ray`` module, or a one-line error saying how to install it."""
    try:
        import ray  # here: a missing Ray becomes the one-line error below
    except ImportError:
        raise LdlError("--ray needs Ray: pip install 'ldl-toolkit[ray]' (or pip install 'ray[client]')") from None
    return ray


def parse_address(address: str) -> dict[str, Any]:
    """``ray.init`` arguments for an ``--ray`` value (see :data:`ADDRESS_HELP`)."""
    text = address.strip()
    if text == "local":  # "local" also when RAY_ADDRESS is set: start a cluster here
        return {"address": "local", "num_cpus": None}
    if text.startswith("local:"):
        n = text[len("local:"):]
        if not n.isdigit() or int(n) < 1:
            raise InputError(f"--ray local:N needs N >= 1 CPUs, got {address!r}")
        return {"address": "local", "num_cpus": int(n)}
    if text == "auto":
        return {"address": "auto"}
    hostport = text[len("ray://"):] if text.startswith("ray://") else text
    host, sep, port = hostport.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise InputError(f"--ray must be {ADDRESS_HELP}; got {address!r}")
    _check_reachable(host, int(port), address)
    return {"address": text}


def _check_reachable(host: str, port: int, address: str, timeout: float = 3.0) -> None:
    """Fail fast where Ray would retry for minutes: nothing listens at ``host:port``."""
    try:
        socket.create_connection((host, port), timeout=timeout).close()
    except OSError as exc:
        raise InputError(f"cannot reach the Ray cluster at {address} ({exc.strerror or exc}); start one with "
                         "`ray start --head` or use --ray local") from None


def worker_path() -> str:
    """The workers' ``PYTHONPATH``: the folder this toolkit is imported from, then the driver's."""
    here = str(Path(__file__).resolve().parents[2])
    rest = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p and p != here]
    return os.pathsep.join([here, *rest])


def _one_line(exc: BaseException) -> str:
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    return lines[0] if lines else type(exc).__name__


@contextlib.contextmanager
def ray_session(address: str = "local") -> Iterator[Any]:
    """Yield the ``ray`` module connected to the cluster that ``address`` names; disconnect after
    (which stops a local cluster started here). An existing connection is reused and kept."""
    kwargs = parse_address(address)  # bad addresses fail even where a connection exists
    ray = import_ray()
    if ray.is_initialized():
        yield ray
        return
    debug = os.environ.get("LDL_DEBUG") == "1"
    try:
        ray.init(**kwargs, include_dashboard=False, log_to_driver=debug, logging_level="info" if debug else "error",
                 runtime_env={"env_vars": {"PYTHONPATH": worker_path()}})
    except Exception as exc:  # ConnectionError, ValueError, RuntimeError: all one-line messages
        hint = ""
        if kwargs.get("address") not in ("local", "auto") and not os.environ.get("RAY_AUTH_MODE"):
            hint = (" (if the cluster uses token authentication, set RAY_AUTH_MODE=token, with its token in "
                    "~/.ray/auth_token or RAY_AUTH_TOKEN)")
        raise InputError(f"cannot start or join the Ray cluster {address!r}: {_one_line(exc)}{hint}") from None
    try:
        yield ray
    finally:
        ray.shutdown()


def check_resources(ray, device: str, num_cpus: int = 1) -> dict[str, float]:
    """Resources each task asks for (CPUs, and one GPU for ``cuda``); a one-line error when the
    cluster has none of them (the tasks would wait forever)."""
    have = ray.cluster_resources()
    need = {"num_cpus": num_cpus}
    if device.startswith("cuda"):
        need["num_gpus"] = 1
        if have.get("GPU", 0) < 1:
            raise InputError("--device cuda, but the Ray cluster has no GPU")
    if have.get("CPU", 0) < num_cpus:
        raise InputError(f"each worker needs {num_cpus} CPUs but the Ray cluster has {have.get('CPU', 0):g}")
    return need


@dataclass(frozen=True)
class WorkerInfo:
    """Where a task ran: its node's address and process id."""

    node: str
    pid: int

    @property
    def label(self) -> str:
        return f"{self.pid}@{self.node}"


def enter_folder(cwd: str) -> None:
    """Work in the driver's folder ``cwd`` (call first in a task or an actor), so that relative
    paths mean the same as on the driver. Workers of a cluster joined by ``auto`` or an address
    start in the folder of its ``ray start``; a folder missing on a node is left alone (absolute
    paths on a shared filesystem then still work)."""
    if os.path.isdir(cwd):
        os.chdir(cwd)


def current_worker() -> WorkerInfo:
    """This worker process (call inside a task or an actor)."""
    return WorkerInfo(ray.util.get_node_ip_address(), os.getpid())


def as_completed(refs: list, poll_s: float = 0.5) -> Iterator[list[tuple[Any, Any, BaseException | None]]]:
    """Batches of ``(ref, value, None)`` or ``(ref, None, error)`` as tasks finish, each batch
    holding everything that finished since the last one. Polls every ``poll_s`` so that Ctrl-C
    is seen promptly."""
    pending = list(refs)
    while pending:
        ready, pending = ray.wait(pending, num_returns=1, timeout=poll_s)
        if not ready:
            continue
        if pending:
            more, pending = ray.wait(pending, num_returns=len(pending), timeout=0)
            ready += more
        batch = []
        for ref in ready:
            try:
                batch.append((ref, ray.get(ref), None))
            except ray.exceptions.RayError as exc:
                batch.append((ref, None, exc))
        yield batch


def failure_reason(exc: BaseException) -> str:
    """One line for a task that raised (its own exception) or whose worker died past its retries."""
    if isinstance(exc, ray.exceptions.RayTaskError):
        cause = exc.cause if exc.cause is not None else exc
        return f"{type(cause).__name__}: {_one_line(cause)}"
    if isinstance(exc, (ray.exceptions.RayActorError, ray.exceptions.WorkerCrashedError)):
        return f"Ray worker died ({RETRIES} retries): {_one_line(exc)}"
    return f"{type(exc).__name__}: {_one_line(exc)}"


def stop(refs: list, actors: list = (), grace_s: float = 5.0) -> None:
    """Cancel ``refs`` (a running task gets KeyboardInterrupt, so its temporary files go), wait up
    to ``grace_s`` for them, then kill ``actors``."""
    for ref in refs:
        with contextlib.suppress(Exception):
            ray.cancel(ref)
    with contextlib.suppress(Exception):
        ray.wait(list(refs), num_returns=len(refs), timeout=grace_s)
    for actor in actors:
        with contextlib.suppress(Exception):
            ray.kill(actor)


@dataclass
class TaskDone:
    """Progress event: one task finished (``worker`` None when it failed without a result)."""

    label: str
    worker: WorkerInfo | None
    done: int
    total: int


class ThroughputBar:
    """``with ThroughputBar(console, "scenes") as bar: f(..., progress=bar)``: one progress bar
    over all tasks, its line below listing each worker's finished tasks and rate."""

    def __init__(self, console, what: str, show_workers: int = 4):
        self.what, self.show = what, show_workers
        self.progress = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                                 TimeElapsedColumn(), TextColumn("{task.fields[workers]}"), console=console,
                                 transient=True)
        self.task = None
        self.start = time.perf_counter()
        self.counts: dict[str, int] = {}

    def __enter__(self) -> "ThroughputBar":
        self.progress.__enter__()
        self.task = self.progress.add_task(self.what, total=None, workers="starting Ray workers")
        self.start = time.perf_counter()
        return self

    def __exit__(self, *exc) -> None:
        self.progress.__exit__(*exc)

    def rates(self) -> dict[str, float]:
        """Tasks per second of each worker since the bar started."""
        elapsed = max(time.perf_counter() - self.start, 1e-9)
        return {w: n / elapsed for w, n in self.counts.items()}

    def workers_text(self) -> str:
        rates = sorted(self.rates().items(), key=lambda kv: -kv[1])
        if not rates:
            return ""
        per_min = max(r for _, r in rates) < 0.1
        unit = "/min" if per_min else "/s"
        fmt = lambda r: f"{r * 60:.2f}{unit}" if per_min else f"{r:.2f}{unit}"  # noqa: E731
        shown = ", ".join(f"{w} {self.counts[w]} ({fmt(r)})" for w, r in rates[: self.show])
        rest = f", +{len(rates) - self.show} more" if len(rates) > self.show else ""
        return f"{len(rates)} worker(s): {shown}{rest}"

    def __call__(self, event: TaskDone) -> None:
        if event.worker is not None:
            self.counts[event.worker.label] = self.counts.get(event.worker.label, 0) + 1
        self.progress.update(self.task, description=f"{self.what}: {event.label}", completed=event.done,
                             total=event.total, workers=self.workers_text())
