#!/usr/bin/env bash
# Installs splitrender with its test dependencies and runs every test: the Rust tests, the Python
# tests, and the checks of the typed surface (the `_native` stub against the built module, and
# mypy --strict on the package). Used by .ci/run after the fmt and clippy gates; run it locally
# the same way: `bash scripts/test.sh`.
set -euo pipefail
cd "$(dirname "$0")/.."

export PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_ROOT_USER_ACTION=ignore
# Builds the extension in release mode (maturin) and installs pytest, hypothesis and mypy, and
# Ray for the sweep test on a local 2-CPU Ray (tests/test_sweep.py).
python -m pip install --quiet ".[test,ray]"

# The GPU tests (crates/reproj-wgpu, tests/test_wgpu.py) need a wgpu adapter and skip with a
# message without one. Mesa's software Vulkan driver (lavapipe) gives one on any machine: install
# it when missing and we are root on Debian/Ubuntu (.ci/run also sets REPROJ_WGPU_REQUIRE_ADAPTER=1
# so that there they cannot skip).
if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ] \
    && ! dpkg-query -W -f='${Status}' mesa-vulkan-drivers 2>/dev/null | grep -q "ok installed"; then
    apt-get update -q
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends mesa-vulkan-drivers
fi

# Without a desktop session, Mesa's Vulkan device-selection layer has libwayland print "error:
# XDG_RUNTIME_DIR is invalid or not set" in every test process that makes a wgpu instance: off
# by its own switch, under the rule splitrender.gpu follows for itself (a session, or the
# user's own NODEVICE_SELECT or MESA_VK_DEVICE_SELECT, leaves it). Only for these: the Python
# tests check that the package does it by itself.
(
    if [ -z "${NODEVICE_SELECT+set}${MESA_VK_DEVICE_SELECT+set}${DISPLAY:-}${WAYLAND_DISPLAY:-}" ] \
        && { [ -z "${XDG_RUNTIME_DIR:-}" ] || [ ! -d "$XDG_RUNTIME_DIR" ]; }; then
        export NODEVICE_SELECT=1
    fi
    cargo test --workspace
)

# From the repository root `import splitrender` resolves to the installed package (the sources
# live under python/), so the tests exercise what was just built.
python -m pytest -q

# The stub must match the module: names, signatures, defaults.
python -m mypy.stubtest splitrender._native
python -m mypy
