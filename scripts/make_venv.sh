#!/usr/bin/env bash
# make_venv.sh VENV PYTHON_VERSION BLENDER_EXTRA
# Set up one development venv: Penumbra installed editable with the bpy
# module of one Blender line (pyproject extra) and the dev tools, then the
# stamp VENV/.installed. A venv on another Python is made again.
set -euo pipefail
venv="$1"; ver="$2"; extra="$3"
cd "$(dirname "$0")/.."
start=$(date +%s)
py="$(bash scripts/find_python.sh "$ver")" || exit 2
if [ -x "$venv/bin/python" ] && ! "$venv/bin/python" -c "import sys; sys.exit(sys.version_info[:2] != tuple(map(int, '$ver'.split('.'))))"; then
  echo "$venv is not on Python $ver: making it again"
  rm -rf "$venv"
fi
[ -x "$venv/bin/python" ] || "$py" -m venv "$venv"
"$venv/bin/python" -m pip install -q --disable-pip-version-check --upgrade pip
"$venv/bin/python" -m pip install -q --disable-pip-version-check -e ".[$extra,dev,farm,farm-dev]"
"$venv/bin/python" -c "import bpy, numpy; print('$venv: Blender', bpy.app.version_string, '| Python', '.'.join(map(str, __import__('sys').version_info[:3])), '| numpy', numpy.__version__)"
echo "$venv set up in $(( $(date +%s) - start )) s"
touch "$venv/.installed"
