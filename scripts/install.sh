#!/usr/bin/env bash
# One install for a fresh machine of this kind: the system libraries (libusb for open3d;
# Mesa's software Vulkan driver so the Rerun viewer can render headless in the viewer test),
# the CPU torch wheel (any other torch pin pulls gigabytes of CUDA packages), then the project,
# every package of its dependency closure at the version of requirements.lock (the outputs'
# digests depend on them; scripts/lock.py writes it).
set -euo pipefail
cd "$(dirname "$0")/.."
APT=()
ldconfig -p 2>/dev/null | grep -q libusb-1.0 || APT+=(libusb-1.0-0)
ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1 || APT+=(mesa-vulkan-drivers)
if [ ${#APT[@]} -gt 0 ]; then
    SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
    $SUDO apt-get update -qq && $SUDO apt-get install -y -qq "${APT[@]}" >/dev/null
fi
python3 -m pip install -q -c requirements.lock torch==2.13.0
python3 -m pip install -q -c requirements.lock -e ".[dev]"
