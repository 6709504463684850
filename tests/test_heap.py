"""evalkit.heap: a worker that keeps its freed heap does not fault image-sized arrays in again."""
import subprocess
import sys

import pytest

_PROBE = """
import resource, sys
import numpy as np
if sys.argv[1] == "keep":
    from evalkit.heap import keep_freed_heap
    assert keep_freed_heap()
def frame():                 # a frame's temporaries: three 3.7 MB images, then all freed
    a = [np.ones((480, 640, 3), np.float32) for _ in range(3)]
    del a
frame()                      # first touch: faults either way
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    frame()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc mallopt")
def test_freed_image_arrays_are_reused_not_faulted_in_again():
    def faults(mode):
        r = subprocess.run([sys.executable, "-c", _PROBE, mode], capture_output=True, text=True, check=True)
        return int(r.stdout.strip())
    default, kept = faults("default"), faults("keep")
    assert default > 20 * 900         # freed heap above glibc's trim threshold goes back to the OS
    assert kept < 200                 # the same heap pages are reused
