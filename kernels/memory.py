"""Freed memory given back to the system.

glibc's allocator keeps large freed blocks in its heap once its dynamic mmap threshold has grown (as it
does after the first big NumPy arrays are freed), so the resident size of a process that built and
dropped a few hundred MB of temporaries stays that high, and the next phase's peak stacks on top of
it. malloc_trim(0) returns the free pages: Ember calls it where a phase has just dropped its
temporaries (after the export, after the renderer's tables). Elsewhere than Linux with glibc it does
nothing.
"""
from __future__ import annotations

import ctypes
import sys

_trim = None


def trim_heap() -> None:
    """Return the C heap's free pages to the system (glibc's malloc_trim); a no-op elsewhere."""
    global _trim
    if _trim is None:
        _trim = False
        if sys.platform.startswith("linux"):
            try:
                _trim = ctypes.CDLL("libc.so.6").malloc_trim
                _trim.argtypes, _trim.restype = [ctypes.c_size_t], ctypes.c_int
            except (OSError, AttributeError):
                _trim = False
    if _trim:
        _trim(0)
