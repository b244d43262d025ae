"""numpy input renders bit for bit the float image `pofvr render --out-raw` writes for the
same data (written as a raw file), camera and family."""

import io
import json
import subprocess

import numpy as np
import pytest
from PIL import Image

import pofvr
from conftest import TFS, blobs, data_dir, family

CASES = [
    # dtype, scale, spacing (sx, sy, sz), extra CLI flags, render kwargs
    ("int16", 3926, (0.98, 0.98, 2.0), ["--shade"], {"shade": True}),
    ("uint8", 255, (1.0, 1.0, 1.0), ["--cull", "exact"], {"cull": "exact"}),
    ("uint16", 4000, (1.0, 1.5, 0.5), ["--whole", "--weights", "2,0.5"], {"whole": True, "weights": [2, 0.5]}),
    ("float32", 1.0, (1.0, 1.0, 1.0), ["--engine", "bricks", "--ranks", "3"], {"engine": "bricks", "ranks": 3}),
]


def cli_render(cli, tmp_path, vol, spacing, tf_path, extra, size=(96, 80), view=(30, 20)):
    raw = tmp_path / "vol.raw"
    vol.tofile(raw)
    z, y, x = vol.shape
    dtype = {"int16": "i16", "uint8": "u8", "uint16": "u16", "float32": "f32"}[vol.dtype.name]
    out = tmp_path / "out"
    cmd = [
        str(cli), "render", str(raw), "--dims", f"{x},{y},{z}", "--dtype", dtype,
        "--spacing", ",".join(map(str, spacing)), "--tf", str(tf_path),
        "--view", f"{view[0]},{view[1]}", "--size", f"{size[0]}x{size[1]}",
        "--out", f"{out}.png", "--out-raw", f"{out}.raw", "--camera-out", f"{out}.camera.json",
        "--stats", f"{out}.stats.json", "--quiet", *extra,
    ]
    subprocess.run(cmd, check=True, capture_output=True)
    img = np.fromfile(f"{out}.raw", dtype="<f4").reshape(size[1], size[0], 4)
    png = np.asarray(Image.open(f"{out}.png").convert("RGBA"))
    camera = json.loads(open(f"{out}.camera.json").read())
    stats = json.loads(open(f"{out}.stats.json").read())
    return img, png, camera, stats


@pytest.mark.parametrize("dtype,scale,spacing,flags,kwargs", CASES, ids=[c[0] for c in CASES])
def test_numpy_matches_cli_bit_for_bit(cli, tmp_path, dtype, scale, spacing, flags, kwargs):
    vol = blobs((37, 42, 50), dtype, scale)
    tf_path = tmp_path / "tf.json"
    tf_path.write_text(json.dumps(family(scale)))
    img, png, camera, stats = cli_render(cli, tmp_path, vol, spacing, tf_path, flags)

    scene = pofvr.Scene(vol, spacing=spacing, tf=family(scale))
    frame = scene.render(view=(30, 20), size=(96, 80), **kwargs)
    assert frame.rgba_float.shape == (80, 96, 4)
    assert frame.rgba_float.view(np.uint32).tobytes() == img.view(np.uint32).tobytes()
    assert np.array_equal(frame.rgba, png)
    assert frame.camera == camera
    assert set(frame.stats) == set(stats)
    for key in ("rays", "samples", "engine", "cull", "bricks", "skipped_samples"):
        assert frame.stats[key] == stats[key], key
    assert img[..., 3].max() > 0.2, "the frame is not empty"

    # save() writes what the CLI writes; Jupyter's PNG holds the rgba pixels.
    frame.save(tmp_path / "py.raw")
    assert (tmp_path / "py.raw").read_bytes() == (tmp_path / "out.raw").read_bytes()
    frame.save(tmp_path / "py.png")
    assert np.array_equal(np.asarray(Image.open(tmp_path / "py.png")), png)
    assert np.array_equal(np.asarray(Image.open(io.BytesIO(frame._repr_png_()))), png)

    # The camera dict goes back in and gives the same frame.
    again = scene.render(camera=frame.camera, **kwargs)
    assert again.rgba_float.tobytes() == frame.rgba_float.tobytes()


def test_tf_file_path_and_dict_agree(tmp_path):
    vol = blobs((30, 30, 30), "int16", 3926)
    by_path = pofvr.Scene(vol, tf=str(TFS / "ct-head-skin-bone.json")).render(size=(48, 48))
    by_dict = pofvr.Scene(vol.copy(), tf=json.loads((TFS / "ct-head-skin-bone.json").read_text()))
    assert by_dict.render(size=(48, 48)).rgba_float.tobytes() == by_path.rgba_float.tobytes()


@pytest.mark.skipif(data_dir() is None, reason="needs ../shared/data (real volumes)")
def test_real_ct_from_numpy_matches_cli(cli, tmp_path):
    d = data_dir() / "headsq_quarter"
    raw = next(d.glob("*.raw"))
    vol = np.fromfile(raw, dtype="<i2").reshape(93, 64, 64)
    tf = TFS / "ct-head-skin-bone.json"
    img, _, camera, _ = cli_render(cli, tmp_path, vol, (3.2, 3.2, 1.5), tf, ["--shade"], size=(128, 128))
    frame = pofvr.Scene(vol, spacing=(3.2, 3.2, 1.5), tf=str(tf)).render(size=(128, 128), shade=True)
    assert frame.rgba_float.tobytes() == img.tobytes()
    # The same file through its header, opened by pofvr.open.
    nhdr = next(d.glob("*.nhdr"))
    opened = pofvr.open(nhdr, tf=str(tf)).render(camera=camera, shade=True)
    assert opened.rgba_float.tobytes() == img.tobytes()
