#!/usr/bin/env bash
# The hardware-GPU figures of issue 37 (item 8): the `raw`, `ooc`, `host` and
# `accel` suites in one run that fits a few minutes, for a machine with a GPU
# that has no Rust toolchain (the binary is built here and copied there).
#
#   bash scripts/gpu-bench.sh build   # here: build, strip to target/gpu-bench/brickray-bench (about 30 MB)
#   bash scripts/gpu-bench.sh run     # there: run the suites, outputs in $OUT (default target/gpu-bench/out)
#
# `run` needs only the binary and a Vulkan driver. Without ../shared/data
# beside the repository the suites draw their procedural stand-ins (each
# suite names the volume it drew). SMALL=1 runs every suite at its smallest
# (a check of this script on a machine without a GPU). Each suite is cut at
# LIMIT seconds (default 150); a suite that fails or is cut is named in
# failures.txt and the others still run.
set -uo pipefail
cd "$(dirname "$0")/.."
DIR=target/gpu-bench
BIN="$DIR/brickray-bench"

case "${1:-}" in
build)
    cargo build --release -p brickray-bench || exit 1
    mkdir -p "$DIR"
    cp target/release/brickray-bench "$BIN" && strip "$BIN" || exit 1
    ls -l "$BIN"
    ;;
run)
    OUT="${OUT:-$DIR/out}"
    mkdir -p "$OUT"
    [ -x "$BIN" ] || { echo "no $BIN: run 'bash scripts/gpu-bench.sh build' first" >&2; exit 1; }
    if [ "${SMALL:-0}" = 1 ]; then
        SIZE=128 ROUNDS=1 FRAMES=5 CUTS=1000
    else
        SIZE=1024 ROUNDS=5 FRAMES=60 CUTS=1000,5000,20000,50000
    fi
    command -v nvidia-smi >/dev/null && nvidia-smi > "$OUT/nvidia-smi.txt" 2>&1
    suite() {
        local name=$1
        shift
        echo "== $name: $*"
        local t=$SECONDS
        timeout "${LIMIT:-150}" "$BIN" "$@" > "$OUT/$name.txt" 2>&1
        local rc=$?
        echo "   exit $rc after $((SECONDS - t)) s"
        [ $rc = 0 ] || echo "$name: exit $rc" >> "$OUT/failures.txt"
    }
    suite raw raw --size "$SIZE" --rounds "$ROUNDS"
    suite ooc ooc --parts ab --size "$SIZE" --rounds "$ROUNDS"
    suite host host --size "$SIZE" --frames "$FRAMES" --cuts "$CUTS"
    suite accel accel --size "$SIZE" --rounds "$ROUNDS"
    # The last line of each suite is its JSON object.
    for f in "$OUT"/raw.txt "$OUT"/ooc.txt "$OUT"/host.txt "$OUT"/accel.txt; do
        tail -n 1 "$f" > "${f%.txt}.json"
    done
    ;;
*)
    sed -n '2,16p' "$0"
    exit 2
    ;;
esac
