#!/usr/bin/env bash
# One install for a fresh machine of this kind: the system library open3d needs, the CPU
# torch wheel (any other torch pin pulls gigabytes of CUDA packages), then the project.
set -euo pipefail
cd "$(dirname "$0")/.."
if ! ldconfig -p 2>/dev/null | grep -q libusb-1.0; then
    SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
    $SUDO apt-get update -qq && $SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null
fi
python3 -m pip install -q torch==2.13.0
python3 -m pip install -q -e ".[dev]"
