#!/usr/bin/env bash
# Runs the viewer end-to-end test in headless Chromium: installs Debian's chromium and
# playwright-core when missing, builds volrad, and runs viewer.mjs (prints "N passed, M failed").
# Usage: bash tests/e2e/run.sh [screenshot.png]
set -euo pipefail
cd "$(dirname "$0")/../.."
if ! command -v chromium >/dev/null; then
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
fi
if [ ! -d tests/e2e/node_modules/playwright-core ]; then
  (cd tests/e2e && npm ci --no-audit --no-fund --silent)
fi
cargo build -p volrad --bin volrad --quiet
VOLRAD_BIN="${CARGO_TARGET_DIR:-target}/debug/volrad" CHROMIUM="$(command -v chromium)" node tests/e2e/viewer.mjs "$@"
