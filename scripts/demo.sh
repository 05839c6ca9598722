#!/usr/bin/env bash
# The main job: set up if needed, then `btfrs demo --out demo/` on the built-in material.
# `bash scripts/demo.sh [FOLDER] [--full]`: the quick run (every family in a few minutes) by
# default, `--full` for every example of every model and the full evaluation (README).
set -euo pipefail
cd "$(dirname "$0")/.."
# Mesa warns on every adapter query when XDG_RUNTIME_DIR is unset (headless machines, CI).
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
out=demo
if [ $# -gt 0 ] && [ "${1#--}" = "$1" ]; then out="$1"; shift; fi
bash scripts/setup.sh
exec .venv/bin/btfrs demo --out "$out" "$@"
