"""pipeline/allocator.py: glibc accepts the heap policy, once per process."""

import platform

import pytest

from blendgen.pipeline import allocator


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_glibc_accepts_the_heap_policy_once():
    assert allocator.keep_heap() is True
    assert allocator.keep_heap() is True and allocator.keep_heap.cache_info().misses == 1


def test_policy_values_are_within_glibc_limits():
    assert 0 < allocator.MMAP_THRESHOLD_B <= 32 * 2**20  # HEAP_MAX_SIZE / 2 on 64-bit
    assert allocator.TRIM_THRESHOLD_B >= allocator.MMAP_THRESHOLD_B


_PROBE = """
import resource, sys
import numpy as np
if sys.argv[1] == "keep":
    from blendgen.pipeline import allocator
    assert allocator.keep_heap()
def frame():                 # a frame's temporaries: three 3.7 MB images, then all freed
    a = [np.ones((480, 640, 3), np.float32) for _ in range(3)]
    del a
frame()                      # first touch: faults either way
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    frame()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
"""


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_freed_image_arrays_are_reused_not_faulted_in_again():
    """What the policy is for: a worker's per-frame arrays reuse the heap pages."""
    import subprocess
    import sys

    def faults(mode):
        r = subprocess.run([sys.executable, "-c", _PROBE, mode], capture_output=True, text=True, check=True)
        return int(r.stdout.strip())

    assert faults("default") > 20 * 900  # freed heap above glibc's trim threshold goes back to the OS
    assert faults("keep") < 200  # the same heap pages are reused


_THREADS_PROBE = """
import time, sys
import numpy as np
if sys.argv[1] == "one":
    from blendgen.pipeline import allocator
    allocator.one_thread_per_process()
import cv2
from threadpoolctl import threadpool_info
a = np.random.default_rng(0).random((600, 600))
time.sleep(0.5)                         # let start-up activity settle
a @ a                                   # a product big enough for a threaded BLAS
c0 = time.process_time()
time.sleep(0.1)                         # nothing to do: OpenBLAS's pool spins ~0.1 s of CPU here
idle = time.process_time() - c0
blas = [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
print(cv2.getNumThreads(), max(blas), round(idle, 3))
"""


def test_one_thread_per_process_stops_blas_threads_spinning():
    """After the policy, BLAS and OpenCV report one thread and an idle process burns no CPU after
    a product (without it, measured: 0.1 s of CPU in the 0.1 s after it on 2 cores)."""
    import os
    import subprocess
    import sys

    run = lambda mode: subprocess.run(
        [sys.executable, "-c", _THREADS_PROBE, mode], capture_output=True, text=True, check=True
    ).stdout.split()
    cv_threads, blas_threads, idle_cpu = run("one")
    assert (cv_threads, blas_threads) == ("1", "1")
    assert float(idle_cpu) < 0.02
    if (os.cpu_count() or 1) > 1:
        assert int(run("default")[1]) > 1
