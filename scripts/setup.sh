#!/usr/bin/env bash
# Set up svbrdf on a fresh Debian bookworm machine with a Rust toolchain:
# install the system packages that are missing (idempotent: installed ones are
# skipped), then build the release binary. `--deps-only` stops after the packages.
set -euo pipefail
cd "$(dirname "$0")/.."

packages=(libopencv-dev clang libclang-dev pkg-config ffmpeg libavcodec-dev libavformat-dev libavutil-dev libswscale-dev)
missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing ${missing[*]}" >&2
  sudo=""
  if [ "$(id -u)" -ne 0 ]; then sudo="sudo"; fi
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${missing[@]}" >/dev/null
else
  echo "setup: system packages already installed" >&2
fi

if [ "${1:-}" = "--deps-only" ]; then
  exit 0
fi

cargo build --release --locked
echo "setup: built target/release/svbrdf" >&2
