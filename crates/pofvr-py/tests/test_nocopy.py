"""Volumes from numpy are borrowed, not copied."""

import gc
import sys

import numpy as np
import pytest

import pofvr
from conftest import blobs, family


def rss_bytes():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * __import__("os").sysconf("SC_PAGE_SIZE")


@pytest.mark.parametrize("dtype", ["uint8", "uint16", "int16", "float32"])
def test_scene_reads_the_arrays_own_buffer(dtype):
    a = blobs((20, 24, 28), dtype, 200)
    scene = pofvr.Scene(a, tf=family(200))
    assert scene._voxel_address == a.ctypes.data
    assert scene.shape == a.shape and scene.dims == a.shape[::-1]
    assert not a.flags.writeable, "the borrowed array is locked against writes"
    with pytest.raises(ValueError, match="read-only"):
        a[0, 0, 0] = 1


def test_scene_keeps_the_array_alive():
    a = blobs((20, 24, 28), "uint16", 1000)
    expect = pofvr.Scene(a.copy(), tf=family(1000)).render(size=(32, 32)).rgba_float
    refs = sys.getrefcount(a)
    scene = pofvr.Scene(a, tf=family(1000))
    assert sys.getrefcount(a) == refs + 1, "the scene holds one reference"
    del a
    gc.collect()
    assert scene.render(size=(32, 32)).rgba_float.tobytes() == expect.tobytes()


@pytest.mark.skipif(not __import__("os").path.exists("/proc/self/statm"), reason="needs /proc (Linux)")
def test_resident_memory_does_not_grow_by_the_volume():
    a = np.zeros((128, 256, 256), np.uint16)  # 16 MiB
    a[32:96, 64:192, 64:192] = 1500
    a.fill(a.max())  # touch every page before measuring
    before = rss_bytes()
    scene = pofvr.Scene(a, tf=family(3000))
    grown = rss_bytes() - before
    assert grown < a.nbytes / 4, f"resident memory grew by {grown} bytes for a {a.nbytes}-byte volume"
    assert scene._voxel_address == a.ctypes.data
