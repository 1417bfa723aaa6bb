"""What new memory costs on this machine: the first write to each page of a fresh buffer.

Usage::

    python benchmarks/fresh_memory.py [--gb 1]

Writes one byte per 4 KiB page of a fresh NumPy buffer (the kernel clears each page on its
first touch) right after freeing a buffer of the same size, then after waiting 2, 5, 10 and 20
seconds. On a plain Linux machine every figure is about the same (the time to clear the
pages); on a virtual machine whose host reclaims memory the guest has freed, the figures grow
with the wait, and a process that grows its memory pays that price once per byte of its peak.
This is the difference between the *first* and the median runs of ``filter_speed.py``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def _touch(nbytes: int) -> float:
    t = time.perf_counter()
    a = np.empty(nbytes, np.uint8)
    a[::4096] = 1
    t = time.perf_counter() - t
    del a
    return t


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--gb", type=float, default=1.0)
    args = p.parse_args(argv)
    nbytes = int(args.gb * 2**30)
    _touch(nbytes)
    print(f"first touch of {args.gb:g} GiB of new memory (seconds)")
    print(f"{'idle before':>12} {'seconds':>8} {'GiB/s':>7}")
    for wait in (0, 2, 5, 10, 20):
        time.sleep(wait)
        s = _touch(nbytes)
        print(f"{wait:>10} s {s:>8.3f} {args.gb / s:>7.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
