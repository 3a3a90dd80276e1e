#!/usr/bin/env bash
# Profile `outlet detect` with perf on one core (issue 15, item 1).
#
#   scripts/bench/profile_outlet.sh OUTLET_BIN IMAGE_DIR [PASSES]
#
# Runs `taskset -c 0 perf record -F 4000 --call-graph dwarf` over every PNG of
# IMAGE_DIR (PASSES times over the set, default 5; e.g. the pasted images that
# `scripts/bench_vs_apriltag.sh --keep DIR` keeps in DIR/640x480/pasted), then
# prints the share of samples under each detector stage (inclusive, "children")
# and the top functions by their own samples (`perf report --stdio | head`).
# Needs Debian's linux-perf (apt-get install -y linux-perf); the release profile
# keeps debug info (Cargo.toml: debug = 1), which the dwarf call graphs use.
set -euo pipefail

die() { echo "profile_outlet: $*" >&2; exit 1; }
[[ $# -ge 2 ]] || die "usage: $0 OUTLET_BIN IMAGE_DIR [PASSES]"
OUTLET="$1"; DIR="$2"; PASSES="${3:-5}"
[[ -x "$OUTLET" ]] || die "no executable at $OUTLET"
[[ "$PASSES" =~ ^[1-9][0-9]*$ ]] || die "PASSES must be a positive number"
command -v perf >/dev/null || die "perf is missing: apt-get install -y linux-perf"
shopt -s nullglob
IMGS=("$DIR"/*.png)
[[ ${#IMGS[@]} -gt 0 ]] || die "no PNG in $DIR"
ALL=()
for _ in $(seq "$PASSES"); do ALL+=("${IMGS[@]}"); done

WORK="$(mktemp -d "${TMPDIR:-/tmp}/profile_outlet.XXXXXX")"
trap 'rm -rf "$WORK"' EXIT
taskset -c 0 perf record -q -F 4000 --call-graph dwarf,16384 -o "$WORK/perf.data" -- \
    "$OUTLET" detect --template 2x2 --json "${ALL[@]}" >/dev/null 2>"$WORK/record.log" \
    || { cat "$WORK/record.log" >&2; die "perf record failed (is perf allowed on this machine? see /proc/sys/kernel/perf_event_paranoid)"; }
echo "${#ALL[@]} detections ($PASSES passes over ${#IMGS[@]} images of $DIR), $(perf report -i "$WORK/perf.data" --stdio 2>/dev/null | grep -m1 '^# Samples' | sed 's/^# //' || true)"
echo
echo "## Stages: share of all samples under each (inclusive)"
perf report -i "$WORK/perf.data" --stdio --children --sort symbol 2>/dev/null \
    | grep -E '^ +[0-9]' | sed -E 's/[[:space:]]+-[[:space:]]+-[[:space:]]*$//; s/[[:space:]]+$//' \
    | grep -E '\] (outlet_detector::detect::Detector::(detect|detect_grey|search|refine)|outlet_detector::candidates::find_candidates|outlet_detector::descriptor::classify::.*::classify|outlet_detector::hashing::find_outlet|outlet_detector::refine::fit|outlet_detector::verify::[a-z_]+|outlet_detector::grey_of|image::images::dynimage::open|outlet::templates::load)( \(inlined\))?$' \
    | awk '{ $2 = ""; print }' | awk '!seen[$0]++' || true
echo
echo "## Top functions by their own samples"
perf report -i "$WORK/perf.data" --stdio --no-children -g none --sort symbol 2>/dev/null \
    | grep -E '^ +[0-9]' | sed -E 's/[[:space:]]+-[[:space:]]+-[[:space:]]*$//; s/[[:space:]]+$//' | head -20 || true
