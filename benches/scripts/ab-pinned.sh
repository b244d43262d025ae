#!/usr/bin/env bash
# A/B of march frame times between two pofvr binaries on one pinned core: for a noisy VM,
# where two-thread medians (ab-march.sh) move by 10-40 % from run to run. Per frame,
# `render --threads 1 --frames 10 --orbit 0` under `taskset -c $CPU`, ROUNDS times per
# binary, the order alternating round by round; prints the least median of each binary
# and their ratio (B / A).
#   benches/scripts/ab-pinned.sh ROUNDS BINARY_A BINARY_B   (two different paths)
# Environment: CASES ("VOLUME TF VIEW off|on;..."; default below), CPU (default 1).
set -euo pipefail
cd "$(dirname "$0")/../.."
rounds=$1 a=$2 b=$3
D=${DATA:-../shared/data}
cases=${CASES:-"$D/lidc2_ct_chest/lidc2_ct_chest.nhdr tfs/ct-chest-skin-bone.json 30,20 off;\
$D/lidc2_ct_chest/lidc2_ct_chest.nhdr tfs/ct-chest-skin-bone.json 0,90 off;\
$D/headsq_quarter/headsq_quarter.nhdr tfs/ct-head-skin-bone.json 30,20 on;\
$D/neghip/neghip.nhdr tfs/sim-isobands.json 30,20 off;\
$D/ch2better_mri/ch2better_mri.nhdr tfs/mri-brain.json 0,90 off"}
png=$(mktemp --suffix=.png)
IFS=';' read -ra list <<<"$cases"
for c in "${list[@]}"; do
  read -r vol tf view shade <<<"$c"
  flag=(); [ "$shade" = on ] && flag=(--shade)
  best_a=inf best_b=inf
  for r in $(seq "$rounds"); do
    order=("$a" "$b"); [ $((r % 2)) = 0 ] && order=("$b" "$a")
    for bin in "${order[@]}"; do
      ms=$(taskset -c "${CPU:-1}" "$bin" --threads 1 --quiet render "$vol" --tf "$tf" \
        --view "$view" "${flag[@]}" --size 512x512 --frames 10 --orbit 0 -o "$png" 2>&1 |
        grep -o "median of the rest [0-9.]*" | awk '{print $5}')
      if [ "$bin" = "$a" ]; then
        best_a=$(python3 -c "print(min(float('$best_a'), $ms))")
      else
        best_b=$(python3 -c "print(min(float('$best_b'), $ms))")
      fi
    done
  done
  printf "%-40s %-6s %-4s %8.1f %8.1f  %.3f\n" \
    "$(basename "$vol" .nhdr):$(basename "$tf" .json)" "$view" "$shade" "$best_a" "$best_b" \
    "$(python3 -c "print($best_b / $best_a)")"
done
rm -f "${png%.png}"*.png
