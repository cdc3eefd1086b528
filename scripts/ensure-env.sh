#!/usr/bin/env bash
# Sourced by demo.sh and test.sh: makes sure a C/C++ compiler, a Rust toolchain
# and a Vulkan driver (a real GPU's, or Mesa's software lavapipe) are present.
# Installs what is missing when run as root (or with password-less sudo; rustup
# needs neither); otherwise stops and prints the exact command to run.
set -euo pipefail

# Runs a command as root: directly, with password-less sudo, or not at all.
as_root() {
  if [ "$(id -u)" = 0 ]; then
    "$@"
  elif command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
    sudo "$@"
  else
    return 126
  fi
}

apt_install() {
  echo "brickray: installing $* ..." >&2
  as_root env DEBIAN_FRONTEND=noninteractive apt-get update -qq &&
    as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null
}

# A C/C++ compiler (the FLIP metric's C++ sources and linking need one).
if ! command -v c++ >/dev/null 2>&1 || ! command -v cc >/dev/null 2>&1; then
  if ! apt_install build-essential; then
    echo "brickray: no C/C++ compiler found. Install one with:" >&2
    echo "  sudo apt-get install -y build-essential" >&2
    exit 1
  fi
fi

# The Rust toolchain, through rustup (Debian's own rustc is too old for edition 2024).
if ! command -v cargo >/dev/null 2>&1 && [ -f "$HOME/.cargo/env" ]; then
  . "$HOME/.cargo/env"
fi
if ! command -v cargo >/dev/null 2>&1; then
  rustup_cmd="curl --proto '=https' --tlsv1.2 -sSf https://sh.rustup.rs | sh -s -- -y"
  if ! command -v curl >/dev/null 2>&1; then
    apt_install curl ca-certificates || true
  fi
  echo "brickray: installing the Rust toolchain with rustup ..." >&2
  if ! (command -v curl >/dev/null 2>&1 && sh -c "$rustup_cmd" >&2); then
    echo "brickray: no Rust toolchain (cargo) found and rustup could not be run. Install it with:" >&2
    echo "  $rustup_cmd && . \"\$HOME/.cargo/env\"" >&2
    exit 1
  fi
  . "$HOME/.cargo/env"
fi

