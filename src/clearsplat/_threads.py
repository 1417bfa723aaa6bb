"""Running independent pieces of NumPy work on several cores.

NumPy releases the GIL inside its array operations, so per-view work made of large array
operations (features of an image pair, one view's depth test) runs in parallel in threads.
Each piece computes exactly what it would alone, so results do not depend on the thread count.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Iterable

__all__ = ["cores", "thread_map"]


def cores() -> int:
    """Threads to use by default: the CPU cores this process may run on, at most
    ``OMP_NUM_THREADS`` where that is set (Ray sets it for its tasks). The native rasterizer
    takes OpenMP's count, which is the same unless ``OMP_NUM_THREADS`` asks for more threads
    than there are cores: these steps never oversubscribe."""
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:      # not on Linux
        n = os.cpu_count() or 1
    omp = os.environ.get("OMP_NUM_THREADS", "").split(",")[0].strip()
    if omp.isdigit() and int(omp) > 0:
        n = min(n, int(omp))
    return max(1, n)


def thread_map(fn: Callable, items: Iterable, *, workers: int | None = None) -> list:
    """``[fn(x) for x in items]``, computed on up to ``workers`` threads (default: the cores).

    The first exception raised by ``fn`` is raised here, as in the loop.
    """
    items = list(items)
    workers = min(len(items), cores() if workers is None else max(1, int(workers)))
    if workers <= 1:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(workers) as pool:
        return list(pool.map(fn, items))
