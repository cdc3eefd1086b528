#!/usr/bin/env bash
# The test suite: sets up what is missing, then runs every test of the workspace
# (GPU tests render on a real adapter or on Mesa's lavapipe; the windowed tests
# of the viewer and the winit example draw on the X server of DISPLAY, or on an
# Xvfb started here).
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/ensure-env.sh
ensure_display
trap stop_display EXIT
export BRICKRAY_TEST_OUTPUT="${BRICKRAY_TEST_OUTPUT:-$PWD/target/test-images}"
cargo test --workspace --no-fail-fast "$@"
# The API documentation builds without warnings (broken intra-doc links among
# them); skipped when the run is filtered to some tests.
if [ $# -eq 0 ]; then
    RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps
fi
