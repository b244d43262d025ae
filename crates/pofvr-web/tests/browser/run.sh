#!/usr/bin/env bash
# Builds `pofvr`, installs the browser test's npm packages if missing and runs the
# real-browser tests (viewer.test.mjs, tf-panel.test.mjs). Needs Debian's `chromium` and `nodejs`/`npm` (apt-get install -y
# chromium nodejs npm). Screenshot and benchmark JSON land in target/browser-artifacts/.
#
#   POFVR_PROFILE=debug|release   build profile (default release)
#   other POFVR_* variables: see viewer.test.mjs
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
repo="$(cd "$here/../../../.." && pwd)"
cd "$repo"

profile="${POFVR_PROFILE:-release}"
if [ "$profile" = release ]; then
  cargo build --release -p pofvr-cli
else
  cargo build -p pofvr-cli
fi
target="${CARGO_TARGET_DIR:-$repo/target}"
export POFVR_BIN="${POFVR_BIN:-$target/$profile/pofvr}"
export POFVR_ARTIFACTS="${POFVR_ARTIFACTS:-$repo/target/browser-artifacts}"

for tool in node npm; do
  command -v "$tool" >/dev/null || { echo "run.sh: $tool is required (apt-get install -y nodejs npm)"; exit 1; }
done
[ -x "${CHROMIUM:-/usr/bin/chromium}" ] || { echo "run.sh: ${CHROMIUM:-/usr/bin/chromium} is missing (apt-get install -y chromium)"; exit 1; }

cd "$here"
if [ ! -d node_modules/playwright-core ]; then
  npm ci --no-audit --no-fund
fi
node --test --test-reporter=spec viewer.test.mjs tf-panel.test.mjs
