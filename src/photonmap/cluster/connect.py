"""Starting or joining a Ray cluster and placing the worker actors on it.

``--workers N`` starts a private local Ray instance on the loopback address with N CPUs, one
worker actor per CPU. ``--ray ADDRESS`` joins a running cluster (``ray start --head`` prints its
address, ``host:6379``): before Ray is asked, the address is parsed and its port probed with a
short timeout, so an address that cannot be reached is one line (:class:`ClusterError`) after at
most ``timeout`` seconds instead of Ray's minute of retries. On a cluster the default is one
worker per node, each reserving all of that node's CPUs (Dr.Jit runs that many threads), or one
GPU per worker when the driver runs on CUDA (``PHOTONMAP_DEVICE=cuda``).

Actors restart after a crash (``max_restarts``) and Ray retries the task that was running on
them (``max_task_retries``; Ray's actor fault tolerance); :mod:`.schedule` reschedules on the other
workers what still fails.
"""

from __future__ import annotations

import atexit
import os
import shutil
import socket
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass

from ..core.errors import BackendError, ParameterError, PhotonmapError

MAX_RESTARTS = 2  # restarts of a crashed actor (its constructor reruns: scene load)
MAX_TASK_RETRIES = 2  # retries of the task that was running when it crashed
CONNECT_TIMEOUT = 3.0  # seconds to wait for a cluster address to answer
OBJECT_STORE = 512 * 2**20  # bytes of shared memory for a local instance's results
QUIET = {"include_dashboard": False, "log_to_driver": False, "logging_level": "error"}


class ClusterError(PhotonmapError):
    """A Ray cluster that cannot be reached or used, or no worker left to run the work on."""


def import_ray():
    """The ``ray`` module, or a :class:`BackendError` saying how to install it."""
    try:
        import ray
    except ImportError:
        raise BackendError(
            "distributed rendering needs Ray: pip install 'photonmap[cluster]' (or pip install ray)"
        ) from None
    return ray


def parse_address(address: str) -> tuple[str, int]:
    """``host:port`` → (host, port); anything else is a :class:`ClusterError`."""
    text = address.strip()
    if text.startswith("ray://"):
        raise ClusterError(
            f"--ray {address!r}: Ray Client addresses (ray://) need 'ray[client]' and do not "
            "run drivers on the cluster; give the head node's GCS address host:6379 (run the "
            "render on a cluster node, or use 'ray job submit')"
        )
    host, sep, port = text.rpartition(":")
    host = host.strip("[]")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ClusterError(
            f"--ray {address!r} is not a cluster address: expected HOST:PORT, e.g. "
            "127.0.0.1:6379 (printed by 'ray start --head')"
        )
    return host, int(port)


def probe(address: str, timeout: float = CONNECT_TIMEOUT) -> None:
    """Raise a :class:`ClusterError` unless a TCP connection to ``address`` opens within
    ``timeout`` seconds."""
    host, port = parse_address(address)
    try:
        with socket.create_connection((host, port), timeout=timeout):
            pass
    except OSError as exc:
        why = "timed out" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc))
        raise ClusterError(
            f"cannot reach a Ray cluster at {address}: {why} (is 'ray start --head' running "
            "there, and is the port open?)"
        ) from None


@dataclass(frozen=True)
class Placement:
    """How many worker actors to start and what each reserves."""

    workers: int
    cpus: float
    gpus: float
    threads: int
    device: str


@contextmanager
def cluster(workers: int | None = None, address: str | None = None, timeout=CONNECT_TIMEOUT):
    """Start a local Ray instance (``workers`` CPUs) or join the one at ``address``; yield the
    :class:`Placement` of the workers; shut Ray down afterwards. Joining a Ray already
    initialised in this process (a test's cluster) keeps it running."""
    if workers is not None and (isinstance(workers, bool) or not 1 <= workers <= 4096):
        raise ParameterError(f"--workers must lie in 1…4096, got {workers}")
    if address is not None:
        probe(address, timeout)
    ray = import_ray()
    own = not ray.is_initialized()
    if own:
        _init(ray, workers, address)
    try:
        yield placement(ray, workers)
    finally:
        if own:
            ray.shutdown()
            remove_session_files()


