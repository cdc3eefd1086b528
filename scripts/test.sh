#!/usr/bin/env bash
# The test suite: sets up what is missing, then runs every test of the workspace
# (GPU tests render on a real adapter or on Mesa's lavapipe; the windowed tests
# of the viewer and the winit example draw on the X server of DISPLAY, or on an
# Xvfb started here). The remote-store tests read from a Range HTTP server and
# an S3 server (moto) started here on loopback, and the smoke run of the
# benchmark that compares with VTK needs VTK's Python package, installed here;
# they are marked ignored in a plain `cargo test` and run in a second pass
# below.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/ensure-env.sh
trap 'stop_display; stop_remote_servers' EXIT
ensure_display
ensure_remote_servers
ensure_vtk
export BRICKRAY_TEST_OUTPUT="${BRICKRAY_TEST_OUTPUT:-$PWD/target/test-images}"
# A one-off run (CI) gains nothing from incremental compilation and would keep
# gigabytes of its caches.
if [ "${CI:-}" = true ]; then export CARGO_INCREMENTAL="${CARGO_INCREMENTAL:-0}"; fi
status=0
cargo test --workspace --no-fail-fast "$@" || status=$?
# The tests that need the servers or VTK (the only ignored tests of a plain
# `cargo test`). Workspace-wide, so that features unify as in the first pass
# and nothing is built twice.
BRICKRAY_ALLOW_HTTP=1 cargo test --workspace --no-fail-fast --tests -- --ignored || status=$?
# The API documentation builds without warnings (broken intra-doc links among
# them); skipped when the run is filtered to some tests.
if [ $# -eq 0 ]; then
    RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps || status=$?
fi
exit "$status"
