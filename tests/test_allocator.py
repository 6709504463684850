"""pipeline/allocator.py: glibc accepts the heap policy, once per process."""
import platform

import pytest

from blendgen.pipeline import allocator


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_glibc_accepts_the_heap_policy_once():
    assert allocator.keep_heap() is True
    assert allocator.keep_heap() is True and allocator.keep_heap.cache_info().misses == 1


def test_policy_values_are_within_glibc_limits():
    assert 0 < allocator.MMAP_THRESHOLD_B <= 32 * 2 ** 20      # HEAP_MAX_SIZE / 2 on 64-bit
    assert allocator.TRIM_THRESHOLD_B >= allocator.MMAP_THRESHOLD_B
