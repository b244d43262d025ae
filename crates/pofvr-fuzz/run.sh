#!/usr/bin/env bash
# Runs one fuzz target (or `all`) for COUNT inputs: crates/pofvr-fuzz/run.sh TARGET COUNT [runner flags]
# e.g. crates/pofvr-fuzz/run.sh nrrd 1000000 --seed 7. Findings land in crates/pofvr-fuzz/findings/.
set -euo pipefail
cd "$(dirname "$0")/../.."
[ $# -ge 2 ] || { echo "usage: $0 TARGET|all COUNT [--seed S] [--time-limit-ms MS] [--only N]"; exit 2; }
cargo build --release -q -p pofvr-fuzz
exec target/release/pofvr-fuzz "$@"
