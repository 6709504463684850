"""Process policies of the pipeline's workers: keep freed memory in the process heap instead
of handing it back to the kernel (:func:`keep_heap`), and run BLAS and OpenCV on one thread
(:func:`one_thread_per_process`).

The per-frame image stages allocate and free many arrays of 0.1-5 MB. With glibc's default
policy such blocks are ``mmap``-ed and ``munmap``-ed (or trimmed off the heap top) again and
again, and every new block costs one page fault per 4 kB page on first touch (~1 us each in a
VM): measured on ``bench particles`` (60000 particles, 640x480) that was about half of the
frame's CPU time. ``mallopt`` (glibc, ``man 3 mallopt``) with a high ``M_MMAP_THRESHOLD`` and
``M_TRIM_THRESHOLD`` makes the heap keep and reuse those pages: the resident set stays at its
peak instead (a few hundred MB per render worker). No-op on other C libraries.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools

M_TRIM_THRESHOLD, M_TOP_PAD, M_MMAP_THRESHOLD = -1, -2, -3
MMAP_THRESHOLD_B = 32 * 2**20  # glibc's maximum on 64-bit (HEAP_MAX_SIZE / 2)
TRIM_THRESHOLD_B = 1 * 2**30
TOP_PAD_B = 64 * 2**20


@functools.cache
def keep_heap() -> bool:
    """Apply the policy once per process; True if glibc accepted it."""
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
        mallopt = getattr(libc, "mallopt", None)
    except OSError:
        return False
    if mallopt is None:
        return False
    ok = [
        mallopt(opt, val)
        for opt, val in (
            (M_MMAP_THRESHOLD, MMAP_THRESHOLD_B),
            (M_TRIM_THRESHOLD, TRIM_THRESHOLD_B),
            (M_TOP_PAD, TOP_PAD_B),
        )
    ]
    return all(r == 1 for r in ok)


def one_thread_per_process() -> None:
    """Run BLAS (numpy's and scipy's OpenBLAS, via threadpoolctl) and OpenCV on the calling thread.

    The pipeline's parallelism is one process per core. A threaded OpenBLAS keeps its threads
    spinning for tens of ms after a product, even a small one (measured: a lamp's beam table
    at a sequence's start made the next 20 particle frames cost 2.3x their wall time in CPU,
    ``bench particles``)."""
    import cv2
    from threadpoolctl import threadpool_limits

    threadpool_limits(1, user_api="blas")
    cv2.setNumThreads(1)
