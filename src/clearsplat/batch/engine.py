"""The Ray layer: start or join a cluster, run tasks on it, gather them as they finish.

Only scheduling lives here; the work is plain functions (:func:`~clearsplat.batch.filter_scene`,
:func:`clearsplat.bench.run_case`) that run without Ray too. ``ray`` is imported only when a
cluster is used (``pip install 'clearsplat[batch]'``).
"""

from __future__ import annotations

import contextlib
import os
import socket
from typing import Callable, Iterator, Sequence

from ..errors import ClearsplatError

__all__ = ["ray_cluster", "run_tasks", "node_memory", "TaskFailed"]


class TaskFailed(Exception):
    """A task that did not return: its worker died (killed for memory, crashed) or Ray failed."""


def _import_ray():
    try:
        import ray
    except ImportError:
        raise ClearsplatError("Ray is not installed: pip install 'clearsplat[batch]'",
                              field="ray") from None
    return ray


@contextlib.contextmanager
def ray_cluster(*, address: str | None = None, num_cpus: int | None = None) -> Iterator:
    """Connect to Ray for the duration of the ``with`` block; yields the ``ray`` module.

    Parameters
    ----------
    address : str, optional
        An existing cluster: ``"auto"``, ``"HOST:PORT"`` or ``"ray://HOST:PORT"`` (Ray Client).
        The connection is closed at the end; the cluster keeps running. Without it a local Ray
        instance is started and stopped again at the end: nothing is left running.
    num_cpus : int, optional
        CPUs of the local instance (default: all of this machine's). Ignored with ``address``.

    Notes
    -----
    When Ray is already initialised in this process (a caller's own ``ray.init``), that
    connection is used and left open.
    """
    ray = _import_ray()
    if ray.is_initialized():
        yield ray
        return
    options = {"include_dashboard": False, "log_to_driver": False,
               "logging_level": "ERROR"}
    if address:
        _check_reachable(address)
    try:
        if address:
            ray.init(address=address, **options)
        else:   # "local": a new instance, never a cluster that happens to run on this machine
            ray.init(address="local", num_cpus=num_cpus, **options)
    except (ConnectionError, RuntimeError, ValueError) as e:
        where = address or "a local instance"
        raise ClearsplatError(f"cannot start or join Ray at {where}: "
                              f"{' '.join(str(e).split())}", field="--address") from None
    try:
        yield ray
    finally:
        ray.shutdown()


def _check_reachable(address: str, timeout: float = 5.0) -> None:
    """Fail fast on a ``HOST:PORT`` nobody listens on (Ray itself retries for minutes)."""
    hostport = address[len("ray://"):] if address.startswith("ray://") else address
    host, sep, port = hostport.rpartition(":")
    if address == "auto" or not sep or not port.isdigit():
        return
    try:
        socket.create_connection((host.strip("[]") or "127.0.0.1", int(port)), timeout).close()
    except OSError as e:
        raise ClearsplatError(f"cannot reach a Ray cluster at {address} ({e.strerror or e})",
                              field="--address") from None


def node_memory(ray) -> list[float]:
    """The ``memory`` resource (bytes) of each alive node of the connected cluster."""
    return [float(n.get("Resources", {}).get("memory", 0.0)) for n in ray.nodes()
            if n.get("Alive")]


def run_tasks(ray, fn: Callable, items: Sequence, *, options: Sequence[dict] | None = None,
              ) -> Iterator[tuple[int, object]]:
    """Run ``fn(item)`` for each item as a Ray task; yield ``(index, result)`` as each finishes.

    Parameters
    ----------
    ray : module
        As yielded by :func:`ray_cluster`.
    fn : callable
        A module-level function (it is pickled to the workers).
    items : sequence
        One argument per task.
    options : sequence of dict, optional
        Per task, Ray's resource options (``num_cpus``, ``memory`` in bytes...).

    Yields
    ------
    index : int
        Position of the item in ``items``.
    result : object
        What ``fn`` returned, or a :class:`TaskFailed` when the task raised or its worker
        died (the other tasks go on).
    """
    remote = ray.remote(fn)
    pending = {}
    for i, item in enumerate(items):
        opts = dict(options[i]) if options is not None else {}
        opts.setdefault("max_retries", 0)
        pending[remote.options(**opts).remote(item)] = i
    try:
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                i = pending.pop(ref)
                try:
                    result = ray.get(ref)
                except Exception as e:     # RayTaskError, WorkerCrashedError, OutOfMemoryError
                    cause = getattr(e, "cause", None) or e
                    text = " ".join(str(cause).split()) or type(cause).__name__
                    result = TaskFailed(f"{type(cause).__name__}: {text}")
                yield i, result
    finally:
        for ref in pending:             # interrupted: do not leave work running
            with contextlib.suppress(Exception):
                ray.cancel(ref, force=True)


def local_cpus() -> int:
    """CPUs this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:              # not Linux
        return os.cpu_count() or 1
