#!/usr/bin/env bash
# System libraries the Python packages need on a fresh Debian machine.
#   libusb-1.0-0            open3d imports it at load time
#   libegl1 libegl-mesa0 libgl1-mesa-dri libgl1   headless OpenGL (Mesa llvmpipe) for the GLSL test
#   glslang-tools           static check of the GLSL snippet
#   chromium                headless browser tests (segmentation editor, three.js GLB view)
#   nodejs npm              the Khronos glTF validator (npm gltf-validator) for the glTF tests
# Installs them with apt-get when we are root and they are missing; otherwise prints the command.
set -eu
need=()
have_lib() { ldconfig -p 2>/dev/null | grep -q "$1"; }
have_lib libusb-1.0.so.0 || need+=(libusb-1.0-0)
have_lib libEGL.so.1 || need+=(libegl1)
have_lib libGL.so.1 || need+=(libgl1)
[ -e /usr/share/glvnd/egl_vendor.d/50_mesa.json ] || need+=(libegl-mesa0 libgl1-mesa-dri)
command -v glslangValidator >/dev/null 2>&1 || need+=(glslang-tools)
command -v node >/dev/null 2>&1 || need+=(nodejs)
command -v npm >/dev/null 2>&1 || need+=(npm)
if [ "${LEAFFIT_SKIP_BROWSER:-0}" != 1 ]; then
  command -v chromium >/dev/null 2>&1 || need+=(chromium)
fi
[ ${#need[@]} -eq 0 ] && exit 0
if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
  echo "setup: apt-get install ${need[*]}" >&2
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq >/dev/null
  apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
else
  echo "setup: missing system packages; run: sudo apt-get install -y --no-install-recommends ${need[*]}" >&2
  [ "${need[*]}" = "chromium" ] || [ "${need[*]}" = "glslang-tools" ] || exit 1
fi
