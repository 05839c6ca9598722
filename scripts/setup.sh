#!/usr/bin/env bash
# Set up everything btfrs needs on a fresh Debian machine, skipping what is already there:
# Debian packages, a virtual environment in .venv with the Python packages, and the release
# build of the Rust extension (maturin develop; cargo rebuilds only what changed).
set -euo pipefail
cd "$(dirname "$0")/.."

log() { printf '\033[1m[setup]\033[0m %s\n' "$*" >&2; }

# --- Debian packages -------------------------------------------------------------------------
# mesa-vulkan-drivers: lavapipe, the software Vulkan driver the wgpu renderer falls back to.
# pkg-config + a C compiler: for -sys crates. python3-venv: for the virtual environment.
missing=()
for p in mesa-vulkan-drivers pkg-config gcc; do
  dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  if command -v apt-get >/dev/null 2>&1; then
    SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
    log "installing Debian packages: ${missing[*]}"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  else
    log "warning: no apt-get; please install ${missing[*]} yourself"
  fi
fi

# --- Rust ------------------------------------------------------------------------------------
if ! command -v cargo >/dev/null 2>&1; then
  [ -x "$HOME/.cargo/bin/cargo" ] && export PATH="$HOME/.cargo/bin:$PATH"
fi
command -v cargo >/dev/null 2>&1 || { log "error: cargo (Rust >= 1.89) is required: https://rustup.rs"; exit 1; }

# --- Python ----------------------------------------------------------------------------------
PY="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
  log "creating .venv with $($PY --version 2>&1)"
  "$PY" -m venv .venv
fi

# The extension compiles in the background while the packages below download, unpack and
# install (pip's work is mostly on one core; cargo takes what is left): `maturin build` runs
# the very cargo build that `maturin develop` runs further down, which then finds everything
# compiled and only installs. The wheel it writes is thrown away; its output is kept for a failure, which the
# develop step reports again anyway.
if ! .venv/bin/python -c "import maturin" >/dev/null 2>&1; then
  log "installing maturin into .venv"
  .venv/bin/python -m pip install -q --disable-pip-version-check "maturin>=1.7,<2"
fi
# BTFRS_PROFILE (scripts/test.sh sets "ci", see Cargo.toml) picks another cargo profile.
profile=(--release)
[ -n "${BTFRS_PROFILE:-}" ] && profile=(--profile "$BTFRS_PROFILE")
prebuild_dir="$(mktemp -d)"
.venv/bin/maturin build "${profile[@]}" -i .venv/bin/python -o "$prebuild_dir/wheels" --quiet \
  >"$prebuild_dir/log" 2>&1 &
prebuild=$!
stamp=""
cleanup() {
  kill "$prebuild" 2>/dev/null || true
  rm -rf "$prebuild_dir" ${stamp:+"$stamp"}
}
trap cleanup EXIT
if ! .venv/bin/python -c "import maturin, numpy, pytest, xdist, scipy, sklearn, mypy, matplotlib" >/dev/null 2>&1; then
  log "installing Python packages into .venv"
  .venv/bin/python -m pip install -q --disable-pip-version-check "maturin>=1.7,<2" "numpy>=1.22" "pytest>=7" "pytest-xdist>=3" "scipy>=1.9" "scikit-learn>=1.3" "mypy>=1.10" "matplotlib>=3.5" "pillow>=9"
fi
# SSIM for the RTI benchmark script (scripts/rti_benchmark.py) and its test: btfrs[bench].
if ! .venv/bin/python -c "import skimage" >/dev/null 2>&1; then
  log "installing scikit-image into .venv"
  .venv/bin/python -m pip install -q --disable-pip-version-check "scikit-image>=0.21"
fi
# The btfrs[dask] extra (btfrs.dask and its LocalCluster tests).
if ! .venv/bin/python -c "import dask.array, distributed, zarr" >/dev/null 2>&1; then
  log "installing dask, distributed and zarr into .venv"
  .venv/bin/python -m pip install -q --disable-pip-version-check "dask[array]>=2024.1" "distributed>=2024.1" "zarr>=3"
fi

# The documentation site (mkdocs.yml, docs/): scripts/test.sh builds it with --strict; the API
# reference is read from the sources by griffe (mkdocstrings' Python handler), without importing.
if ! .venv/bin/python -c "import mkdocs, material, mkdocstrings, mkdocstrings_handlers.python" >/dev/null 2>&1; then
  log "installing mkdocs-material and mkdocstrings into .venv"
  .venv/bin/python -m pip install -q --disable-pip-version-check "mkdocs>=1.6,<2" "mkdocs-material>=9.5" "mkdocstrings[python]>=0.26"
fi

# Mitsuba 3 for the ground-truth tests (btfrs.tools.groundtruth path traces a heightfield). Pinned:
# Mitsuba 3.9 / Dr.Jit 1.5 emit llvm.minimum, which the LLVM 15 of Debian 12 (mesa's, also the
# one lavapipe uses) cannot compile for x86 ("Cannot select: fminimum"); 3.5.2 / 0.4.6 work.
# (The version from the package metadata: mitsuba refuses attribute access before set_variant.)
if ! .venv/bin/python -c "import importlib.metadata as m, drjit; assert m.version('mitsuba') == '3.5.2'" >/dev/null 2>&1; then
  log "installing Mitsuba 3 (ground-truth tests)"
  .venv/bin/python -m pip install -q --disable-pip-version-check "mitsuba==3.5.2" "drjit==0.4.6"
fi
# glTF's reader for the tests of the glTF export (pygltflib: MIT, pure Python).
if ! .venv/bin/python -c "import pygltflib" >/dev/null 2>&1; then
  log "installing pygltflib into .venv"
  .venv/bin/python -m pip install -q --disable-pip-version-check "pygltflib>=1.16"
fi

# The browser viewer's tests (tests/test_viewer.py): Debian's chromium, driven by Playwright's
# Python package, which must not download a browser of its own.
if ! dpkg -s chromium >/dev/null 2>&1 && command -v apt-get >/dev/null 2>&1; then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  log "installing chromium (browser tests)"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends chromium >/dev/null
fi
if ! .venv/bin/python -c "import playwright.sync_api" >/dev/null 2>&1; then
  log "installing playwright (its Python package only: the tests drive Debian's chromium)"
  PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD=1 .venv/bin/python -m pip install -q --disable-pip-version-check "playwright>=1.40"
fi

# --- Build -----------------------------------------------------------------------------------
log "building the extension (${BTFRS_PROFILE:-release})"
# A failed build must fail this script: an older extension left in place would otherwise pass
# for the new one and the tests would run a stale binary. maturin's progress lines are dropped
# (the `|| true` is grep's: it exits 1 when it passes no line through); with pipefail the
# pipeline's status is then maturin's.
if ! wait "$prebuild"; then
  log "the background build failed; the build below reports why"
fi
stamp="$(mktemp)"
if ! VIRTUAL_ENV="$PWD/.venv" .venv/bin/maturin develop "${profile[@]}" --quiet 2>&1 \
    | { grep -v "^📦\|^✏️\|^🛠\|^🔗\|^🐍" >&2 || true; }; then
  log "error: building the extension failed (see above)"
  exit 1
fi
# And the btfrs that Python imports must be the extension just installed (maturin rewrites it
# on every develop), not another copy found first on the path.
native="$(.venv/bin/python -c "import btfrs._native as n; print(n.__file__)")" \
  || { log "error: the build did not produce an importable btfrs"; exit 1; }
[ "$native" -nt "$stamp" ] \
  || { log "error: python imports $native, which this build did not write (a stale extension)"; exit 1; }
