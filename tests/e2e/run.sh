#!/usr/bin/env bash
# Runs the viewer end-to-end test in headless Chromium: installs Debian's chromium and
# playwright-core when missing, builds volrad unless $VOLRAD_BIN names a binary, and runs
# viewer.mjs (prints "N passed, M failed").
# Usage: [VOLRAD_BIN=path/to/volrad] bash tests/e2e/run.sh [screenshot.png]
set -euo pipefail
cd "$(dirname "$0")/../.."
if ! command -v chromium >/dev/null; then
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
fi
if [ ! -d tests/e2e/node_modules/playwright-core ]; then
  (cd tests/e2e && npm ci --no-audit --no-fund --silent)
fi
# The volrad binary: $VOLRAD_BIN when given (CI passes the one its optimised tests built, so
# nothing is compiled again), else a debug build of this checkout.
if [ -z "${VOLRAD_BIN:-}" ]; then
  cargo build -p volrad --bin volrad --quiet
  VOLRAD_BIN="${CARGO_TARGET_DIR:-target}/debug/volrad"
fi
VOLRAD_BIN="$VOLRAD_BIN" CHROMIUM="$(command -v chromium)" node tests/e2e/viewer.mjs "$@"
