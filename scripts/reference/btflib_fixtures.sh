#!/usr/bin/env bash
# Regenerate tests/fixtures/ubo2014/ with btflib (the UBO2014 format's
# reference MATLAB library) run in GNU Octave.
#
#   scripts/reference/btflib_fixtures.sh [BTFLIB_DIR]
#
# BTFLIB_DIR (or the BTFLIB_DIR environment variable) is a checkout of
# https://github.com/cgbonn/btflib; without one, the pinned commit below is
# cloned (from BTFLIB_URL, default GitHub) into a temporary directory.
# OUT_DIR (environment) overrides the output directory. Installs octave and
# liboctave-dev (for mkoctfile, which compiles btflib's halfprecision MEX)
# with apt-get when they are missing.
#
# Octave 7.3 may print "error: ignoring const execution_exception& while
# preparing to exit" after a successful run; the exit status is still 0.
#
# Fixtures in the repository were made with GNU Octave 7.3.0 (Debian 12) and
# btflib a9645d520417995603d7e16f38150f599d011e2e.
set -euo pipefail

BTFLIB_URL=${BTFLIB_URL:-https://github.com/cgbonn/btflib}
BTFLIB_COMMIT=a9645d520417995603d7e16f38150f599d011e2e

repo=$(cd "$(dirname "$0")/../.." && pwd)
out=${OUT_DIR:-$repo/tests/fixtures/ubo2014}
btflib=${1:-${BTFLIB_DIR:-}}

if ! command -v octave >/dev/null || ! command -v mkoctfile >/dev/null; then
    sudo=""
    [ "$(id -u)" -eq 0 ] || sudo=sudo
    $sudo apt-get update
    $sudo apt-get install -y --no-install-recommends octave liboctave-dev
fi

tmp=""
cleanup() { [ -z "$tmp" ] || rm -rf "$tmp"; }
trap cleanup EXIT
if [ -z "$btflib" ]; then
    tmp=$(mktemp -d)
    git clone --quiet "$BTFLIB_URL" "$tmp/btflib"
    git -C "$tmp/btflib" checkout --quiet "$BTFLIB_COMMIT"
    btflib=$tmp/btflib
fi
btflib=$(cd "$btflib" && pwd)
have=$(git -C "$btflib" rev-parse HEAD 2>/dev/null || echo unknown)
if [ "$have" != "$BTFLIB_COMMIT" ]; then
    echo "note: btflib at $have, fixtures were made with $BTFLIB_COMMIT" >&2
fi

echo "$(octave --version | head -n 1); btflib $have" >&2
mkdir -p "$out"
cd "$repo"
octave --no-gui --no-window-system --norc --quiet --eval \
    "addpath('$repo/scripts/reference'); btflib_fixtures('$btflib', '$out');"
