#!/usr/bin/env bash
# Runs every cargo-fuzz target for a set time and prints, per target, the
# executions, executions per second, coverage and findings.
#
#   scripts/fuzz.sh [SECONDS_PER_TARGET]      (default 60)
#   FUZZ_TARGETS="ply wire" scripts/fuzz.sh 30 (a subset)
#
# Needs a nightly toolchain and cargo-fuzz (`cargo install cargo-fuzz --locked`).
# Corpora grow in fuzz/corpus/<target> (seeded from fuzz/seeds/<target>), crashes
# land in fuzz/artifacts/<target>, libFuzzer's output in fuzz/logs/<target>.log.
# A crash found: fix it, then keep its input as a regression test that plain
# `cargo test` runs (protocol/tests/fuzz_regressions/, services/*/tests/fuzz_regressions/).
set -euo pipefail

seconds="${1:-60}"
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"

if ! cargo +nightly fuzz --version >/dev/null 2>&1; then
    echo "cargo-fuzz on nightly is needed: rustup toolchain install nightly && cargo install cargo-fuzz --locked" >&2
    exit 2
fi

targets="${FUZZ_TARGETS:-$(cargo +nightly fuzz list --fuzz-dir fuzz)}"
echo "building the fuzz targets (nightly, address sanitizer, debug assertions)..."
mkdir -p fuzz/logs
if ! cargo +nightly fuzz build --fuzz-dir fuzz >fuzz/logs/build.log 2>&1; then
    cat fuzz/logs/build.log >&2
    exit 2
fi

printf '\n%-14s %12s %10s %8s %8s  %s\n' target executions exec/s cov ft findings
status=0
for target in $targets; do
    corpus="fuzz/corpus/$target"
    artifacts="fuzz/artifacts/$target"
    log="fuzz/logs/$target.log"
    mkdir -p "$corpus" "$artifacts"
    seeds=()
    [ -d "fuzz/seeds/$target" ] && seeds=("fuzz/seeds/$target")
    before=$(find "$artifacts" -type f | wc -l)
    # libFuzzer stops at the first crash and saves its input in $artifacts.
    cargo +nightly fuzz run --fuzz-dir fuzz "$target" "$corpus" "${seeds[@]}" -- \
        -max_total_time="$seconds" -rss_limit_mb=4096 -timeout=20 -max_len=65536 \
        -print_final_stats=1 -artifact_prefix="$artifacts/" >"$log" 2>&1 || true
    after=$(find "$artifacts" -type f | wc -l)
    runs=$(grep -E '^stat::number_of_executed_units' "$log" | tail -1 | awk '{print $2}')
    rate=$(grep -E '^stat::average_exec_per_sec' "$log" | tail -1 | awk '{print $2}')
    # The last status line: "#N  DONE/pulse  cov: C ft: F corp: ..."
    line=$(grep -E '^#[0-9]+' "$log" | grep -E 'cov:' | tail -1)
    cov=$(sed -nE 's/.*cov: ([0-9]+).*/\1/p' <<<"$line")
    ft=$(sed -nE 's/.*ft: ([0-9]+).*/\1/p' <<<"$line")
    findings=$((after - before))
    kinds=$(grep -oE 'ERROR: libFuzzer: [a-z-]+|panicked at [^ ]+' "$log" | sort | uniq -c | tr '\n' ';' || true)
    printf '%-14s %12s %10s %8s %8s  %s %s\n' "$target" "${runs:-?}" "${rate:-?}" "${cov:-?}" "${ft:-?}" "$findings" "$kinds"
    [ "$findings" -gt 0 ] && status=1
done
echo
echo "logs: fuzz/logs/<target>.log; crashing inputs: fuzz/artifacts/<target>/"
exit $status
