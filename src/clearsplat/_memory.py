"""Estimate the memory a job needs before allocating it, and refuse what cannot fit.

The filter's footprint was read off the native rasterizer and measured (``docs/errors.md``,
"memory"): per camera, a :class:`~clearsplat.render.PreparedView` holds a 60-byte record per
visible Gaussian (``Splat`` 48 B, ``Rect`` 8 B, index 4 B, ``cpp/raster.h``) plus one int32 per
(tile, Gaussian) pair and a Gaussian-to-visible map (int32); the filter holds at once only the
prepared views that fit in ``FilterConfig.view_memory`` (plus the one being read and the one
being prepared) and keeps an
own-view mask (bool) and a packed visibility bit per view. Per input pixel it keeps the image,
the full and exclusion renders, the reveal reference, features, similarity maps, proposal masks and verification
buffers; per Gaussian the projection scratch (76 B, ``cpp/project.cpp``) and a few masks. The
constants below make the estimate 5 to 15 % above the measured peak on the synthetic scenes
(0.23 to 0.92 million Gaussians, 4 and 8 views).
"""

from __future__ import annotations

import os
from typing import Sequence

from .errors import ClearsplatError

__all__ = ["estimate_filter_memory", "estimate_read_memory", "available_memory",
           "check_memory"]

#: Bytes per visible Gaussian per view in a PreparedView: Splat 48 + Rect 8 + index 4.
PER_VISIBLE = 60
#: Bytes per (tile, Gaussian) pair in a PreparedView's tile lists (int32).
PER_PAIR = 4
#: Bytes per Gaussian in a PreparedView once it maps Gaussians to visible ids (int32).
PER_GAUSSIAN_PREPARED = 4
#: Further bytes per Gaussian per view that the filter keeps for every view, prepared or not:
#: own mask (bool) and a packed visibility bit.
PER_GAUSSIAN_VIEW = 1.125
#: Bytes per Gaussian once: projection scratch (76 B) and the filter's masks.
PER_GAUSSIAN = 100
#: Bytes per input pixel: image, renders, features, maps and verification buffers (360,
#: measured), and the reveal reference (rgb, alpha, depth and where it applies: 21).
PER_PIXEL = 381
#: Reading a binary PLY peaks at about this many times its size (bytes, columns, Gaussians,
#: raw columns; 4.5 measured).
READ_FACTOR_BINARY = 5
#: An ASCII PLY is split into Python strings first: far more per byte (15 measured).
READ_FACTOR_ASCII = 20
#: Set this environment variable to 0 to skip the check (swap, or a pessimistic estimate).
ENV_SWITCH = "CLEARSPLAT_MEMORY_CHECK"


def estimate_filter_memory(num_gaussians: int, cameras: Sequence, *,
                           tiles_per_gaussian: float = 2.0,
                           visible_fraction: float = 1.0,
                           view_budget: int | None = None) -> int:
    """Bytes :func:`clearsplat.filter_distractors` needs beyond the loaded scene.

    Parameters
    ----------
    num_gaussians : int
        N, the Gaussians in the scene.
    cameras : sequence of Camera
        The input cameras (anything with ``width`` and ``height``).
    tiles_per_gaussian : float, default 2.0
        Mean 16x16 tiles a visible Gaussian overlaps (1.5 on the synthetic scenes; large
        splats of trained scenes cover more).
    visible_fraction : float, default 1.0
        Share of the Gaussians that survive culling in a view (1: every one, an upper bound).
    view_budget : int, optional
        Bytes the prepared views may hold at once (``FilterConfig.view_memory``); the filter
        then keeps views up to it, plus the one being read and the one being prepared.

    Returns
    -------
    int
        Estimated peak bytes.
    """
    n = max(int(num_gaussians), 0)
    views = len(cameras)
    pixels = sum(int(c.width) * int(c.height) for c in cameras)
    prepared = n * (visible_fraction * (PER_VISIBLE + PER_PAIR * tiles_per_gaussian)
                    + PER_GAUSSIAN_PREPARED)
    held = views * prepared
    if view_budget is not None:
        held = min(held, int(view_budget) + 2 * prepared)
    return int(held + views * n * PER_GAUSSIAN_VIEW + n * PER_GAUSSIAN + pixels * PER_PIXEL)


