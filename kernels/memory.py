"""Memory and the operating system: freed memory given back, and no huge-page advice while scenes are built
where huge pages would stall.

glibc's allocator keeps large freed blocks in its heap once its dynamic mmap threshold has grown (as it
does after the first big NumPy arrays are freed), so the resident size of a process that built and
dropped a few hundred MB of temporaries stays that high, and the next phase's peak stacks on top of
it. malloc_trim(0) returns the free pages: Ember calls it where a phase has just dropped its
temporaries (after the export, after the renderer's tables). Elsewhere than Linux with glibc it does
nothing.

NumPy advises the kernel to back every array of 4 MB or more with huge pages (madvise MADV_HUGEPAGE). Where
the kernel's transparent_hugepage/defrag setting is "madvise" (the default of many distributions) and no
huge page is free, each first touch of such an array then waits for a synchronous compaction instead of
taking small pages (numpy/numpy#31590). Building a scene writes a few hundred MB of fresh arrays once, which
such stalls slow down by a third (docs/architecture.md, Memory). `small_pages` turns the advice off while a
scene is exported and its renderer built, and restores it after.

It does so only where a stall can happen: when the kernel would compact for madvised memory (defrag
"always", "madvise" or "defer+madvise") and has less than HUGE_PAGES_FREE_MB free in blocks of a huge page
or more (/proc/buddyinfo). With that much free, huge pages come without compaction, and they are the faster
way by far: half the page faults, and less system and wall time.
"""
from __future__ import annotations

import contextlib
import ctypes
import os
import sys
import threading

import numpy as np

_trim = None
_mallopt = None


def _libc(name: str, argtypes):
    """A glibc function, False off Linux or without glibc."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        function = getattr(ctypes.CDLL("libc.so.6"), name)
    except (OSError, AttributeError):
        return False
    function.argtypes, function.restype = argtypes, ctypes.c_int
    return function


def trim_heap() -> None:
    """Return the C heap's free pages to the system (glibc's malloc_trim); a no-op elsewhere."""
    global _trim
    if _trim is None:
        _trim = _libc("malloc_trim", [ctypes.c_size_t])
    if _trim:
        _trim(0)


# glibc's mallopt parameters, and what its dynamic thresholds reach in a process that frees big NumPy arrays
# (the values kept_heap leaves behind; setting them turns the dynamic adjustment off).
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
KEPT_BYTES = 1 << 30
SETTLED_MMAP_BYTES, SETTLED_TRIM_BYTES = 32 << 20, 64 << 20
_kept_depth = 0


def keep_freed_memory(keep: bool = True) -> bool:
    """Have glibc keep freed memory for the next allocation (keep) or give big blocks back to the system as
    it settles on its own (not keep). A render frees and allocates its waves' arrays (megabytes each)
    at every bounce: glibc gave them back each time and the next ones faulted fresh zeroed pages, some
    100,000 page faults and a tenth of a 2-second render in the kernel. False where this is not glibc."""
    global _mallopt
    if _mallopt is None:
        _mallopt = _libc("mallopt", [ctypes.c_int, ctypes.c_int])
    if not _mallopt:
        return False
    mmap, trim = (KEPT_BYTES, KEPT_BYTES) if keep else (SETTLED_MMAP_BYTES, SETTLED_TRIM_BYTES)
    return bool(_mallopt(_M_MMAP_THRESHOLD, mmap)) and bool(_mallopt(_M_TRIM_THRESHOLD, trim))


@contextlib.contextmanager
def kept_heap():
    """keep_freed_memory() inside (a render); when the last of nested or concurrent uses leaves, glibc
    settles again and the kept memory goes back to the system (trim_heap)."""
    global _kept_depth
    with _lock:
        if _kept_depth == 0:
            keep_freed_memory(True)
        _kept_depth += 1
    try:
        yield
    finally:
        with _lock:
            _kept_depth -= 1
            if _kept_depth == 0:
                keep_freed_memory(False)
                trim_heap()


def _advice_switch():
    """NumPy's (getter, setter) of its huge-page advice (private API, NumPy 1.x and 2.x), or None."""
    for name in ("numpy._core.multiarray", "numpy.core.multiarray"):
        module = sys.modules.get(name)
        if module is None:
            try:
                module = __import__(name, fromlist=["_get_madvise_hugepage"])
            except ImportError:
                continue
        get, put = getattr(module, "_get_madvise_hugepage", None), getattr(module, "_set_madvise_hugepage", None)
        if get is not None and put is not None:
            return get, put
    return None


_SWITCH = _advice_switch() if sys.platform.startswith("linux") else None

# Free memory in blocks of a huge page or more above which the advice is left on (small_pages).
HUGE_PAGES_FREE_MB = 2048
_STALLING_DEFRAG = ("always", "madvise", "defer+madvise")   # modes that compact on a madvised fault


def free_huge_blocks_mb(buddyinfo: str, page_bytes: int = 4096, huge_bytes: int = 2 << 20) -> float:
    """MB free in blocks of at least huge_bytes, from the text of /proc/buddyinfo (one line per zone:
    'Node 0, zone Normal' then the count of free blocks of 2^k pages for k = 0, 1, ...)."""
    first = max(0, (huge_bytes // page_bytes).bit_length() - 1)   # the order of a huge page
    total = 0
    for line in buddyinfo.splitlines():
        counts = line.split("zone", 1)[-1].split()[1:]
        for order, count in enumerate(counts):
            if order >= first and count.isdigit():
                total += int(count) << order
    return total * page_bytes / 2**20


def _read(path: str) -> str | None:
    try:
        with open(path) as f:
            return f.read()
    except OSError:
        return None


def huge_pages_ready() -> bool:
    """Whether huge pages come without a compaction stall now: the kernel's defrag mode never compacts
    on a fault, or HUGE_PAGES_FREE_MB are free in blocks of a huge page or more."""
    mode = _read("/sys/kernel/mm/transparent_hugepage/defrag")
    chosen = mode[mode.find("[") + 1:mode.find("]")] if mode and "[" in mode else None
    if chosen is not None and chosen not in _STALLING_DEFRAG:
        return True
    info = _read("/proc/buddyinfo")
    if info is None:
        return False
    size = _read("/sys/kernel/mm/transparent_hugepage/hpage_pmd_size")
    huge = int(size) if size and size.strip().isdigit() else 2 << 20
    return free_huge_blocks_mb(info, os.sysconf("SC_PAGE_SIZE"), huge) >= HUGE_PAGES_FREE_MB
_lock = threading.Lock()
_depth = 0
_saved = False


@contextlib.contextmanager
def small_pages():
    """NumPy's huge-page advice off inside (nested and concurrent uses restore it once, when the last one
    leaves), unless huge_pages_ready() when the first one enters; a no-op off Linux or where NumPy has no
    switch. Also a decorator."""
    global _depth, _saved
    if _SWITCH is None:
        yield
        return
    get, put = _SWITCH
    with _lock:
        if _depth == 0:
            _saved = bool(get())
            if not huge_pages_ready():
                put(False)
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                put(_saved)
