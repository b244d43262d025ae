"""Sweeps one basis weight and prints the bricks culled per frame.

    python weight_sweep.py [--basis 0] [--steps 9]

POFs are built once for the scene (their cost is paid before the first frame); every
frame then culls with them at its own weights, and the culled bricks change with the
weight of the occluding basis. Reads the catalogue's Colin27 MRI
(../shared/data/ch2better_mri) with tfs/mri-brain-opaque.json; without ../shared/data it
says so and sweeps the built-in head phantom ("skin", "bone").
"""

import argparse
import os
import pathlib
import sys

import numpy as np

import pofvr

REPO = pathlib.Path(__file__).resolve().parents[3]


def scene():
    data = pathlib.Path(os.environ.get("POFVR_DATA", REPO.parent / "shared" / "data"))
    folder = data / "ch2better_mri"
    raws = sorted(folder.glob("*.raw")) if folder.is_dir() else []
    if not raws:
        print(f"{folder} not found: sweeping the head phantom instead", file=sys.stderr)
        return pofvr.open("phantom:head:96", brick=8), 12
    vol = np.fromfile(raws[0], dtype=np.uint8).reshape(316, 370, 301)
    tf = REPO / "tfs" / "mri-brain-opaque.json"
    return pofvr.Scene(vol, spacing=(0.5, 0.5, 0.5), tf=str(tf)), 12


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--basis", type=int, default=0)
    ap.add_argument("--steps", type=int, default=9)
    a = ap.parse_args()
    s, views = scene()
    if not 0 <= a.basis < len(s.bases):
        sys.exit(f"weight_sweep: basis {a.basis} of a family of {len(s.bases)} ({s.bases})")
    s.build_pofs(views=(views, views))
    print(f"{s}\nsweeping basis {a.basis} ({s.bases[a.basis]!r}) over [0, 4]")
    print(f"{'weight':>7} {'culled':>7} {'non-empty':>10} {'visible':>8} {'ms':>8}")
    for i in range(a.steps):
        w = list(s.default_weights)
        w[a.basis] = 4.0 * i / max(a.steps - 1, 1)
        f = s.render(view=(0, 0), size=(384, 384), weights=w, cull="pof")
        b = f.stats["bricks"]
        print(f"{w[a.basis]:7.2f} {b['culled']:7d} {b['non_empty']:10d} {b['visible']:8d} {f.stats['frame_ms']:8.1f}")


if __name__ == "__main__":
    main()
