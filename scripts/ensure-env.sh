#!/usr/bin/env bash
# Sourced by demo.sh and test.sh: makes sure a Rust toolchain and a Vulkan driver
# (a real GPU's, or Mesa's software lavapipe) are present. Installs the software
# driver when run as root (or with password-less sudo); otherwise stops and prints
# the exact command to run.
set -euo pipefail

if ! command -v cargo >/dev/null 2>&1; then
  echo "brickray: no Rust toolchain (cargo) found. Install it with:" >&2
  echo "  curl --proto '=https' --tlsv1.2 -sSf https://sh.rustup.rs | sh -s -- -y && . \"\$HOME/.cargo/env\"" >&2
  exit 1
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
  pkgs="mesa-vulkan-drivers libvulkan1"
  if [ "$(id -u)" = 0 ]; then
    echo "brickray: installing the software Vulkan driver ($pkgs)..." >&2
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $pkgs >/dev/null
  elif command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
    echo "brickray: installing the software Vulkan driver ($pkgs) with sudo..." >&2
    sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $pkgs >/dev/null
  else
    echo "brickray: no Vulkan driver found. Install Mesa's software driver with:" >&2
    echo "  sudo apt-get install -y $pkgs" >&2
    exit 1
  fi
fi

# Mesa's loader warns when XDG_RUNTIME_DIR is unset; give it a private one.
if [ -z "${XDG_RUNTIME_DIR:-}" ]; then
  export XDG_RUNTIME_DIR="${TMPDIR:-/tmp}/brickray-xdg-$(id -u)"
  mkdir -p "$XDG_RUNTIME_DIR" && chmod 700 "$XDG_RUNTIME_DIR"
fi
