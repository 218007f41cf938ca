#!/usr/bin/env bash
# Print the path of a working CPython X.Y (argument, e.g. 3.13): `pythonX.Y` on
# PATH first (only if it runs: pyenv shims exist for versions not selected),
# then pyenv's versions (`pyenv root`), then ~/.pyenv/versions.
# Exits 1 with one line on stderr saying what to install when there is none.
set -uo pipefail
ver="$1"
works() { [ -n "$1" ] && "$1" -c "import sys, venv; sys.exit(sys.version_info[:2] != tuple(map(int, '$ver'.split('.'))))" >/dev/null 2>&1; }
cand="$(command -v "python$ver" 2>/dev/null || true)"
real() { "$1" -c "import sys; print(sys.executable)"; }
if works "$cand"; then real "$cand"; exit 0; fi
roots=()
if command -v pyenv >/dev/null 2>&1; then roots+=("$(pyenv root 2>/dev/null)"); fi
roots+=("$HOME/.pyenv")
for root in "${roots[@]}"; do
  for cand in $(ls -d "$root"/versions/"$ver"*/bin/python"$ver" 2>/dev/null | sort -rV); do
    if works "$cand"; then real "$cand"; exit 0; fi
  done
done
echo "need CPython $ver with venv (python$ver on PATH, or pyenv install $ver; Debian/Ubuntu: apt install python$ver python$ver-venv)" >&2
exit 1
