#!/usr/bin/env bash
# One-time set-up of a fresh machine: system libraries for headless rendering and the virtualenv.
set -euo pipefail
cd "$(dirname "$0")/.."

# MuJoCo renders headless through EGL (Mesa), and the design explorer's test drives a headless Chromium;
# install them when missing (needs root, Debian).
if ! ldconfig -p | grep -q libEGL.so.1 || ! ls /usr/lib/*/dri/swrast_dri.so >/dev/null 2>&1 \
    || ! command -v chromium >/dev/null || ! command -v chromedriver >/dev/null; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
        apt-get update -qq
        apt-get install -y -qq libegl1 libgl1-mesa-dri libgles2 chromium chromium-driver >/dev/null
    else
        echo "warning: libEGL/Mesa or chromium missing and not root: rendering and browser tests will be skipped" >&2
    fi
fi

python3 -m venv .venv
.venv/bin/pip install -q --upgrade pip
# The CPU build of torch lies on this machine's disk; a plain 'torch' would pull a CUDA build.
.venv/bin/pip install -q "torch==2.13.0"
.venv/bin/pip install -q -e ".[rl,dev,docs]"
touch .venv/.installed
