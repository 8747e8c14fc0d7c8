#!/usr/bin/env bash
# Create or reuse the project virtualenv and install gprbot with its dev extras.
# Installs apt's libusb-1.0-0 (needed by pyrealsense2) and chromium + chromium-driver (the web console's
# browser tests) when running as root and they are missing.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
PYTHON=${PYTHON:-python3}

if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
        echo "bootstrap: installing libusb-1.0-0 (needed by pyrealsense2)"
        apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 >/dev/null
    else
        echo "bootstrap: warning: libusb-1.0-0 is missing; install it (apt-get install libusb-1.0-0) for the RealSense driver" >&2
    fi
fi

# The web console's browser tests drive Debian's headless Chromium; without it they are skipped (and say so).
if ! command -v chromedriver >/dev/null || ! { command -v chromium >/dev/null || command -v chromium-browser >/dev/null; }; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
        echo "bootstrap: installing chromium and chromium-driver (the web console's browser tests)"
        apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver >/dev/null
    else
        echo "bootstrap: note: chromium + chromium-driver are missing; the web console's browser tests will be skipped" >&2
    fi
fi

stamp="$VENV/.installed-$(sha256sum pyproject.toml | cut -c1-16)"
if [ ! -f "$stamp" ]; then
    [ -x "$VENV/bin/python" ] || "$PYTHON" -m venv "$VENV"
    "$VENV/bin/python" -m pip install -q --upgrade pip
    "$VENV/bin/python" -m pip install -q -e ".[dev,robot${EXTRAS:+,$EXTRAS}]"
    rm -f "$VENV"/.installed-*
    touch "$stamp"
fi