def _init(ray, workers, address) -> None:
    try:
        if address is not None:
            ray.init(address=address, **QUIET)
        else:
            start_local(ray, workers or os.cpu_count())
    except (ConnectionError, RuntimeError, ValueError) as exc:
        where = f"at {address}" if address else "locally"
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ClusterError(f"cannot start or join Ray {where}: {first}") from None


_session_dirs: list[str] = []  # the temporary folders of the local instances this process started


def remove_session_files() -> None:
    """Remove the session folders (logs, sockets, spilled objects) of the local Ray instances
    this process started and shut down; also run at exit."""
    while _session_dirs:
        shutil.rmtree(_session_dirs.pop(), ignore_errors=True)


atexit.register(remove_session_files)


def start_local(ray, cpus: int) -> str:
    """Start a private Ray instance with ``cpus`` CPUs on the loopback address, its workers
    importing the same photonmap as this process at this process's priority; return its address
    (``host:port``). Its session files go to a temporary folder of its own (not ``/tmp/ray``),
    removed when it is shut down (:func:`remove_session_files`) or at exit."""
    from ray._private import ray_constants

    # A private instance stays on the loopback address: without this Ray advertises the
    # machine's network address (what it does on macOS and Windows by default).
    ray_constants.ENABLE_RAY_CLUSTER = False
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # a private instance reports nothing
    src = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    path = os.pathsep.join(p for p in (src, os.environ.get("PYTHONPATH")) if p)
    # a short path: Ray's Unix sockets live in it (at most 107 characters)
    folder = tempfile.mkdtemp(prefix="photonmap-ray-", dir="/tmp" if os.path.isdir("/tmp") else None)
    _session_dirs.append(folder)
    context = ray.init(
        num_cpus=cpus,
        object_store_memory=OBJECT_STORE,
        _node_ip_address="127.0.0.1",
        _temp_dir=folder,
        runtime_env={"env_vars": {"PYTHONPATH": path}},
        # Ray runs its workers at niceness 15 to keep its own daemons responsive; here the
        # workers are the render, and at 15 any other busy process on the machine starves them
        # (a 2-CPU instance beside two busy processes: 56 s to the first block instead of 7 s).
        _system_config={"worker_niceness": 0},
        **QUIET,
    )
    return context.address_info["gcs_address"]


def placement(ray, workers: int | None) -> Placement:
    """``workers`` actors sharing the cluster's CPUs (or GPUs) evenly, or, when None, one per
    CPU on a single node and one per node on several."""
    import mitsuba as mi

    device = "cuda" if mi.variant().startswith("cuda") else "cpu"
    nodes = [n for n in ray.nodes() if n.get("Alive")]
    total = ray.cluster_resources()
    cpus, gpus = int(total.get("CPU", 0)), int(total.get("GPU", 0))
    if device == "cuda":
        if gpus < 1:
            raise ClusterError("the driver runs on CUDA but the cluster has no GPU")
        n = workers or gpus
        return Placement(n, 1.0, min(1.0, gpus / n), 1, device)
    if cpus < 1:
        raise ClusterError("the cluster has no CPU to run workers on")
    n = workers or (cpus if len(nodes) <= 1 else len(nodes))
    per = max(1, cpus // n)
    return Placement(n, float(per), 0.0, per, device)


@contextmanager
def spawn(ray, worker_class, place: Placement, *args):
    """``place.workers`` actors of ``worker_class`` built with ``*args``, restarting after a
    crash and retrying the task that was running (Ray actor fault tolerance); killed on exit, so
    their CPUs are free for the next job at once."""
    remote = ray.remote(
        num_cpus=place.cpus,
        num_gpus=place.gpus,
        max_restarts=MAX_RESTARTS,
        max_task_retries=MAX_TASK_RETRIES,
        scheduling_strategy="SPREAD",
    )(worker_class)
    actors = [remote.remote(*args, place.device, place.threads) for _ in range(place.workers)]
    try:
        yield actors
    finally:
        for actor in actors:
            ray.kill(actor)
