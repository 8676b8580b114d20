#!/usr/bin/env bash
# Runs every Check suite and fuzz target given on the command line, then
# prints one closing line adding up the Check counts: "tests: N passed, M failed"
# (then ", K skipped" when K > 0 tests printed a line starting with "SKIPPED:").
# Usage: tests/run-suites.sh SUITE... [-- FUZZ[:N]...]; a fuzz target runs its
# corpus and N mutations (20000 if not given). A SUITE written PATH:CASE runs
# only that Check case (CK_RUN_CASE takes one name, so a subset is one
# argument per case). The environment (VB_*) comes from the Makefile. Exits
# non-zero if anything failed. Each suite's wall time is printed after it
# ("-- SUITE: N s") and once more, all together, at the end (docs/TESTING.md
# keeps a table of them).
set -u
passed=0
failed=0
skipped=0
status=0
fuzz=0
times=""
start_all=$(date +%s.%N)
# Seconds since $1 (date +%s.%N), to a tenth.
since() { awk -v a="$1" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }'; }
for t in "$@"; do
    if [ "$t" = "--" ]; then fuzz=1; continue; fi
    if [ $fuzz = 1 ]; then
        n=20000
        case $t in *:*) n=${t##*:}; t=${t%:*} ;; esac
        echo "== $t (corpus + $n mutations)"
        t0=$(date +%s.%N)
        if "$t" tests/data/fuzz "$n"; then passed=$((passed + 1)); else failed=$((failed + 1)); status=1; fi
        s=$(since "$t0"); echo "-- ${t##*/}: $s s"; times="$times${t##*/} $s\n"
        continue
    fi
    ck_case=""
    t0=$(date +%s.%N)
    case "$t" in *:*) ck_case=${t#*:}; t=${t%%:*} ;; esac
    # Check's XML log holds each case's duration: the slowest are printed
    xml=$(mktemp)
    if [ -n "$ck_case" ]; then
        echo "== $t ($ck_case)"
        out=$(CK_XML_LOG_FILE_NAME="$xml" CK_RUN_CASE="$ck_case" "$t" 2>&1); rc=$?
    else
        echo "== $t"
        out=$(CK_XML_LOG_FILE_NAME="$xml" "$t" 2>&1); rc=$?
    fi
    printf '%s\n' "$out"
    slow=$(awk -F'[<>]' '/<id>/ { id = $3 } /<duration>/ && id != "" { printf "%s %s\n", $3, id; id = "" }' "$xml" |
        sort -rn | head -n 5 | awk '$1 >= 1 { printf "%s%s %.1f s", sep, $2, $1; sep = ", " }')
    rm -f "$xml"
    [ -z "$slow" ] || echo "-- slowest cases: $slow"
    k=$(printf '%s\n' "$out" | grep -c '^SKIPPED:')
    skipped=$((skipped + k))
    line=$(printf '%s\n' "$out" | grep -E 'Checks: [0-9]+, Failures: [0-9]+, Errors: [0-9]+' | tail -n 1)
    if [ -n "$line" ]; then
        n=$(echo "$line" | sed -E 's/.*Checks: ([0-9]+).*/\1/')
        f=$(echo "$line" | sed -E 's/.*Failures: ([0-9]+).*/\1/')
        e=$(echo "$line" | sed -E 's/.*Errors: ([0-9]+).*/\1/')
        passed=$((passed + n - f - e))
        failed=$((failed + f + e))
        if [ -n "$ck_case" ] && [ "$n" = 0 ]; then
            # a renamed case would otherwise be skipped without a word
            echo "$t: no Check case named '$ck_case'"
            failed=$((failed + 1))
        fi
    else
        echo "$t: no Check summary (crashed?)"
        failed=$((failed + 1))
    fi
    [ $rc = 0 ] || status=1
    s=$(since "$t0"); name=${t##*/}${ck_case:+:$ck_case}
    echo "-- $name: $s s"; times="$times$name $s\n"
done
echo "seconds per suite:"
printf '%b' "$times" | awk '{ printf "  %-36s %7s\n", $1, $2 }'
echo "all suites: $(since "$start_all") s"
if [ $skipped -gt 0 ]; then
    echo "tests: $passed passed, $failed failed, $skipped skipped"
else
    echo "tests: $passed passed, $failed failed"
fi
[ $failed = 0 ] || status=1
exit $status
