#!/usr/bin/env bash
# outlet's detector side by side with AprilTag 3 (Debian's apriltag 3.3) on the
# same frames, on one core (issue 15, item 1). See BENCHMARKS.md, "Side by side
# with AprilTag 3.3".
#
#   scripts/bench_vs_apriltag.sh [--count N] [--reps R] [--seed S] [--keep DIR] [--outlet BIN]
#
# For 640x480 and 1280x960: renders N white2x2 scenes (`outlet render`), pastes
# a tag36h11 tag (id 0, 15% of the image width, white border) into a copy of each
# where it does not cover the outlet, then, pinned to CPU 0 (`taskset -c 0`):
#   - AprilTag: a small C program (scripts/bench/apriltag_bench.c), 1 thread,
#     tag36h11, quad_decimate 1 and 2; per image the median of R calls of
#     apriltag_detector_detect alone, and the time it took to read the PGM;
#   - outlet: `outlet detect --template 2x2 --json` over the pasted PNGs, and over
#     the same PGMs AprilTag reads, R runs each;
#     per image the median of its own timing_ms.detect (Detector::detect on the
#     decoded image in memory, wall clock), and the process's CPU time per image
#     over a whole run ((CPU of N images - CPU of 1 image) / (N - 1): reading
#     the file, detection and the JSON line; startup and template cancel out).
# CPU times are what to trust on a busy machine; wall times on an idle one.
# Prints a markdown table: medians over the images, ratios outlet / AprilTag,
# and how many images each found (AprilTag: the pasted tag; outlet: the outlet,
# "right" when every hole is within 3 px of the truth).
#
# Needs: cc, python3, taskset, Debian's apriltag + libapriltag-dev and netpbm
# (installed with apt-get when run as root), cargo for outlet (or --outlet BIN).
set -euo pipefail

COUNT=20
REPS=5
SEED=15
KEEP=""
OUTLET_BIN=""

die() { echo "bench_vs_apriltag: $*" >&2; exit 1; }
usage() { sed -n '2,26p' "$0" | sed 's/^# \{0,1\}//'; exit "${1:-0}"; }

while [[ $# -gt 0 ]]; do
    case "$1" in
        --count) COUNT="${2:?--count needs a number}"; shift 2 ;;
        --reps) REPS="${2:?--reps needs a number}"; shift 2 ;;
        --seed) SEED="${2:?--seed needs a number}"; shift 2 ;;
        --keep) KEEP="${2:?--keep needs a folder}"; shift 2 ;;
        --outlet) OUTLET_BIN="${2:?--outlet needs a path}"; shift 2 ;;
        -h|--help) usage 0 ;;
        *) echo "unknown argument: $1" >&2; usage 2 >&2 ;;
    esac
done
[[ "$COUNT" =~ ^[0-9]+$ && "$COUNT" -ge 2 ]] || die "--count must be a number >= 2"
[[ "$REPS" =~ ^[0-9]+$ && "$REPS" -ge 1 ]] || die "--reps must be a number >= 1"
[[ "$SEED" =~ ^[0-9]+$ ]] || die "--seed must be a number"

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
HERE="$ROOT/scripts/bench"

# 1. Debian packages.
PKGS=()
[[ -f /usr/include/apriltag/apriltag.h ]] || PKGS+=(apriltag libapriltag-dev)
command -v pngtopnm >/dev/null && command -v jpegtopnm >/dev/null \
    && command -v ppmtopgm >/dev/null && command -v pnmtopng >/dev/null || PKGS+=(netpbm)
