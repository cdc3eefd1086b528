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
