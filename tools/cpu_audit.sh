#!/usr/bin/env bash
# The CPU audit (issue 22): the fitting and evaluation tests under several kernel and thread settings,
# every test whose outcome changes reported. Options and settings: tools/cpu_audit.py --help.
#   bash tools/cpu_audit.sh [--jobs N] [--settings a,b] [tests ...] [-- pytest options]
set -euo pipefail
cd "$(dirname "$0")/.."
[ -x .venv/bin/python ] || bash tools/setup.sh
exec .venv/bin/python tools/cpu_audit.py "$@"
