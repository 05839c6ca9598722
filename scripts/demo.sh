#!/usr/bin/env bash
# The main job: set up if needed, then `btfrs demo --out demo/` on the built-in material.
set -euo pipefail
cd "$(dirname "$0")/.."
# Mesa warns on every adapter query when XDG_RUNTIME_DIR is unset (headless machines, CI).
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
bash scripts/setup.sh
exec .venv/bin/btfrs demo --out "${1:-demo}"
