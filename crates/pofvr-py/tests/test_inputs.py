"""Every bad input raises the right exception, with a message naming the problem."""

import errno

import numpy as np
import pytest

import pofvr
from conftest import TFS, blobs, family

TF = family(1000)


def vol(dtype="uint16", shape=(12, 14, 16)):
    return blobs(shape, dtype, 1000)


@pytest.mark.parametrize(
    "arr,exc,words",
    [
        ([[[1, 2]]], TypeError, ["numpy.ndarray", "list"]),
        (np.zeros((4, 4, 4), np.float64), TypeError, ["float64", "uint8, uint16, int16 or float32"]),
        (np.zeros((4, 4, 4), np.int32), TypeError, ["int32"]),
        (np.zeros((4, 4, 4), ">i2"), TypeError, [">i2", "big-endian"]),
        (np.zeros((4, 4), np.uint8), ValueError, ["shape (4, 4)", "2 dimensions"]),
        (np.zeros((2, 4, 4, 4), np.uint8), ValueError, ["shape (2, 4, 4, 4)"]),
        (np.zeros((4, 5, 6), np.uint16, order="F"), ValueError, ["strides (2, 8, 40)", "C-contiguous"]),
        (np.zeros((4, 5, 12), np.uint8)[:, :, ::2], ValueError, ["strides (60, 12, 2)", "C-contiguous"]),
        (np.zeros((0, 5, 6), np.uint8), ValueError, ["shape (0, 5, 6)", "zero dimension"]),
    ],
)
def test_bad_arrays(arr, exc, words):
    with pytest.raises(exc) as e:
        pofvr.Scene(arr, tf=TF)
    for w in words:
        assert w in str(e.value)
    if isinstance(arr, np.ndarray):
        assert arr.flags.writeable, "a rejected array is left writeable"


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_floats_rejected_as_the_cli_does(bad):
    a = vol("float32")
    a[3, 4, 5] = bad
    with pytest.raises(pofvr.InputError) as e:
        pofvr.Scene(a, tf=family(1.0))
    assert isinstance(e.value, ValueError) and isinstance(e.value, pofvr.Error)
    index = 5 + 16 * (4 + 14 * 3)
    assert f"non-finite value {bad} at voxel index {index}" in str(e.value).replace("NaN", "nan")
    assert "numpy array" in str(e.value)


def test_misaligned_buffer():
    buf = np.zeros(2 * 4 * 4 * 4 + 1, np.uint8)
    a = np.frombuffer(buf.data, dtype=np.uint16, count=64, offset=1).reshape(4, 4, 4)
    with pytest.raises(ValueError, match="not aligned"):
        pofvr.Scene(a, tf=TF)


@pytest.mark.parametrize(
    "kwargs,words",
    [
        ({"spacing": (1, -1, 1)}, ["bad spacing", "-1"]),
        ({"spacing": (1, float("nan"), 1)}, ["bad spacing"]),
        ({"weights": [1.0]}, ["the weights given", "got 1 weights", "one per basis (2)"]),
        ({"weights": [1.0, -2.0]}, ["weights", "-2"]),
        ({"step": 0.0}, ["sample step", "got 0"]),
        ({"ert": -1.0}, ["early-termination threshold"]),
        ({"brick": 1}, ["brick"]),
    ],
)
def test_bad_scene_settings(kwargs, words):
    with pytest.raises(pofvr.InputError) as e:
        pofvr.Scene(vol(), tf=TF, **kwargs)
    msg = str(e.value)
    for w in words:
        assert w.lower() in msg.lower(), msg


def test_bad_families(tmp_path):
    with pytest.raises(pofvr.FileError) as e:
        pofvr.Scene(vol(), tf=str(tmp_path / "missing.json"))
    assert isinstance(e.value, OSError) and e.value.errno == errno.ENOENT
    assert "missing.json" in str(e.value)
    bad = dict(TF, bases=[{"name": "x", "opacity": [[5, 0.1], [1, 0.2]]}], weights=[1.0])
    with pytest.raises(pofvr.InputError, match=r"tf dict: bases\[0\]\.opacity"):
        pofvr.Scene(vol(), tf=bad)
    with pytest.raises(pofvr.InputError, match="tf dict"):
        pofvr.Scene(vol(), tf={"bases": 3})
    with pytest.raises(TypeError, match="tf: expected a path"):
        pofvr.Scene(vol(), tf=42)


