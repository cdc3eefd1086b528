#!/usr/bin/env bash
# The demo: sets up what is missing, then renders to PNG files and says where.
# Usage: scripts/demo.sh [--help] [demo options]
set -euo pipefail
cd "$(dirname "$0")/.."

usage() {
  cat <<'USAGE'
Usage: scripts/demo.sh [options]

Installs what is missing (compiler, Rust, a Vulkan driver), builds the demo
and runs it: it streams a volume out of core, renders a camera path to PNG
files and prints one line of statistics per frame. By default the volume is a
procedural 4096^3 Mandelbulb and the path flies from the whole volume down to
about a voxel per pixel.

Options (passed to the demo, examples/demo.rs):
  --volume FILE    a raw+JSON (.json) or NRRD (.nrrd/.nhdr) volume; it is built
                   into a brick store next to the output and streamed from it
                   and shown along an orbit (default: a procedural 4096^3
                   Mandelbulb, 64 GiB virtual, no data needed)
  --in-core        upload --volume whole instead of streaming it
  --frames N       frames of the camera path (default 16; out of core the
                   first and last views are held while bricks arrive)
  --size PX        image side in pixels (default 256)
  --pool-mib M     GPU brick pool in MiB (default 64)
  --out DIR        where the PNGs go (default out/demo)
  -h, --help       this text

For the interactive viewer: cargo run --release -p brickray-viewer -- [FILE]
USAGE
}

for arg in "$@"; do
  case "$arg" in
    -h|--help) usage; exit 0 ;;
  esac
done

. scripts/ensure-env.sh
if [ ! -x target/debug/examples/demo ]; then
  echo "brickray: building the demo (the first build compiles wgpu and the other dependencies: a few minutes) ..." >&2
fi
cargo build -p brickray --example demo
exec cargo run --quiet -p brickray --example demo -- "$@"
