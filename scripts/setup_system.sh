#!/usr/bin/env bash
# Debian libraries the PyPI bpy module loads even in background mode
# (BLENDER_NOTES.md). Installs only what is missing; needs root or sudo.
set -euo pipefail
# node runs the Flamenco job type farm/flamenco/penumbra_render.js in tests/test_farm_flamenco.py
if ! command -v node >/dev/null 2>&1; then
  echo "installing nodejs (the Flamenco job type's tests)"
  NSUDO=""; [ "$(id -u)" -ne 0 ] && NSUDO="sudo"
  $NSUDO apt-get update -qq && $NSUDO apt-get install -y -qq nodejs >/dev/null
fi
need=()
for lib in libGL.so.1 libX11.so.6 libXi.so.6 libXrender.so.1 libXfixes.so.3 \
           libxkbcommon.so.0 libSM.so.6 libICE.so.6 libXxf86vm.so.1; do
  ldconfig -p 2>/dev/null | grep -q "$lib" || need+=("$lib")
done
[ ${#need[@]} -eq 0 ] && exit 0
echo "installing X/GL client libraries bpy needs: ${need[*]}"
SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq libgl1 libx11-6 libxi6 libxrender1 libxfixes3 \
      libxkbcommon0 libsm6 libice6 libxxf86vm1 >/dev/null
