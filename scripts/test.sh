#!/usr/bin/env bash
# Every test of btfrs: the Rust workspace (cargo test, without the PyO3 crate, so no Python is
# linked), the stub check of the native module, and the Python suite (pytest).
set -euo pipefail
cd "$(dirname "$0")/.."
# Mesa warns on every adapter query when XDG_RUNTIME_DIR is unset (headless machines, CI).
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
# One optimised build for the extension and the Rust tests (Cargo.toml, [profile.ci]).
export BTFRS_PROFILE="${BTFRS_PROFILE:-ci}"
bash scripts/setup.sh
[ -x "$HOME/.cargo/bin/cargo" ] && export PATH="$HOME/.cargo/bin:$PATH"

echo "== cargo fmt --check, cargo clippy -D warnings =="
if cargo fmt --version >/dev/null 2>&1; then cargo fmt --all --check; else echo "rustfmt not installed: format check skipped"; fi
if cargo clippy --version >/dev/null 2>&1; then
  cargo clippy --quiet --workspace --all-targets -- -D warnings
else
  echo "clippy not installed: lint skipped"
fi

echo "== cargo test (workspace) =="
cargo test --quiet --profile "$BTFRS_PROFILE"

echo "== stubtest btfrs._native =="
.venv/bin/python -m mypy.stubtest btfrs._native

echo "== pytest =="
# Two workers (pytest-xdist), each test file on one of them, so a module's shared fixture is
# computed once: the Rust side is parallel already, but much of the suite is Python and numpy.
.venv/bin/python -m pytest -q -n "${BTFRS_TEST_WORKERS:-2}" --dist loadfile "$@"
