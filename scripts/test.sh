#!/usr/bin/env bash
# Every test of btfrs: the Rust workspace (cargo test, without the PyO3 crate, so no Python is
# linked), the stub check of the native module, the package's types (mypy --strict), the
# documentation build (mkdocs --strict) and the Python suite (pytest, which also runs every
# python block of README.md and docs/).
set -euo pipefail
cd "$(dirname "$0")/.."
# Mesa warns on every adapter query when XDG_RUNTIME_DIR is unset (headless machines, CI).
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
# One optimised build for the extension and the Rust tests (Cargo.toml, [profile.ci]).
export BTFRS_PROFILE="${BTFRS_PROFILE:-ci}"
[ -x "$HOME/.cargo/bin/cargo" ] && export PATH="$HOME/.cargo/bin:$PATH"
stage() { printf '== %s (at %dm%02ds) ==\n' "$1" $((SECONDS / 60)) $((SECONDS % 60)); }

# Lint while building: clippy-driver stands in for rustc on the workspace's own crates, as
# `cargo clippy` does, but in the real (optimised) build instead of a separate check-only one,
# so the dependencies (wgpu, naga, image, ...) are compiled once for the extension, the Rust
# tests and the lints; a check build of its own cost ~9 of a 2-core CI run's minutes.
# CLIPPY_ARGS is cargo-clippy's way of handing `-- -D warnings` to the driver (its separator
# is the literal __CLIPPY_HACKERY__). The lints cover everything `cargo clippy --workspace
# --all-targets` does: the extension (maturin), libs, tests and examples (cargo test), benches
# (cargo build --benches).
if command -v clippy-driver >/dev/null 2>&1 && clippy-driver --version >/dev/null 2>&1; then
  export RUSTC_WORKSPACE_WRAPPER="$(command -v clippy-driver)"
  export CLIPPY_ARGS="-D__CLIPPY_HACKERY__warnings__CLIPPY_HACKERY__"
  lint="clippy -D warnings in the build"
else
  lint="clippy not installed: lint skipped"
fi

stage "setup and the extension's build ($lint)"
bash scripts/setup.sh

stage "cargo fmt --check"
if cargo fmt --version >/dev/null 2>&1; then cargo fmt --all --check; else echo "rustfmt not installed: format check skipped"; fi

stage "cargo test (workspace; $lint)"
# --workspace selects the PyO3 crate too (it has no test target: nothing of it is built) so that
# the dependencies' features resolve as in the extension's build and its compiled dependencies
# are reused instead of built a second time (rust/btfrs-py/Cargo.toml).
cargo test --quiet --profile "$BTFRS_PROFILE" --workspace
stage "cargo build --benches ($lint), and beside it: stubtest, mkdocs --strict, mypy --strict"
# The three Python checks run on one core each, one after the other, while cargo compiles the
# benches; their output is shown after both finish, in order.
checks_log="$(mktemp)"
trap 'rm -f "$checks_log"' EXIT
python_checks() {
  echo "-- stubtest btfrs._native"
  .venv/bin/python -m mypy.stubtest btfrs._native
  # The documentation site. Not -q: mkdocs 1.6 counts only the warnings it logs, and -q logs
  # none, so --strict -q passes with warnings. The INFO lines are dropped instead (grep's
  # `|| true`: it exits 1 when it passes no line; with pipefail the pipeline's status is then
  # mkdocs's).
  echo "-- mkdocs build --strict (the documentation site)"
  local docs_site
  docs_site="$(mktemp -d)"
  NO_MKDOCS_2_WARNING=1 .venv/bin/mkdocs build --strict -d "$docs_site" 2>&1 | { grep -v "^INFO" || true; }
  rm -rf "$docs_site"
  # The package's types ([tool.mypy] in pyproject.toml: strict, with the overrides listed there).
  echo "-- mypy --strict"
  .venv/bin/python -m mypy
}
( set -euo pipefail; python_checks ) >"$checks_log" 2>&1 &
checks=$!
benches=0
cargo build --quiet --profile "$BTFRS_PROFILE" --workspace --benches || benches=$?
checks_status=0
wait "$checks" || checks_status=$?
cat "$checks_log"
[ "$benches" -eq 0 ] || { echo "cargo build --benches failed"; exit "$benches"; }
[ "$checks_status" -eq 0 ] || { echo "a Python check failed (above)"; exit "$checks_status"; }

stage "pytest"
# Two workers (pytest-xdist), each test file on one of them, so a module's shared fixture is
# computed once: the Rust side is parallel already, but much of the suite is Python and numpy.
# The files are handed out in collection order, which tests/conftest.py starts with the longest
# (xdist's default order, by test count, left a long file of few tests for the end).
# --durations: the slowest tests and fixtures are in every log, for whoever keeps CI short.
.venv/bin/python -m pytest -q -n "${BTFRS_TEST_WORKERS:-2}" --dist loadfile --no-loadscope-reorder --durations=15 "$@"
stage "done"
