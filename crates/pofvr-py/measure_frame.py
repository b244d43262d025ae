import json, subprocess, sys, time, statistics, pathlib, os
import numpy as np, pofvr
repo = pathlib.Path("/work/wt/python")
d = repo.parent / "shared/data/lidc2_ct_chest"
nhdr = next(d.glob("*.nhdr")); raw = next(d.glob("*.raw"))
tf = repo / "tfs/ct-chest-skin-bone.json"
cli = repo / "target/release/pofvr"
args = ["--view", "30,20", "--size", "512x512", "--shade"]
cli_frame, cli_wall = [], []
for i in range(5):
    t = time.perf_counter()
    subprocess.run([str(cli), "render", str(nhdr), "--tf", str(tf), *args, "--out", "/tmp/m.png", "--out-raw", "/tmp/m.raw", "--stats", "/tmp/m.json", "--quiet"], check=True, capture_output=True)
    cli_wall.append(time.perf_counter() - t)
    cli_frame.append(json.load(open("/tmp/m.json"))["frame_ms"])
vol = np.fromfile(raw, dtype=np.uint8).reshape(133, 256, 256)
t = time.perf_counter(); scene = pofvr.Scene(vol, spacing=(1.40625, 1.40625, 2.5), tf=str(tf)); t_scene = time.perf_counter() - t
py_call, py_frame = [], []
for i in range(6):
    t = time.perf_counter(); f = scene.render(view=(30, 20), size=(512, 512), shade=True); py_call.append(time.perf_counter() - t)
    py_frame.append(f.stats["frame_ms"])
same = f.rgba_float.tobytes() == np.fromfile("/tmp/m.raw", dtype="<f4").tobytes()
med = statistics.median
print(json.dumps({
  "volume": nhdr.name, "load": os.getloadavg(),
  "cli_frame_ms_median": med(cli_frame), "cli_process_wall_s_median": med(cli_wall),
  "py_scene_s": t_scene, "py_first_call_ms": py_call[0] * 1e3, "py_call_ms_median_rest": med(py_call[1:]) * 1e3,
  "py_frame_ms_median_rest": med(py_frame[1:]), "bit_identical_to_cli": same}, indent=1))
