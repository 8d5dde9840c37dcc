#!/usr/bin/env bash
# System libraries for offscreen rendering (torch4dtree.render: pyrender through EGL on Mesa's
# software renderer llvmpipe, no GPU or display needed). Debian 12 / Ubuntu; idempotent, quiet.
#
#   libegl1          libEGL.so.1, the GLVND EGL loader PyOpenGL opens (PYOPENGL_PLATFORM=egl)
#   libegl-mesa0     Mesa's EGL vendor library (EGL device/surfaceless platforms)
#   libgl1           libGL.so.1, where PyOpenGL's EGL platform looks up desktop GL functions
#                    (pyrender needs OpenGL 3.3 core; pulls libglx0 + libglx-mesa0)
#   libgl1-mesa-dri  the Mesa drivers themselves, including the swrast/llvmpipe software renderer
#   libxrender1      `import pyrender` imports pyglet's X11 window code, which loads libXrender
#                    (torch4dtree.render avoids it on displayless machines with PYGLET_HEADLESS)
#
# ffmpeg is not needed: imageio-ffmpeg ships a static ffmpeg with libx264. Fonts are not
# needed: Pillow (>= 10.1) embeds a scalable font.
# .ci/run also needs `python3 -m venv`, which Debian splits into python3-venv: added when missing.
set -euo pipefail

packages=(libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri libxrender1)

if ! command -v dpkg-query >/dev/null 2>&1; then
    echo "system-packages.sh: not a Debian/Ubuntu system; install EGL + Mesa (e.g. mesa-libEGL mesa-dri-drivers) yourself" >&2
    exit 0
fi

missing=()
for p in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "ok installed" || missing+=("$p")
done
if command -v python3 >/dev/null 2>&1 && ! python3 -c "import ensurepip, venv" >/dev/null 2>&1; then
    missing+=("python3-venv")
fi

if [ ${#missing[@]} -eq 0 ]; then
    echo "system-packages.sh: already installed: ${packages[*]}"
    exit 0
fi

sudo=()
if [ "$(id -u)" -ne 0 ]; then
    sudo=(sudo)
fi
echo "system-packages.sh: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
"${sudo[@]}" apt-get update -qq
"${sudo[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
