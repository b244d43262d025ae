"""A 36-frame orbit of a catalogued volume rendered into an animated GIF.

    python orbit_gif.py [OUT.gif] [--size 256]

Reads the catalogue's CT head (../shared/data/headsq_quarter, a raw file read with numpy
and borrowed by the scene, not copied) with tfs/ct-head-skin-bone.json, shaded. Without
../shared/data (or $POFVR_DATA) it says so and orbits the built-in smooth head phantom.
"""

import argparse
import os
import pathlib
import sys
import time

import numpy as np
from PIL import Image

import pofvr

REPO = pathlib.Path(__file__).resolve().parents[3]


def scene():
    data = pathlib.Path(os.environ.get("POFVR_DATA", REPO.parent / "shared" / "data"))
    folder = data / "headsq_quarter"
    raws = sorted(folder.glob("*.raw")) if folder.is_dir() else []
    if not raws:
        print(f"{folder} not found: orbiting the smooth head phantom instead", file=sys.stderr)
        return pofvr.open("phantom:smooth-head:128"), "phantom:smooth-head:128"
    # 64 × 64 × 93 i16, x fastest: the array is (z, y, x); spacing is (sx, sy, sz).
    vol = np.fromfile(raws[0], dtype="<i2").reshape(93, 64, 64)
    tf = REPO / "tfs" / "ct-head-skin-bone.json"
    return pofvr.Scene(vol, spacing=(3.2, 3.2, 1.5), tf=str(tf)), raws[0].name


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", nargs="?", default="orbit.gif")
    ap.add_argument("--size", type=int, default=256)
    a = ap.parse_args()
    s, name = scene()
    frames, ms = [], []
    t0 = time.perf_counter()
    for i in range(36):
        # 10° of azimuth (about the volume's y axis) per frame.
        f = s.render(view=(10 * i, 20), size=(a.size, a.size), shade=True)
        ms.append(f.stats["frame_ms"])
        # GIFs have no alpha: composite the straight-alpha frame over black.
        rgba = f.rgba.astype(np.float32) / 255
        rgb = rgba[..., :3] * rgba[..., 3:]
        frames.append(Image.fromarray((rgb * 255 + 0.5).astype(np.uint8)))
    frames[0].save(a.out, save_all=True, append_images=frames[1:], duration=60, loop=0)
    print(
        f"{a.out}: 36 frames of {name} at {a.size}², median {sorted(ms)[18]:.1f} ms per frame, "
        f"{time.perf_counter() - t0:.1f} s in all"
    )


if __name__ == "__main__":
    main()
