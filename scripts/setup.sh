#!/usr/bin/env bash
# Set up pghm on a fresh Debian machine: the system OpenGL libraries the GL paths need and
# Chromium, which the web page's test opens (only when missing), a .venv with pghm, its test
# tools and the capture extra (mediapipe), and the native splat kernel.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-$(command -v python3.11 || command -v python3)}

missing_system_packages() {
    local missing=()
    ldconfig -p | grep -q 'libEGL.so.1 ' || missing+=(libegl1)
    ldconfig -p | grep -q 'libEGL_mesa.so.0 ' || missing+=(libegl-mesa0)
    ls /usr/lib/*/dri/swrast_dri.so >/dev/null 2>&1 || missing+=(libgl1-mesa-dri)
    command -v Xvfb >/dev/null || missing+=(xvfb)
    command -v chromium >/dev/null || missing+=(chromium)  # the web page's browser test
    echo "${missing[@]}"
}

packages=$(missing_system_packages)
if [ -n "$packages" ]; then
    if command -v apt-get >/dev/null; then
        echo "setup: installing system packages: $packages"
        sudo_cmd=""
        [ "$(id -u)" -eq 0 ] || sudo_cmd="sudo"
        $sudo_cmd apt-get update -qq
        # shellcheck disable=SC2086
        DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq $packages >/dev/null
    else
        echo "setup: warning: missing $packages and no apt-get; GL rendering and the viewer will not work" >&2
    fi
fi

if [ ! -x .venv/bin/python ]; then
    "$PYTHON" -m venv .venv
fi
stamp=.venv/.pghm-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
    echo "setup: installing pghm and its dependencies into .venv"
    if ! .venv/bin/python -m pip install -q --disable-pip-version-check -e ".[test,capture]" >.venv/pip.log 2>&1; then
        cat .venv/pip.log >&2
        exit 1
    fi
    touch "$stamp"
fi
.venv/bin/python -m pghm.splat.native || echo "setup: warning: the native splat kernel did not build; renders fall back to the slow torch path" >&2
