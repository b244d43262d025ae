#!/usr/bin/env python3
"""Generates the 512x512x1728 i16 benchmark volume of issue 16 from the chest CT.

The catalogued chest CT (lidc2_ct_chest, 256x256x133 u8, spacing 1.40625 x 1.40625 x 2.5 mm)
is resampled linearly to 512x512 in x and y and to 1728 slices in z (voxel centres spread
over the same extent), written as little-endian int16 on the CT's own 0..255 scale, so that
tfs/ct-chest-skin-bone.json applies unchanged. The spacing keeps the extent between the first
and last voxel centres (about 0.7017 x 0.7017 x 0.1911 mm). The output is about 906 MB: write it outside the repository.

    python3 benches/volumes/chest1728.py ../shared/data/lidc2_ct_chest/lidc2_ct_chest.nhdr /tmp/chest1728

writes /tmp/chest1728/chest1728.nhdr and its raw file. Needs numpy only.
"""

import os
import sys

import numpy as np

NX, NY, NZ = 512, 512, 1728


def read_nhdr(path):
    fields = {}
    with open(path) as f:
        for line in f:
            if ":" in line and not line.startswith("#"):
                k, v = line.split(":", 1)
                fields[k.strip()] = v.strip()
    dims = [int(x) for x in fields["sizes"].split()]
    spacing = [float(x) for x in fields["spacings"].split()]
    assert fields["type"] in ("uint8", "unsigned char"), fields["type"]
    raw = os.path.join(os.path.dirname(path), fields["data file"])
    data = np.fromfile(raw, dtype=np.uint8).reshape(dims[2], dims[1], dims[0])
    return data, dims, spacing


def weights(n_in, n_out):
    """Linear interpolation from n_in samples to n_out over the same extent (end points kept)."""
    x = np.linspace(0.0, n_in - 1.0, n_out)
    i0 = np.minimum(np.floor(x).astype(np.int64), n_in - 2)
    return i0, (x - i0).astype(np.float32)


def main():
    src, out_dir = sys.argv[1], sys.argv[2]
    data, dims, spacing = read_nhdr(src)
    os.makedirs(out_dir, exist_ok=True)
    xi, xf = weights(dims[0], NX)
    yi, yf = weights(dims[1], NY)
    zi, zf = weights(dims[2], NZ)
    # Every input slice upsampled in x and y once (133 x 512 x 512 float32, about 140 MB).
    d = data.astype(np.float32)
    d = d[:, :, xi] * (1 - xf) + d[:, :, xi + 1] * xf
    d = d[:, yi, :] * (1 - yf)[None, :, None] + d[:, yi + 1, :] * yf[None, :, None]
    raw_name = f"chest1728_{NX}x{NY}x{NZ}_int16.raw"
    tmp = os.path.join(out_dir, raw_name + ".part")
    with open(tmp, "wb") as f:
        for z in range(NZ):
            s = d[zi[z]] * (1 - zf[z]) + d[zi[z] + 1] * zf[z]
            np.rint(s).astype("<i2").tofile(f)
    os.replace(tmp, os.path.join(out_dir, raw_name))
    ext = [(n - 1) * s for n, s in zip(dims, spacing)]
    sp = [e / (n - 1) for e, n in zip(ext, (NX, NY, NZ))]
    header = (
        "NRRD0004\n"
        "# lidc2_ct_chest resampled linearly to 512x512x1728 (benches/volumes/chest1728.py)\n"
        "type: int16\ndimension: 3\n"
        f"sizes: {NX} {NY} {NZ}\n"
        f"spacings: {sp[0]:.9g} {sp[1]:.9g} {sp[2]:.9g}\n"
        "endian: little\nencoding: raw\n"
        f"data file: {raw_name}\n"
    )
    with open(os.path.join(out_dir, "chest1728.nhdr"), "w") as f:
        f.write(header)
    print(os.path.join(out_dir, "chest1728.nhdr"))


if __name__ == "__main__":
    main()
