#!/usr/bin/env bash
# Install everything silfit needs on a Debian machine (run as root, or with sudo available):
#   - system packages: libllvm19 (Dr.Jit's CPU backend; Mesa's libLLVM 15 crashes it),
#     libosmesa6 (offscreen OpenGL for pyrender) and chromium (the tests open `silfit report`'s
#     HTML gallery in headless Chromium),
#   - a virtual environment in .venv with torch 2.13.0 (CPU wheel) and silfit installed editable
#     with its test and docs extras, every package at the version constraints.txt names.
# Idempotent: a second run checks and returns in a second or two.
set -euo pipefail
cd "$(dirname "$0")/.."

missing=()
for pkg in libllvm19 libosmesa6 chromium; do
  dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done
if ((${#missing[@]})); then
  sudo=""
  [ "$(id -u)" -eq 0 ] || sudo="sudo"
  echo "setup: installing Debian packages: ${missing[*]}"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

[ -x .venv/bin/python ] || "${PYTHON:-python3}" -m venv .venv
stamp=.venv/.silfit-setup
want=$(sha256sum pyproject.toml constraints.txt tools/setup.sh | sha256sum | cut -d' ' -f1)
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "setup: installing Python packages into .venv"
  # torch first and pinned: it comes from the local CPU wheel; a looser request pulls CUDA builds.
  .venv/bin/python -m pip install -q --disable-pip-version-check "torch==2.13.0"
  .venv/bin/python -m pip install -q --disable-pip-version-check -c constraints.txt -e ".[test,docs]"
  echo "$want" > "$stamp"
fi