command -v cc >/dev/null || PKGS+=(gcc libc6-dev)
command -v taskset >/dev/null || PKGS+=(util-linux)
if [[ ${#PKGS[@]} -gt 0 ]]; then
    if [[ "$(id -u)" -ne 0 ]]; then
        die "missing Debian packages; install them with: sudo apt-get install -y ${PKGS[*]}"
    fi
    echo "installing ${PKGS[*]} ..." >&2
    export DEBIAN_FRONTEND=noninteractive
    if ! apt-get install -y "${PKGS[@]}" >&2; then
        apt-get update >&2 && apt-get install -y "${PKGS[@]}" >&2 \
            || die "apt-get install -y ${PKGS[*]} failed"
    fi
fi
command -v python3 >/dev/null || die "python3 is needed (apt-get install -y python3)"

WORK="$(mktemp -d "${TMPDIR:-/tmp}/bench_vs_apriltag.XXXXXX")"
cleanup() { rm -rf "$WORK"; }
trap cleanup EXIT

# 2. The two programs. outlet is copied so that a concurrent build cannot change it mid-run.
if [[ -z "$OUTLET_BIN" ]]; then
    echo "building outlet (cargo build --release -p outlet) ..." >&2
    (cd "$ROOT" && cargo build --release -p outlet >&2) || die "cargo build failed"
    OUTLET_BIN="$ROOT/target/release/outlet"
fi
[[ -x "$OUTLET_BIN" ]] || die "no outlet binary at $OUTLET_BIN"
cp "$OUTLET_BIN" "$WORK/outlet"
OUTLET="$WORK/outlet"
cc -O2 -Wall -o "$WORK/apriltag_bench" "$HERE/apriltag_bench.c" \
    -I/usr/include/apriltag -lapriltag -lapriltag-utils -lm \
    || die "compiling scripts/bench/apriltag_bench.c against libapriltag failed"
APRIL="$WORK/apriltag_bench"
PY="$HERE/bench_vs_apriltag.py"

if [[ "$OUTLET_BIN" == "$ROOT/target/release/outlet" ]]; then
    SRC="built from the working tree at commit $(git -C "$ROOT" rev-parse --short HEAD 2>/dev/null || echo '?')"
    git -C "$ROOT" diff --quiet HEAD -- services protocol clients Cargo.toml Cargo.lock 2>/dev/null \
        || SRC="$SRC with uncommitted changes"
else
    SRC="the binary $OUTLET_BIN"
fi
VERSIONS="outlet: $SRC; AprilTag: libapriltag-dev $(dpkg-query -W -f='${Version}' libapriltag-dev 2>/dev/null || echo '?'); CPU: $(grep -m1 'model name' /proc/cpuinfo | sed 's/.*: //'), $(nproc) cores, load average $(cut -d' ' -f1-3 /proc/loadavg) at the start"

ROWS=()
JSONS=()
for RES in 640x480 1280x960; do
    W="${RES%x*}"; H="${RES#*x}"
    TAG=$(( W * 15 / 100 ))
    D="$WORK/$RES"
    mkdir -p "$D/render" "$D/pasted"
    echo "[$RES] rendering $COUNT white2x2 scenes (seed $SEED) ..." >&2
    "$OUTLET" render --scenario white2x2 --count "$COUNT" --seed "$SEED" --width "$W" --height "$H" \
        --threads 1 --out "$D/render" >/dev/null 2>"$D/render.log" \
        || { cat "$D/render.log" >&2; die "outlet render failed"; }
    echo "[$RES] pasting a ${TAG} px tag36h11 tag into each ..." >&2
    n=0
    for truth in "$D"/render/white2x2_*.json; do
        stem="$(basename "$truth" .json)"
        if [[ -f "$D/render/$stem.png" ]]; then
            pngtopnm "$D/render/$stem.png" >"$D/$stem.ppm" 2>/dev/null
        elif [[ -f "$D/render/$stem.jpg" ]]; then
            jpegtopnm "$D/render/$stem.jpg" >"$D/$stem.ppm" 2>/dev/null
        else
            die "no image for $truth"
        fi
        read -r X Y < <(python3 "$PY" place "$truth" "$W" "$H" "$TAG")
        "$APRIL" paste "$TAG" "$X" "$Y" "$D/$stem.ppm" "$D/pasted/$stem.ppm"
        ppmtopgm "$D/pasted/$stem.ppm" >"$D/pasted/$stem.pgm"
        pnmtopng "$D/pasted/$stem.ppm" >"$D/pasted/$stem.png" 2>/dev/null
        rm -f "$D/$stem.ppm" "$D/pasted/$stem.ppm"
        n=$((n + 1))
    done
    [[ "$n" -eq "$COUNT" ]] || die "$RES: rendered $n images, expected $COUNT"

    echo "[$RES] AprilTag, decimate 1 and 2, $REPS repetitions each, on CPU 0 ..." >&2
    taskset -c 0 "$APRIL" detect 1 "$REPS" "$D"/pasted/*.pgm >"$D/april_d1.txt"
    taskset -c 0 "$APRIL" detect 2 "$REPS" "$D"/pasted/*.pgm >"$D/april_d2.txt"
    # outlet reads the colour PNG (and makes its own grey, the brightest channel), and
    # the very PGM AprilTag reads (its grey is luminance: a mono camera's).
    for INPUT in png pgm; do
        echo "[$RES] outlet detect on the ${INPUT^^} files, $REPS runs, on CPU 0 ..." >&2
        TRUTH_DIR="$D/render" python3 "$PY" time-outlet "$OUTLET" "$REPS" "$D"/pasted/*."$INPUT" >"$D/outlet_$INPUT.json"
        out="$(python3 "$PY" summary "$RES, ${INPUT^^}" "$D/outlet_$INPUT.json" "$D/april_d1.txt" "$D/april_d2.txt")"
        ROWS+=("$(grep -v '^JSON ' <<<"$out")")
        JSONS+=("$(grep '^JSON ' <<<"$out" | sed 's/^JSON //')")
    done
done

if [[ -n "$KEEP" ]]; then
    mkdir -p "$KEEP"
    cp -r "$WORK/640x480" "$WORK/1280x960" "$KEEP/"
    echo "images and raw timings kept in $KEEP" >&2
fi

echo
echo "$VERSIONS"
echo "N = $COUNT images per resolution, $REPS repetitions, one core (taskset -c 0); ms, medians over the images."
echo "wall: outlet's own timing_ms.detect (Detector::detect, image decoded in memory) vs apriltag_detector_detect alone;"
echo "CPU: outlet's process CPU time per image over a batch run ((N images - 1 image) / (N - 1), reading included)"
echo "     vs AprilTag's thread CPU time of PGM reading + detection. d1 / d2: AprilTag's quad_decimate 1 / 2."
echo "PNG rows: outlet reads the colour PNG; PGM rows: outlet reads the same grey PGM file as AprilTag."
echo
echo "tracking: outlet detect --track 30 over each image repeated 6 times (a still camera), the frames a window found."
echo
echo "| resolution | N | outlet detect, wall | outlet tracking, wall (windows found) | AprilTag d1 / d2, wall | outlet / AprilTag d1 / d2 | outlet tracking / AprilTag d1 / d2 | outlet per image, CPU, reading incl. | AprilTag d1 / d2 read + detect, CPU | outlet / AprilTag d1 / d2 | outlet found | AprilTag found d1, d2 |"
echo "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
printf '%s\n' "${ROWS[@]}"
echo
echo "load average at the end: $(cut -d' ' -f1-3 /proc/loadavg)"
echo
printf '%s\n' "${JSONS[@]}"
