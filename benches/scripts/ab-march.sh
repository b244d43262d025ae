#!/usr/bin/env bash
# A/B of march frame times between pofvr binaries, interleaved round by round: per CT/MRI
# volume, view (30,20 and 0,90) and shading, `render --frames 10 --orbit 0` and its median
# of the frames after the first; prints the median over rounds per binary and the ratio
# to the first binary.
#   benches/scripts/ab-march.sh ROUNDS BINARY_A BINARY_B...
# Environment: DATA (default ../shared/data), BIG (default /work/big/chest1728), VIEWS
# (default "30,20 0,90"), VOLS (instead of the volumes below: "VOLUME TF;VOLUME TF;...").
set -euo pipefail
cd "$(dirname "$0")/../.."
rounds=$1
shift
bins=("$@")
D=${DATA:-../shared/data}
big=${BIG:-/work/big/chest1728}
log=$(mktemp)
vols=("$big/chest1728.nhdr tfs/ct-chest-skin-bone.json"
  "$D/lidc2_ct_chest/lidc2_ct_chest.nhdr tfs/ct-chest-skin-bone.json"
  "$D/headsq_quarter/headsq_quarter.nhdr tfs/ct-head-skin-bone.json"
  "$D/ch2better_mri/ch2better_mri.nhdr tfs/mri-brain.json")
[ -n "${VOLS:-}" ] && IFS=';' read -ra vols <<<"$VOLS"
read -ra views <<<"${VIEWS:-30,20 0,90}"
png=$(mktemp --suffix=.png)
for _ in $(seq "$rounds"); do
  for bin in "${bins[@]}"; do
    for v in "${vols[@]}"; do
      read -r vol tf <<<"$v"
      for view in "${views[@]}"; do
        for shade in off on; do
          flag=(); [ "$shade" = on ] && flag=(--shade)
          ms=$("$bin" --threads 2 --quiet render "$vol" --tf "$tf" --view "$view" "${flag[@]}" \
            --size 512x512 --frames 10 --orbit 0 -o "$png" 2>&1 |
            grep -o "median of the rest [0-9.]*" | awk '{print $5}')
          echo "$bin $(basename "$vol" .nhdr)$(basename "$tf" .json | sed 's/^/:/') $view $shade $ms" >>"$log"
        done
      done
    done
  done
done
python3 - "$log" "${bins[@]}" <<'PY'
import collections, statistics, sys
log, bins = sys.argv[1], sys.argv[2:]
res = collections.defaultdict(list)
for line in open(log):
    b, n, v, s, ms = line.split()
    res[(n, v, s, b)].append(float(ms))
for k in sorted({k[:3] for k in res}):
    m = [statistics.median(res[k + (b,)]) for b in bins]
    print(f"{k[0]:16s} {k[1]:6s} {k[2]:4s} " + "  ".join(f"{x:7.1f}" for x in m)
          + "   ratios " + " ".join(f"{x / m[0]:.3f}" for x in m[1:]))
PY
rm -f "$log" "${png%.png}"*.png
