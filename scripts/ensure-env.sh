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
