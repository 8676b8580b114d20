#!/usr/bin/env bash
# Runs libFuzzer targets (make FUZZ=1 fuzz-build) one after another, each on
# a scratch copy of its committed corpus tests/data/fuzz-NAME (so what the
# fuzzer adds is thrown away and the corpus stays as committed), with the
# dictionary tests/data/fuzz-NAME.dict when there is one; then prints a
# table of target, executions, seconds and findings.
#
#   tests/run-libfuzzer.sh BINDIR RUNS MAX_SECONDS TARGET...
#       RUNS: -runs for each target; MAX_SECONDS: -max_total_time (0: none).
#       A finding is a crash, leak, timeout (25 s an input) or out-of-memory
#       (2 GiB); its input and log are kept in build-fuzz/findings/TARGET/.
#       Exits 1 if anything was found.
#   tests/run-libfuzzer.sh --available
#       exits 0 when clang links -fsanitize=fuzzer (libFuzzer is installed).
set -u
if [ "${1:-}" = --available ]; then
    command -v clang >/dev/null 2>&1 || exit 1
    t=$(mktemp -d "${TMPDIR:-/tmp}/vb-libfuzzer-probe.XXXXXX") || exit 1
    printf 'int LLVMFuzzerTestOneInput(const unsigned char *d, unsigned long n);\n%s\n' \
        'int LLVMFuzzerTestOneInput(const unsigned char *d, unsigned long n) { (void)d; (void)n; return 0; }' \
        >"$t/probe.c"
    clang -fsanitize=fuzzer,address,undefined -o "$t/probe" "$t/probe.c" >/dev/null 2>&1
    rc=$?
    rm -rf "$t"
    exit $rc
fi
if [ $# -lt 4 ]; then
    echo "usage: $0 BINDIR RUNS MAX_SECONDS TARGET... | --available" >&2
    exit 2
fi
bindir=$1 runs=$2 maxt=$3
shift 3
findings_root=build-fuzz/findings
scratch=$(mktemp -d "${TMPDIR:-/tmp}/vb-libfuzzer.XXXXXX") || exit 2
trap 'rm -rf "$scratch"' EXIT
status=0
table=""
for t in "$@"; do
    name=${t#fuzz_}
    work=$scratch/$t
    mkdir -p "$work/corpus" "$work/artifacts"
    cp tests/data/fuzz-"$name"/* "$work/corpus/"
    args=(-runs="$runs" -timeout=25 -rss_limit_mb=2048 -print_final_stats=1
          -artifact_prefix="$work/artifacts/")
    [ "$maxt" != 0 ] && args+=(-max_total_time="$maxt")
    [ -f tests/data/fuzz-"$name".dict ] && args+=(-dict=tests/data/fuzz-"$name".dict)
    echo "== $t: ${args[*]} (corpus: tests/data/fuzz-$name, a copy)"
    start=$(date +%s.%N)
    "$bindir/$t" "${args[@]}" "$work/corpus" >"$work/log" 2>&1
    rc=$?
    end=$(date +%s.%N)
    secs=$(awk -v a="$start" -v b="$end" 'BEGIN { printf "%.1f", b - a }')
    execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$work/log" | tail -n 1)
    found=$(find "$work/artifacts" -type f | wc -l)
    # a non-zero exit with no artifact (killed, a fault at start-up) counts too
    if [ "$rc" != 0 ] && [ "$found" = 0 ]; then found=1; fi
    if [ "$found" != 0 ]; then
        status=1
        mkdir -p "$findings_root/$t"
        cp "$work/artifacts/"* "$findings_root/$t/" 2>/dev/null
        cp "$work/log" "$findings_root/$t/log"
        echo "$t: exit $rc, $found finding(s), kept in $findings_root/$t/; the log's end:"
        tail -n 40 "$work/log"
    else
        grep -E '^#[0-9]+[[:space:]]+DONE' "$work/log" | tail -n 1
    fi
    table+=$(printf '%-12s %12s %9s %9s' "$t" "${execs:-?}" "$secs" "$found")$'\n'
done
echo
printf '%-12s %12s %9s %9s\n' target executions seconds findings
printf '%s' "$table"
exit $status
