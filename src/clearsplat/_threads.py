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
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:      # not on Linux
        return os.cpu_count() or 1


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