def test_bad_render_arguments():
    scene = pofvr.Scene(vol(), tf=TF)
    cases = [
        ({"weights": [1, 2, 3]}, "weights: got 3 values"),
        ({"weights": [1, float("inf")]}, "weights[1]"),
        ({"cull": "sideways"}, "cull: unknown"),
        ({"cull": "pof"}, "cull: pof needs POFs"),
        ({"engine": "warp"}, "engine: unknown engine"),
        ({"engine": "march", "cull": "exact"}, "march engine cannot render"),
        ({"size": (0, 10)}, "size: (0, 10)"),
        ({"view": (float("nan"), 0)}, "view: (NaN, 0) is not a finite"),
        ({"projection": "fisheye"}, "projection"),
        ({"threshold": 0.0}, "cull threshold"),
        ({"ranks": 0}, "rank count"),
        ({"threads": 0}, "threads: got 0"),
        ({"whole": True, "cull": "exact"}, "whole"),
        ({"curve": "peano"}, "curve"),
    ]
    for kwargs, words in cases:
        with pytest.raises(pofvr.InputError) as e:
            scene.render(**{"size": (16, 16), **kwargs})
        assert words in str(e.value), (kwargs, str(e.value))


def test_bad_cameras():
    scene = pofvr.Scene(vol(), tf=TF)
    cam = scene.render(size=(16, 16)).camera
    with pytest.raises(pofvr.InputError, match="camera: position: must differ from focal_point"):
        scene.render(camera=dict(cam, position=cam["focal_point"]))
    with pytest.raises(pofvr.InputError, match="camera: view_up"):
        scene.render(camera=dict(cam, view_up=[0, 0, 0]))
    with pytest.raises(pofvr.InputError, match="camera: parallel_scale"):
        scene.render(camera=dict(cam, parallel_scale=-1))
    with pytest.raises(pofvr.InputError, match="camera: missing field `width`"):
        scene.render(camera={k: v for k, v in cam.items() if k != "width"})


def test_bad_files(tmp_path):
    with pytest.raises(pofvr.FileError) as e:
        pofvr.open(tmp_path / "nope.nhdr", tf=str(TFS / "ct-head-skin-bone.json"))
    assert e.value.errno == errno.ENOENT and "nope.nhdr" in str(e.value)
    with pytest.raises(pofvr.InputError, match="unknown volume format"):
        pofvr.open(tmp_path / "x.vol", tf=TF)
    short = tmp_path / "short.raw"
    short.write_bytes(b"\0" * 10)
    with pytest.raises(pofvr.Error, match="short.raw"):
        pofvr.open(short, tf=TF, dims=(4, 4, 4), dtype="u16")
    with pytest.raises(pofvr.InputError, match="dtype: unknown data type"):
        pofvr.open(short, tf=TF, dims=(4, 4, 4), dtype="u7")
    with pytest.raises(pofvr.InputError, match="need both dims"):
        pofvr.open(short, tf=TF, dims=(4, 4, 4))
    with pytest.raises(pofvr.InputError, match="tf: a family"):
        pofvr.open(short, dims=(4, 4, 4), dtype="u8")
    with pytest.raises(pofvr.InputError, match="phantom size"):
        pofvr.open("phantom:head:1")
    scene = pofvr.Scene(vol(), tf=TF)
    with pytest.raises(pofvr.FileError, match="missing.pof"):
        scene.load_pofs(tmp_path / "missing.pof")
    with pytest.raises(pofvr.FileError, match="cannot write"):
        scene.render(size=(8, 8)).save(tmp_path / "no" / "such" / "dir.png")
