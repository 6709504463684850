"""Keep freed heap memory in a long-running worker process instead of returning it.

The render and evaluation workers allocate and free the same few image-sized arrays
(640x480x3 float32 = 3.7 MB) for every frame. glibc's malloc serves blocks that large
with a fresh ``mmap`` and returns them on free, so every frame faults in (and zeroes)
its pages again: measured, one suite trial of ``dockbench bench suite``: 1.14 M minor
page faults and 6.0 s of kernel time; with the thresholds below 0.22 M and 4.9-5.5 s.
The cost is resident memory the process keeps for its next frame (at most
``TRIM_THRESHOLD_B`` of free heap), which the workers' recycling bounds.
"""
from __future__ import annotations

import ctypes
import sys

MMAP_THRESHOLD_B = 256 << 20   # blocks below this come from the heap (glibc max is 32 MB by default)
TRIM_THRESHOLD_B = 512 << 20   # free heap kept before returning memory to the OS
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3   # <malloc.h>


def keep_freed_heap() -> bool:
    """Set glibc's mmap and trim thresholds for this process; False (nothing changed) on
    another C library or platform."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_B)) and bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_B))
