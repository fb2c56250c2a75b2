#!/usr/bin/env bash
# Set up geofit on a fresh Debian machine with Python 3.11: system libraries, a venv in .venv,
# and the package with its test and docs extras. Safe to run again (it only installs what is missing).
set -euo pipefail
cd "$(dirname "$0")/.."

# System libraries: Open3D needs libusb-1.0 to import at all; its headless OffscreenRenderer
# needs Vulkan (software, llvmpipe); the report test uses Debian's Chromium when present.
pkgs=(libusb-1.0-0 libgomp1 libgl1 libegl1 libvulkan1 mesa-vulkan-drivers)
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ "${#missing[@]}" -gt 0 ]; then
  SUDO=""
  [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null && SUDO="sudo"
  echo "setup: installing system packages: ${missing[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

PY=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip 2>&1 | grep -v "^WARNING: Location" || true
.venv/bin/python -m pip install -q -e ".[test,docs]" 2>&1 | grep -v "^WARNING: Location" || true
.venv/bin/python -c "import geofit, open3d, embreex, nlopt; print('setup: geofit', geofit.__version__, 'ready in .venv')"
