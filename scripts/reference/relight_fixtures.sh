#!/usr/bin/env bash
# Regenerate tests/fixtures/relight: relight-cli's own web-format, .ptm and .rti
# outputs and relit images for a small synthetic capture, so the tests can check
# btfrs's readers and writers against relight without building relight.
#
# Reference versions the committed fixtures were made with:
#   relight   https://github.com/cnr-isti-vclab/relight
#             commit 5cca5c3e55519ec87ca179eb1487ce06ec3f962a (RELIGHT_VERSION 2026.03)
#   Debian 12 (bookworm), amd64
#   Qt        6.4.2 (qt6-base-dev 6.4.2+dfsg-10)
#   gcc/g++   12.2.0 (Debian 12.2.0-14+deb12u1)
#   cmake     3.25.1
#   libjpeg-turbo 2.1.5, lcms2 2.14, exiv2 0.27.6, libtiff 4.5.0, libpng 1.6.39, Eigen 3.4.0
#   capture maker: numpy 2.4.6, Pillow 13.0.0
# The versions of the run that last wrote the fixtures are in
# tests/fixtures/relight/versions.txt.
#
# relight is GPL software: this script only builds and runs it; nothing of its
# source is copied into this repository.  The files it writes are data.
#
# Usage:
#   scripts/reference/relight_fixtures.sh [options]
#     --relight-src DIR    relight checkout to build (default: clone the pinned
#                          commit into $CACHE_DIR/relight)
#     --build-dir DIR      CMake build folder (default: $CACHE_DIR/relight-build)
#     --relight-cli PATH   use this relight-cli binary, skip the build
#     --python PATH        Python with numpy and Pillow (default: $PYTHON or python3)
#     --out DIR            fixture folder (default: tests/fixtures/relight)
#     --no-apt             do not install missing Debian packages
#     --exports-only DIR   only run the btfrs-export section on DIR (see below)
#     --selftest-exports   run the btfrs-export section on relight's own .ptm/.rti
#                          and web outputs, into a temporary folder, and check it
#   CACHE_DIR defaults to ${XDG_CACHE_HOME:-$HOME/.cache}/btfrs-reference.
#
# Build (what the script runs):
#   apt-get install cmake make g++ pkg-config git qt6-base-dev qt6-svg-dev libexiv2-dev \
#       liblcms2-dev libtiff-dev libpng-dev libjpeg-dev libeigen3-dev
#   cmake -S <relight> -B <build> -DCMAKE_BUILD_TYPE=Release
#   cmake --build <build> --target relight-cli -j<ncpu>
# (qt6-svg-dev is only needed because the top-level CMakeLists also configures the
# relightlab GUI; only the relight-cli target is compiled.)
#
# Reruns are reproducible: every file comes out byte-identical except the web
# plane JPEGs of the fits, whose embedded ICC profile carries its creation time
# (their pixels are identical).

set -euo pipefail

RELIGHT_URL=https://github.com/cnr-isti-vclab/relight
RELIGHT_COMMIT=5cca5c3e55519ec87ca179eb1487ce06ec3f962a
APT_PACKAGES=(cmake make g++ pkg-config git qt6-base-dev qt6-svg-dev libexiv2-dev liblcms2-dev
	libtiff-dev libpng-dev libjpeg-dev libeigen3-dev)

# The four relighting directions, as given to relight-cli -L (it normalises them).
LIGHT_NAMES=(top right_up left_up down)
LIGHT_ARGS=("0:0:1" "0.5:0.3:0.81" "-0.6:0.2:0.77" "0.1:-0.7:0.71")

REPO_ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
CACHE_DIR=${CACHE_DIR:-${XDG_CACHE_HOME:-$HOME/.cache}/btfrs-reference}
RELIGHT_SRC=""
BUILD_DIR=""
RELIGHT_CLI=""
PYTHON=${PYTHON:-python3}
OUT="$REPO_ROOT/tests/fixtures/relight"
USE_APT=1
EXPORTS_ONLY=""
SELFTEST=0

while [[ $# -gt 0 ]]; do
	case "$1" in
	--relight-src) RELIGHT_SRC=$2; shift 2 ;;
	--build-dir) BUILD_DIR=$2; shift 2 ;;
	--relight-cli) RELIGHT_CLI=$2; shift 2 ;;
	--python) PYTHON=$2; shift 2 ;;
	--out) OUT=$2; shift 2 ;;
	--no-apt) USE_APT=0; shift ;;
	--exports-only) EXPORTS_ONLY=$2; shift 2 ;;
	--selftest-exports) SELFTEST=1; shift ;;
	-h | --help) sed -n '2,45p' "$0"; exit 0 ;;
	*) echo "unknown option: $1" >&2; exit 2 ;;
	esac
