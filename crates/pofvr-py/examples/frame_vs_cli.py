"""One frame from Python against the same frame from `pofvr render`: times and bit identity.

    python frame_vs_cli.py [PATH/TO/pofvr]

The catalogue's chest CT (../shared/data/lidc2_ct_chest, read with numpy) with
tfs/ct-chest-skin-bone.json, view 30,20, 512², shaded: five CLI runs (the frame's own
frame_ms from --stats, and the whole process), then six frames from one Python scene (the
first, then the median of the rest: the march engine measures the volume's cells once per
scene, on its first frame). Needs ../shared/data (or $POFVR_DATA) and target/release/pofvr.
"""

import json
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

import pofvr

REPO = pathlib.Path(__file__).resolve().parents[3]


def main():
    data = pathlib.Path(os.environ.get("POFVR_DATA", REPO.parent / "shared" / "data"))
    d = data / "lidc2_ct_chest"
    if not d.is_dir():
        sys.exit(f"frame_vs_cli: {d} not found (needs ../shared/data)")
    nhdr, raw = next(d.glob("*.nhdr")), next(d.glob("*.raw"))
    tf = REPO / "tfs" / "ct-chest-skin-bone.json"
    cli = sys.argv[1] if len(sys.argv) > 1 else REPO / "target" / "release" / "pofvr"
    tmp = pathlib.Path(tempfile.mkdtemp())
    cli_frame, cli_wall = [], []
    for _ in range(5):
        t = time.perf_counter()
        subprocess.run(
            [str(cli), "render", str(nhdr), "--tf", str(tf), "--view", "30,20", "--size", "512x512",
             "--shade", "--out", str(tmp / "f.png"), "--out-raw", str(tmp / "f.raw"),
             "--stats", str(tmp / "f.json"), "--quiet"],
            check=True, capture_output=True)
        cli_wall.append(time.perf_counter() - t)
        cli_frame.append(json.loads((tmp / "f.json").read_text())["frame_ms"])
    vol = np.fromfile(raw, dtype=np.uint8).reshape(133, 256, 256)
    t = time.perf_counter()
    scene = pofvr.Scene(vol, spacing=(1.40625, 1.40625, 2.5), tf=str(tf))
    t_scene = time.perf_counter() - t
    calls, frames = [], []
    for _ in range(6):
        t = time.perf_counter()
        f = scene.render(view=(30, 20), size=(512, 512), shade=True)
        calls.append(time.perf_counter() - t)
        frames.append(f.stats["frame_ms"])
    same = f.rgba_float.tobytes() == np.fromfile(tmp / "f.raw", dtype="<f4").tobytes()
    med = statistics.median
    print(json.dumps({
        "load_average": os.getloadavg(),
        "cli_frame_ms_median": med(cli_frame),
        "cli_process_s_median": med(cli_wall),
        "py_scene_s": t_scene,
        "py_first_call_ms": calls[0] * 1e3,
        "py_call_ms_median_rest": med(calls[1:]) * 1e3,
        "py_frame_ms_median_rest": med(frames[1:]),
        "bit_identical_to_cli": same,
    }, indent=1))


if __name__ == "__main__":
    main()
