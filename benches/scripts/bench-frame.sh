#!/usr/bin/env bash
# The `bench frame` report of docs/results.md: every catalogued volume/family pair and the
# generated 1728-slice chest CT, VTK in the same run.
#   benches/scripts/bench-frame.sh OUT.json [POFVR_BINARY]
# Environment: ROUNDS (rounds per frame, each with its own VTK process, default 3), DATA
# (default ../shared/data), BIG (the folder benches/volumes/chest1728.py wrote, default
# /work/big/chest1728), PEER_PYTHON (a Python with vtk, numpy and pillow), PEER (default
# ../shared/peer/vtk_render.py).
set -euo pipefail
cd "$(dirname "$0")/../.."
out=${1:?usage: bench-frame.sh OUT.json [pofvr]}
bin=${2:-target/release/pofvr}
D=${DATA:-../shared/data}
big=${BIG:-/work/big/chest1728}
"$bin" --threads 2 --quiet bench frame \
  --volume "$D/lidc2_ct_chest/lidc2_ct_chest.nhdr" --tf tfs/ct-chest-skin-bone.json \
  --volume "$D/headsq_quarter/headsq_quarter.nhdr" --tf tfs/ct-head-skin-bone.json \
  --volume "$D/ch2better_mri/ch2better_mri.nhdr" --tf tfs/mri-brain-opaque.json \
  --volume "$D/ch2better_mri/ch2better_mri.nhdr" --tf tfs/mri-brain.json \
  --volume "$D/neghip/neghip.nhdr" --tf tfs/sim-isobands.json \
  --volume "$D/ironprot/ironprot.nhdr" --tf tfs/sim-isobands.json \
  --volume "$D/hydrogen/hydrogen.nhdr" --tf tfs/sim-hydrogen.json \
  --volume "$big/chest1728.nhdr" --tf tfs/ct-chest-skin-bone.json \
  --size 512x512 --reps 5 --rounds "${ROUNDS:-3}" \
  --peer-python "${PEER_PYTHON:-/work/venv-vtk/bin/python}" \
  --peer-script "${PEER:-../shared/peer/vtk_render.py}" --json "$out"
