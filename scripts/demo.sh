#!/usr/bin/env bash
# The demo: sets up what is missing, then renders to PNG files and says where.
# Usage: scripts/demo.sh [extra demo arguments]
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/ensure-env.sh
cargo run --quiet -p brickray --example demo -- "$@"
