#!/usr/bin/env bash
# The main job: set up if needed, then `btfrs demo --out demo/` on the built-in material.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/btfrs demo --out "${1:-demo}"