def estimate_read_memory(file_size: int, *, ascii: bool = False) -> int:
    """Bytes :func:`clearsplat.io.read_ply` needs at its peak for a file of ``file_size`` bytes."""
    return int(file_size) * (READ_FACTOR_ASCII if ascii else READ_FACTOR_BINARY)


def _read_int(path: str) -> int | None:
    try:
        with open(path) as f:
            text = f.read().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def _stat_value(path: str, key: str) -> int:
    try:
        with open(path) as f:
            for line in f:
                k, _, v = line.partition(" ")
                if k == key and v.strip().isdigit():
                    return int(v)
    except OSError:
        pass
    return 0


def _cgroup_available() -> int | None:
    """Limit minus usage (without reclaimable file cache) of this process's cgroup, if limited."""
    for limit_file, usage_file, stat_file, inactive in (
            ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current",
             "/sys/fs/cgroup/memory.stat", "inactive_file"),
            ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
             "/sys/fs/cgroup/memory/memory.usage_in_bytes",
             "/sys/fs/cgroup/memory/memory.stat", "total_inactive_file")):
        limit, usage = _read_int(limit_file), _read_int(usage_file)
        if limit is None or usage is None or limit >= 2**60:
            continue
        return max(limit - max(usage - _stat_value(stat_file, inactive), 0), 0)
    return None


def available_memory() -> int | None:
    """Bytes that can be allocated without swapping, or None when unknown.

    ``MemAvailable`` from ``/proc/meminfo`` (else ``os.sysconf`` free pages), lowered to the
    room left under a cgroup memory limit (containers).
    """
    avail, kib = None, 0
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    kib = int(line.split()[1])          # "MemAvailable:  123 kB"
                    break
    except (OSError, ValueError, IndexError):
        kib = 0
    if kib:
        avail = kib * 1024
    else:
        try:
            avail = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (AttributeError, ValueError, OSError):
            avail = None
    group = _cgroup_available()
    if group is not None:
        avail = group if avail is None else min(avail, group)
    return avail


def _gb(b: float) -> str:
    return f"{b / 1e9:.1f} GB" if b >= 1e8 else f"{b / 1e6:.0f} MB"


_ADVICE = "use fewer or smaller views or fewer Gaussians, or a machine with more memory"


def check_memory(estimate: int, *, available: int | None = None, what: str = "the filter",
                 path=None, field: str = "memory", advice: str = _ADVICE) -> None:
    """Raise :class:`ClearsplatError` when ``estimate`` bytes exceed the available memory.

    Parameters
    ----------
    estimate : int
        Bytes needed, e.g. from :func:`estimate_filter_memory`.
    available : int, optional
        Bytes available; :func:`available_memory` by default. Nothing is checked when it
        is unknown, or when the environment variable ``CLEARSPLAT_MEMORY_CHECK`` is ``0``.
    what : str
        The job, for the message.
    path, field :
        Named in the error.
    advice : str
        What to do, for the message.

    Raises
    ------
    ClearsplatError
        ``"<what> needs about X GB, Y GB available ..."``.
    """
    if os.environ.get(ENV_SWITCH, "1").strip() == "0":
        return
    if available is None:
        available = available_memory()
    if available is None or estimate <= available:
        return
    raise ClearsplatError(
        f"{what} needs about {_gb(estimate)}, {_gb(available)} available: {advice} "
        f"({ENV_SWITCH}=0 skips this check)", path=path, field=field)


def return_free_memory() -> bool:
    """Hand the memory this process has freed back to the system, where the C library keeps
    it (glibc's ``malloc_trim``): after a long piece of work, so that the next one does not
    start on top of the last one's fragments (docs/method.md, "A long video"). True where
    it was done."""
    import ctypes
    import ctypes.util
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        trim = libc.malloc_trim
    except (OSError, AttributeError):       # not glibc: nothing to do
        return False
    trim.argtypes = [ctypes.c_size_t]
    trim(0)
    return True