have_vulkan_driver() {
  # An installed Vulkan ICD manifest (lavapipe's is lvp_icd.*.json) and the loader.
  local icd=0 f
  for f in /usr/share/vulkan/icd.d/*.json /etc/vulkan/icd.d/*.json; do
    [ -e "$f" ] && icd=1
  done
  [ "$icd" = 1 ] || return 1
  for f in /usr/lib/*/libvulkan.so.1 /lib/*/libvulkan.so.1 /usr/lib/libvulkan.so.1; do
    [ -e "$f" ] && return 0
  done
  return 1
}

if ! have_vulkan_driver; then
  if ! apt_install mesa-vulkan-drivers libvulkan1; then
    echo "brickray: no Vulkan driver found. Install Mesa's software driver with:" >&2
    echo "  sudo apt-get install -y mesa-vulkan-drivers libvulkan1" >&2
    exit 1
  fi
fi

# Mesa's loader warns when XDG_RUNTIME_DIR is unset; give it a private one.
if [ -z "${XDG_RUNTIME_DIR:-}" ]; then
  export XDG_RUNTIME_DIR="${TMPDIR:-/tmp}/brickray-xdg-$(id -u)"
  mkdir -p "$XDG_RUNTIME_DIR" && chmod 700 "$XDG_RUNTIME_DIR"
fi

# An X server for the windowed tests (the viewer and the winit example):
# `ensure_display` (called by test.sh, not by the demo) keeps a DISPLAY that
# is already set; otherwise it installs Xvfb when missing (as above: as root,
# with password-less sudo, or it stops with the exact command), starts one on
# a free display number and exports DISPLAY. The caller stops it with
# `stop_display` (test.sh does so on exit).
BRICKRAY_XVFB_PID=""
ensure_display() {
  if [ -n "${DISPLAY:-}" ]; then
    return 0
  fi
  if ! command -v Xvfb >/dev/null 2>&1; then
    if ! apt_install xvfb; then
      echo "brickray: no X server for the windowed tests. Install Xvfb with:" >&2
      echo "  sudo apt-get install -y xvfb" >&2
      exit 1
    fi
  fi
  local fdfile
  fdfile="$(mktemp "${TMPDIR:-/tmp}/brickray-xvfb.XXXXXX")"
  # -displayfd: Xvfb picks a free display number and writes it when ready.
  Xvfb -displayfd 3 -screen 0 1280x1024x24 -nolisten tcp 3>"$fdfile" >/dev/null 2>&1 &
  BRICKRAY_XVFB_PID=$!
  local i
  for i in $(seq 1 100); do
    if [ -s "$fdfile" ]; then
      break
    fi
    if ! kill -0 "$BRICKRAY_XVFB_PID" 2>/dev/null; then
      break
    fi
    sleep 0.1
  done
  if [ ! -s "$fdfile" ]; then
    rm -f "$fdfile"
    echo "brickray: Xvfb did not start" >&2
    exit 1
  fi
  export DISPLAY=":$(head -n1 "$fdfile")"
  rm -f "$fdfile"
  echo "brickray: started Xvfb on $DISPLAY for the windowed tests" >&2
}

stop_display() {
  if [ -n "$BRICKRAY_XVFB_PID" ]; then
    kill "$BRICKRAY_XVFB_PID" 2>/dev/null || true
    wait "$BRICKRAY_XVFB_PID" 2>/dev/null || true
    BRICKRAY_XVFB_PID=""
  fi
}

# Servers for the remote-store tests, on loopback only (called by test.sh,
# not by the demo): `ensure_remote_servers` starts a Range-capable HTTP
# server (scripts/test-servers/range_http.py, Python's standard library) and
# moto's S3 server, installing Python 3 and `moto[server]` when missing (as
# above: as root, with password-less sudo, or it stops with the exact
# command), and exports their addresses as BRICKRAY_TEST_HTTP and
# BRICKRAY_TEST_S3 (an address a caller already set is kept, and no server
# of that kind is started). In front of each it starts a fault-injecting
# proxy (scripts/test-servers/fault_proxy.py: latency, 503 and 429, resets,
# truncated and stalled bodies) as BRICKRAY_TEST_HTTP_FAULTY and
# BRICKRAY_TEST_S3_FAULTY, and one that only delays every request by 300 ms
# as BRICKRAY_TEST_HTTP_SLOW. `stop_remote_servers` stops what it started.
BRICKRAY_HTTP_PID=""
BRICKRAY_MOTO_PID=""
BRICKRAY_PROXY_PIDS=""
BRICKRAY_REMOTE_DIR=""

# Waits for a port file written by a server of PID; echoes the port.
wait_port_file() {
  local file=$1 pid=$2 i
  for i in $(seq 1 150); do
    if [ -s "$file" ]; then
      cat "$file"
      return 0
    fi
    kill -0 "$pid" 2>/dev/null || return 1
    sleep 0.1
  done
  return 1
}

free_port() {
  python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

ensure_remote_servers() {
  if ! command -v python3 >/dev/null 2>&1; then
    if ! apt_install python3 python3-pip; then
      echo "brickray: no Python 3 for the remote-store test servers. Install it with:" >&2
      echo "  sudo apt-get install -y python3 python3-pip" >&2
      exit 1
    fi
  fi
  BRICKRAY_REMOTE_DIR="$(mktemp -d "${TMPDIR:-/tmp}/brickray-remote.XXXXXX")"
  if [ -z "${BRICKRAY_TEST_HTTP:-}" ]; then
    mkdir -p "$BRICKRAY_REMOTE_DIR/http"
    python3 scripts/test-servers/range_http.py --root "$BRICKRAY_REMOTE_DIR/http" \
      --port-file "$BRICKRAY_REMOTE_DIR/http.port" >/dev/null 2>&1 &
    BRICKRAY_HTTP_PID=$!
    local port
    if ! port="$(wait_port_file "$BRICKRAY_REMOTE_DIR/http.port" "$BRICKRAY_HTTP_PID")"; then
      echo "brickray: the Range HTTP test server did not start" >&2
      exit 1
    fi
    export BRICKRAY_TEST_HTTP="http://127.0.0.1:$port"
    echo "brickray: Range HTTP test server on $BRICKRAY_TEST_HTTP" >&2
  fi
  if [ -z "${BRICKRAY_TEST_S3:-}" ]; then
    # moto's server: its script, or the module where pip put the script off PATH.
    have_moto() { python3 -c 'import moto.server, flask' >/dev/null 2>&1; }
    if ! have_moto; then
      echo "brickray: installing moto[server] (an S3 server for the tests) ..." >&2
      python3 -m pip install --quiet 'moto[server]' >&2 ||
        python3 -m pip install --quiet --break-system-packages 'moto[server]' >&2 || true
    fi
    if ! have_moto; then
      echo "brickray: no S3 test server (moto). Install it with:" >&2
      echo "  python3 -m pip install 'moto[server]'" >&2
      exit 1
    fi
    local s3port i
    s3port="$(free_port)"
    python3 -m moto.server -H 127.0.0.1 -p "$s3port" >"$BRICKRAY_REMOTE_DIR/moto.log" 2>&1 &
    BRICKRAY_MOTO_PID=$!
    for i in $(seq 1 300); do
      if python3 -c "import urllib.request,sys; urllib.request.urlopen('http://127.0.0.1:$s3port/moto-api/', timeout=1)" 2>/dev/null; then
        break
      fi
      if ! kill -0 "$BRICKRAY_MOTO_PID" 2>/dev/null || [ "$i" = 300 ]; then
        echo "brickray: moto_server did not start (log: $BRICKRAY_REMOTE_DIR/moto.log)" >&2
        exit 1
      fi
      sleep 0.1
    done
    export BRICKRAY_TEST_S3="http://127.0.0.1:$s3port"
    echo "brickray: S3 test server (moto) on $BRICKRAY_TEST_S3" >&2
  fi
  local name upstream pid pport
  for name in HTTP S3; do
    upstream="BRICKRAY_TEST_$name"
    if [ -n "$(eval echo "\${BRICKRAY_TEST_${name}_FAULTY:-}")" ]; then
      continue
    fi
    python3 scripts/test-servers/fault_proxy.py --upstream "${!upstream}" \
      --port-file "$BRICKRAY_REMOTE_DIR/proxy-$name.port" >/dev/null 2>&1 &
    pid=$!
    BRICKRAY_PROXY_PIDS="$BRICKRAY_PROXY_PIDS $pid"
    if ! pport="$(wait_port_file "$BRICKRAY_REMOTE_DIR/proxy-$name.port" "$pid")"; then
      echo "brickray: the fault-injecting proxy did not start" >&2
      exit 1
    fi
    export "BRICKRAY_TEST_${name}_FAULTY=http://127.0.0.1:$pport"
    echo "brickray: fault-injecting proxy to ${!upstream} on http://127.0.0.1:$pport" >&2
  done
  # A slow road to the HTTP server (every request held 300 ms): what the
  # cancellation tests abort.
  if [ -z "${BRICKRAY_TEST_HTTP_SLOW:-}" ]; then
    python3 scripts/test-servers/fault_proxy.py --upstream "$BRICKRAY_TEST_HTTP" \
      --cycle ok --delay 300 --port-file "$BRICKRAY_REMOTE_DIR/proxy-slow.port" >/dev/null 2>&1 &
    pid=$!
    BRICKRAY_PROXY_PIDS="$BRICKRAY_PROXY_PIDS $pid"
    if ! pport="$(wait_port_file "$BRICKRAY_REMOTE_DIR/proxy-slow.port" "$pid")"; then
      echo "brickray: the slow proxy did not start" >&2
      exit 1
    fi
    export "BRICKRAY_TEST_HTTP_SLOW=http://127.0.0.1:$pport"
    echo "brickray: slow proxy (300 ms) to $BRICKRAY_TEST_HTTP on http://127.0.0.1:$pport" >&2
  fi
}

stop_remote_servers() {
  local pid
  for pid in "$BRICKRAY_HTTP_PID" "$BRICKRAY_MOTO_PID" $BRICKRAY_PROXY_PIDS; do
    if [ -n "$pid" ]; then
      kill "$pid" 2>/dev/null || true
      wait "$pid" 2>/dev/null || true
    fi
  done
  BRICKRAY_HTTP_PID=""
  BRICKRAY_MOTO_PID=""
  BRICKRAY_PROXY_PIDS=""
  if [ -n "$BRICKRAY_REMOTE_DIR" ]; then
    rm -rf "$BRICKRAY_REMOTE_DIR"
    BRICKRAY_REMOTE_DIR=""
  fi
}

# VTK's Python package, for the benchmark suite that compares brickray with
# VTK's volume mappers (`brickray-bench vtk`, its smoke test among the
# ignored tests that test.sh runs in its second pass). Installed as moto is
# above, or it stops with the exact command.
ensure_vtk() {
  have_vtk() { python3 -c 'import vtk, numpy' >/dev/null 2>&1; }
  # One offscreen render: VTK's wheel loads the system's OpenGL (EGL or GLX).
  vtk_renders() {
    python3 -c 'import vtk; w = vtk.vtkRenderWindow(); w.SetOffScreenRendering(1); w.SetSize(8, 8); w.AddRenderer(vtk.vtkRenderer()); w.Render()' >/dev/null 2>&1
  }
  if ! have_vtk; then
    echo "brickray: installing VTK's Python package (the vtk benchmark's comparison) ..." >&2
    python3 -m pip install --quiet vtk numpy >&2 ||
      python3 -m pip install --quiet --break-system-packages vtk numpy >&2 || true
  fi
  if ! have_vtk; then
    echo "brickray: no VTK for Python. Install it with:" >&2
    echo "  python3 -m pip install vtk numpy" >&2
    exit 1
  fi
  if ! vtk_renders; then
    apt_install libegl1 libegl-mesa0 libgl1 libglx-mesa0 || true
  fi
  if ! vtk_renders; then
    echo "brickray: VTK cannot render offscreen (no OpenGL). Install Mesa's with:" >&2
    echo "  sudo apt-get install -y libegl1 libegl-mesa0 libgl1 libglx-mesa0" >&2
    exit 1
  fi
}
