#!/usr/bin/env python3
"""Generates a 2048x2048x2048 u16 volume (16 GiB) from the chest CT, one slice at a time.

The scale case of issue 18: a volume of two thirds of the development machine's memory,
rendered with `--memory-budget 4G` (docs/large-data.md). The catalogued chest CT
(lidc2_ct_chest, 256x256x133 u8) is resampled linearly to 2048 voxels on every axis (voxel
centres over the same extent) and written as little-endian uint16 on the CT's own 0..255
scale, so that tfs/ct-chest-skin-bone.json applies unchanged. Each output slice is made
from the two input slices around it and written at once: the script holds a few slices
(tens of MB), never the volume.

    python3 benches/volumes/chest2048.py ../shared/data/lidc2_ct_chest/lidc2_ct_chest.nhdr /work/big/x [N]

writes /work/big/x/chest2048.nhdr and its raw file (N voxels per axis, default 2048; a
smaller N gives the same volume at another size, for trying it out). Needs numpy only. The
raw file is written as `.part` and renamed when complete.
"""

import os
import sys

import numpy as np

from chest1728 import read_nhdr, weights


def main():
    src, out_dir = sys.argv[1], sys.argv[2]
    n = int(sys.argv[3]) if len(sys.argv) > 3 else 2048
    data, dims, spacing = read_nhdr(src)
    os.makedirs(out_dir, exist_ok=True)
    xi, xf = weights(dims[0], n)
    yi, yf = weights(dims[1], n)
    zi, zf = weights(dims[2], n)
    d = data.astype(np.float32)
    raw_name = f"chest2048_{n}x{n}x{n}_uint16.raw"
    tmp = os.path.join(out_dir, raw_name + ".part")
    with open(tmp, "wb") as f:
        for z in range(n):
            s = d[zi[z]] * (1 - zf[z]) + d[zi[z] + 1] * zf[z]
            s = s[:, xi] * (1 - xf) + s[:, xi + 1] * xf
            s = s[yi, :] * (1 - yf)[:, None] + s[yi + 1, :] * yf[:, None]
            np.rint(s).astype("<u2").tofile(f)
            if z % 256 == 255:
                print(f"{z + 1}/{n} slices", file=sys.stderr, flush=True)
    os.replace(tmp, os.path.join(out_dir, raw_name))
    ext = [(m - 1) * s for m, s in zip(dims, spacing)]
    sp = [e / (n - 1) for e in ext]
    header = (
        "NRRD0004\n"
        f"# lidc2_ct_chest resampled linearly to {n}^3 (benches/volumes/chest2048.py)\n"
        "type: uint16\ndimension: 3\n"
        f"sizes: {n} {n} {n}\n"
        f"spacings: {sp[0]:.9g} {sp[1]:.9g} {sp[2]:.9g}\n"
        "endian: little\nencoding: raw\n"
        f"data file: {raw_name}\n"
    )
    with open(os.path.join(out_dir, "chest2048.nhdr"), "w") as f:
        f.write(header)
    print(os.path.join(out_dir, "chest2048.nhdr"))


if __name__ == "__main__":
    main()