done

log() { printf '== %s\n' "$*" >&2; }
die() { printf 'error: %s\n' "$*" >&2; exit 1; }

# ---------------------------------------------------------------- dependencies
install_packages() {
	local missing=()
	for p in "${APT_PACKAGES[@]}"; do
		dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
	done
	[[ ${#missing[@]} -eq 0 ]] && return 0
	[[ $USE_APT -eq 1 ]] || die "missing Debian packages: ${missing[*]}"
	local sudo=""
	[[ $(id -u) -eq 0 ]] || sudo=sudo
	log "installing ${missing[*]}"
	$sudo apt-get update -qq
	DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
}

# ---------------------------------------------------------------- relight-cli
get_source() {
	if [[ -z $RELIGHT_SRC ]]; then
		RELIGHT_SRC="$CACHE_DIR/relight"
		if [[ ! -d $RELIGHT_SRC/.git ]]; then
			log "cloning relight into $RELIGHT_SRC"
			mkdir -p "$CACHE_DIR"
			GIT_LFS_SKIP_SMUDGE=1 git clone --quiet "$RELIGHT_URL" "$RELIGHT_SRC"
		fi
		if [[ $(git -C "$RELIGHT_SRC" rev-parse HEAD) != "$RELIGHT_COMMIT" ]]; then
			git -C "$RELIGHT_SRC" fetch --quiet origin "$RELIGHT_COMMIT" 2>/dev/null || git -C "$RELIGHT_SRC" fetch --quiet origin
			GIT_LFS_SKIP_SMUDGE=1 git -C "$RELIGHT_SRC" checkout --quiet "$RELIGHT_COMMIT"
		fi
	fi
	[[ -f $RELIGHT_SRC/relight-cli/main.cpp ]] || die "$RELIGHT_SRC is not a relight checkout"
	if git -C "$RELIGHT_SRC" rev-parse HEAD >/dev/null 2>&1; then
		local head
		head=$(git -C "$RELIGHT_SRC" rev-parse HEAD)
		[[ $head == "$RELIGHT_COMMIT" ]] || log "warning: $RELIGHT_SRC is at $head, the fixtures were made at $RELIGHT_COMMIT"
	fi
}

build_relight() {
	if [[ -n $RELIGHT_CLI ]]; then
		[[ -x $RELIGHT_CLI ]] || die "$RELIGHT_CLI is not executable"
		# find the sources it was built from, for versions.txt
		local cache
		cache="$(dirname "$(realpath "$RELIGHT_CLI")")/../CMakeCache.txt"
		if [[ -z $RELIGHT_SRC && -f $cache ]]; then
			RELIGHT_SRC=$(sed -n 's/^CMAKE_HOME_DIRECTORY:INTERNAL=//p' "$cache")
		fi
		return 0
	fi
	get_source
	BUILD_DIR=${BUILD_DIR:-$CACHE_DIR/relight-build}
	mkdir -p "$BUILD_DIR"
	log "building relight-cli in $BUILD_DIR"
	cmake -S "$RELIGHT_SRC" -B "$BUILD_DIR" -DCMAKE_BUILD_TYPE=Release >"$BUILD_DIR/configure.log" 2>&1 ||
		{ tail -30 "$BUILD_DIR/configure.log" >&2; die "cmake configure failed"; }
	cmake --build "$BUILD_DIR" --target relight-cli -j"$(nproc)" >"$BUILD_DIR/build.log" 2>&1 ||
		{ tail -30 "$BUILD_DIR/build.log" >&2; die "relight-cli build failed"; }
	RELIGHT_CLI="$BUILD_DIR/relight-cli/relight-cli"
	[[ -x $RELIGHT_CLI ]] || die "no binary at $RELIGHT_CLI"
}

# ---------------------------------------------------------------- relight-cli wrappers
# Fit a web-format folder: fit BASIS NPLANES OUTDIR
record() { printf '%s\t%s\n' "${1#"$OUT"/}" "$2" >>"$PRODUCED_TSV"; }

fit_web() {
	rm -rf "$3"
	record "$3" "relight-cli -I srgb -b $1 -p $2 capture ${3#"$OUT"/}"
	"$RELIGHT_CLI" -I srgb -b "$1" -p "$2" "$OUT/capture" "$3" >/dev/null
	[[ -f $3/info.json ]] || die "relight-cli wrote no $3/info.json"
}

# Fit straight to .ptm / .rti: fit_legacy BASIS NPLANES FILE
fit_legacy() {
	rm -f "$3"
	record "$3" "relight-cli -I srgb -b $1 -p $2 capture ${3#"$OUT"/}"
	"$RELIGHT_CLI" -I srgb -b "$1" -p "$2" "$OUT/capture" "$3" >/dev/null
	[[ -s $3 ]] || die "relight-cli wrote no $3"
}

# .ptm/.rti -> web folder: to_web FILE OUTDIR
# relight-cli converts, then falls through into the fitting code with an empty
# image set and dies of SIGFPE (exit 136); the folder is complete by then, so
# the exit status is only trusted together with the files.
to_web() {
	rm -rf "$2"
	mkdir -p "$(dirname "$2")" # relight-cli creates only the last folder level
	record "$2" "relight-cli ${1#"$OUT"/} ${2#"$OUT"/}"
	local rc=0
	{ "$RELIGHT_CLI" "$1" "$2"; } >/dev/null 2>&1 || rc=$?
	if [[ $rc -ne 0 && $rc -ne 136 ]] || [[ ! -f $2/info.json ]] || [[ ! -f $2/plane_0.jpg ]]; then
		die "relight-cli could not convert $1 (exit $rc)"
	fi
}

# web folder -> .ptm/.rti: from_web WEBDIR FILE (relight prints warnings on stderr)
from_web() {
	rm -f "$2"
	record "$2" "relight-cli ${1#"$OUT"/}/info.json ${2#"$OUT"/}"
	"$RELIGHT_CLI" "$1/info.json" "$2" >/dev/null 2>&1 || true
	[[ -s $2 ]] || die "relight-cli could not convert $1 to $2"
}

# Relight a web folder at the four lights: relight_all WEBDIR OUTDIR MANIFEST_SOURCE KIND
# Appends one line per image to $MANIFEST_TSV.
relight_all() {
	local web=$1 dst=$2 source=$3 kind=$4
	rm -rf "$dst"
	mkdir -p "$dst"
	local i
	for i in "${!LIGHT_NAMES[@]}"; do
		local png="$dst/${LIGHT_NAMES[$i]}.png"
		"$RELIGHT_CLI" -L "${LIGHT_ARGS[$i]}" -D "$png" "$web" >/dev/null
		[[ -s $png ]] || die "relight-cli wrote no $png"
		printf '%s\t%s\t%s\t%s\t%s\t%s\n' "$kind" "$source" "${web#"$OUT"/}" "${LIGHT_NAMES[$i]}" \
			"${LIGHT_ARGS[$i]}" "${png#"$OUT"/}" >>"$MANIFEST_TSV"
	done
}

# ================================================================ btfrs-side exports
# >>> btfrs exports hook
# btfrs writes .ptm, .rti and relight web folders (a folder holding info.json) into
# one folder; this section has relight-cli read them: .ptm/.rti are converted to a
# web folder first (relight-cli -L only reads the web format), then every web
# folder is relit at the four lights, into $OUT/btfrs_exports/<name>/...
#
# To have the full regeneration produce the exports, set BTFRS_EXPORT_CMD to a
# command that takes two arguments, the capture folder and the folder to write
# the exports to, e.g.
#   BTFRS_EXPORT_CMD="python scripts/reference/btfrs_relight_exports.py"
# or put the exports in $OUT/btfrs_exports/input yourself and run
#   scripts/reference/relight_fixtures.sh --exports-only tests/fixtures/relight/btfrs_exports/input
relight_exports() {
	local src=$1 dst=$2
	[[ -d $src ]] || die "no export folder $src"
	mkdir -p "$dst"
	local found=0 f name
	shopt -s nullglob
	for f in "$src"/*.ptm "$src"/*.rti; do
		name=$(basename "$f")
		name="${name%.*}_${name##*.}"
		to_web "$f" "$dst/$name/web"
		relight_all "$dst/$name/web" "$dst/$name/relit" "${f#"$OUT"/}" btfrs_export
		found=$((found + 1))
	done
	for f in "$src"/*/info.json; do
		name=$(basename "$(dirname "$f")")
		f=${f%/info.json}
		relight_all "$f" "$dst/$name/relit" "${f#"$OUT"/}" btfrs_export
		found=$((found + 1))
	done
	shopt -u nullglob
	[[ $found -gt 0 ]] || die "nothing to relight in $src (expects *.ptm, *.rti or */info.json)"
	log "relit $found btfrs export(s) into $dst"
}
# <<< btfrs exports hook

# ---------------------------------------------------------------- manifest
write_manifest() {
	"$PYTHON" - "$MANIFEST_TSV" "$OUT/manifest.json" "$1" "$PRODUCED_TSV" <<'EOF'
import json, sys
tsv, out, section, produced = sys.argv[1:5]
try:
    with open(out) as f:
        manifest = json.load(f)
except FileNotFoundError:
    manifest = {}
entries = []
with open(tsv) as f:
    for line in f:
        kind, source, web, light_name, light_arg, output = line.rstrip("\n").split("\t")
        with open(f"{out.rsplit('/', 1)[0]}/{web}/info.json") as g:
            info = json.load(g)
        entries.append({
            "kind": kind,
            "source": source,
            "web_folder": web,
            "basis": info["type"],
            "colorspace": info["colorspace"],
            "nplanes": info.get("nplanes"),
            "light_name": light_name,
            "light_arg": light_arg,
            "light": [float(c) for c in light_arg.split(":")],
            "output": output,
        })
manifest["note"] = ("relight-cli -L <light_arg> -D <output> <web_folder>; relight normalises the light. "
                    "Axes: x to the image's right, y up the image, z out of the surface. "
                    "Outputs are 8-bit RGBA PNG (alpha 255), values as computed, no gamma applied.")
manifest[section] = entries
with open(produced) as f:
    made = [line.rstrip("\n").split("\t") for line in f if line.strip()]
if made:
    manifest.setdefault("produced", {})
    for path, command in made:
        manifest["produced"][path] = command
with open(out, "w") as f:
    json.dump(manifest, f, indent=1)
    f.write("\n")
EOF
}

write_versions() {
	{
		if [[ -n $RELIGHT_SRC ]] && git -C "$RELIGHT_SRC" rev-parse --show-toplevel 2>/dev/null | grep -qx "$(realpath "$RELIGHT_SRC")"; then
			echo "relight_commit $(git -C "$RELIGHT_SRC" rev-parse HEAD)"
		else
			echo "relight_commit unknown (expected $RELIGHT_COMMIT)"
		fi
		echo "relight_version $(cat "$RELIGHT_SRC/RELIGHT_VERSION" 2>/dev/null || echo unknown)"
		echo "qt6-base-dev $(dpkg-query -W -f='${Version}' qt6-base-dev 2>/dev/null || echo unknown)"
		echo "gcc $(gcc -dumpfullversion 2>/dev/null || echo unknown)"
		echo "cmake $(cmake --version 2>/dev/null | head -1 | awk '{print $3}')"
		echo "libjpeg62-turbo $(dpkg-query -W -f='${Version}' libjpeg62-turbo 2>/dev/null || echo unknown)"
		echo "liblcms2-2 $(dpkg-query -W -f='${Version}' liblcms2-2 2>/dev/null || echo unknown)"
		"$PYTHON" -c 'import numpy, PIL; print("numpy", numpy.__version__); print("Pillow", PIL.__version__)'
	} >"$OUT/versions.txt"
}

# ================================================================ main
"$PYTHON" -c 'import numpy, PIL' 2>/dev/null || die "$PYTHON lacks numpy or Pillow (use --python)"
if [[ -z $RELIGHT_CLI ]]; then
	install_packages
fi
build_relight
log "relight-cli: $RELIGHT_CLI"
mkdir -p "$OUT"
MANIFEST_TSV=$(mktemp)
PRODUCED_TSV=$(mktemp)
trap 'rm -f "$MANIFEST_TSV" "$PRODUCED_TSV"' EXIT

if [[ -n $EXPORTS_ONLY ]]; then
	relight_exports "$(realpath "$EXPORTS_ONLY")" "$OUT/btfrs_exports"
	write_manifest btfrs_exports
	exit 0
fi

if [[ $SELFTEST -eq 1 ]]; then
	[[ -d $OUT/legacy && -d $OUT/web ]] || die "run the full regeneration first"
	tmp=$(mktemp -d)
	mkdir -p "$tmp/input"
	cp "$OUT"/legacy/*.ptm "$OUT"/legacy/*.rti "$tmp/input/"
	cp -r "$OUT/web/hsh_27" "$tmp/input/hsh_27"
	saved_out=$OUT
	OUT=$tmp
	relight_exports "$tmp/input" "$tmp/btfrs_exports"
	OUT=$saved_out
	# the relit images must equal the committed relight renders of the same data
	status=0
	for name in ptm_rgb_ptm ptm_lrgb_ptm hsh_27_rti hsh_12_rti from_web_hsh_27_rti; do
		for l in "${LIGHT_NAMES[@]}"; do
			cmp -s "$tmp/btfrs_exports/$name/relit/$l.png" "$OUT/relit/legacy/$name/$l.png" ||
				{ echo "selftest: $name/$l.png differs" >&2; status=1; }
		done
	done
	for l in "${LIGHT_NAMES[@]}"; do
		cmp -s "$tmp/btfrs_exports/hsh_27/relit/$l.png" "$OUT/relit/web/hsh_27/$l.png" ||
			{ echo "selftest: hsh_27/$l.png differs" >&2; status=1; }
	done
	if [[ $status -eq 0 ]]; then
		log "selftest passed"
		rm -rf "$tmp"
	else
		log "selftest FAILED, see $tmp"
	fi
	exit $status
fi

log "capture"
"$PYTHON" "$REPO_ROOT/scripts/reference/relight_capture.py" "$OUT"

log "web format fits"
rm -rf "$OUT/web" "$OUT/legacy" "$OUT/legacy_web" "$OUT/relit" "$OUT/manifest.json"
mkdir -p "$OUT/web" "$OUT/legacy" "$OUT/legacy_web"
fit_web ptm 18 "$OUT/web/ptm_rgb"
fit_web lptm 9 "$OUT/web/ptm_lrgb"
fit_web hsh 27 "$OUT/web/hsh_27"
fit_web hsh 12 "$OUT/web/hsh_12"
fit_web rbf 9 "$OUT/web/rbf"
fit_web bilinear 9 "$OUT/web/bilinear"

log ".ptm / .rti"
fit_legacy ptm 18 "$OUT/legacy/ptm_rgb.ptm"   # PTM_FORMAT_RGB, raw
fit_legacy lptm 9 "$OUT/legacy/ptm_lrgb.ptm"  # PTM_FORMAT_JPEG_LRGB
fit_legacy hsh 27 "$OUT/legacy/hsh_27.rti"    # HSH, 9 terms
fit_legacy hsh 12 "$OUT/legacy/hsh_12.rti"    # HSH, 4 terms
from_web "$OUT/web/hsh_27" "$OUT/legacy/from_web_hsh_27.rti"

log ".ptm / .rti -> web format"
for f in "$OUT"/legacy/*.ptm "$OUT"/legacy/*.rti; do
	name=$(basename "$f")
	to_web "$f" "$OUT/legacy_web/${name%.*}_${name##*.}"
done

log "relighting"
for d in "$OUT"/web/*/; do
	d=${d%/}
	relight_all "$d" "$OUT/relit/web/$(basename "$d")" "${d#"$OUT"/}" relight_web
done
for d in "$OUT"/legacy_web/*/; do
	d=${d%/}
	name=$(basename "$d")
	src="legacy/${name%_*}.${name##*_}"
	relight_all "$d" "$OUT/relit/legacy/$name" "$src" relight_legacy
done
write_manifest relit

# ---- btfrs-side exports (see the hook above)
if [[ -n ${BTFRS_EXPORT_CMD:-} ]]; then
	log "btfrs exports: $BTFRS_EXPORT_CMD"
	rm -rf "$OUT/btfrs_exports/input"
	mkdir -p "$OUT/btfrs_exports/input"
	$BTFRS_EXPORT_CMD "$OUT/capture" "$OUT/btfrs_exports/input"
fi
if [[ -d $OUT/btfrs_exports/input ]] && [[ -n $(ls -A "$OUT/btfrs_exports/input") ]]; then
	: >"$MANIFEST_TSV"
	relight_exports "$OUT/btfrs_exports/input" "$OUT/btfrs_exports"
	write_manifest btfrs_exports
fi

write_versions
log "checking the web-format description against relight's renders"
"$PYTHON" "$REPO_ROOT/scripts/reference/relight_check.py" "$OUT" >"$OUT/check.txt" || die "see $OUT/check.txt"
log "done: $(du -sh --apparent-size "$OUT" | cut -f1) in $OUT"
