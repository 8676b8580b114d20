#!/usr/bin/env bash
# Runs every Check suite and fuzz target given on the command line, then
# prints one closing line adding up the Check counts: "tests: N passed, M failed"
# (then ", K skipped" when K > 0 tests printed a line starting with "SKIPPED:").
# Usage: tests/run-suites.sh SUITE... [-- FUZZ[:N]...]; a fuzz target runs its
# corpus and N mutations (20000 if not given). A SUITE written PATH:CASE runs
# only that Check case (CK_RUN_CASE takes one name, so a subset is one
# argument per case). The environment (VB_*) comes from the Makefile. Exits
# non-zero if anything failed.
set -u
passed=0
failed=0
skipped=0
status=0
fuzz=0
for t in "$@"; do
    if [ "$t" = "--" ]; then fuzz=1; continue; fi
    if [ $fuzz = 1 ]; then
        n=20000
        case $t in *:*) n=${t##*:}; t=${t%:*} ;; esac
        echo "== $t (corpus + $n mutations)"
        if "$t" tests/data/fuzz "$n"; then passed=$((passed + 1)); else failed=$((failed + 1)); status=1; fi
        continue
    fi
    ck_case=""
    case "$t" in *:*) ck_case=${t#*:}; t=${t%%:*} ;; esac
    if [ -n "$ck_case" ]; then
        echo "== $t ($ck_case)"
        out=$(CK_RUN_CASE="$ck_case" "$t" 2>&1); rc=$?
    else
        echo "== $t"
        out=$("$t" 2>&1); rc=$?
    fi
    printf '%s\n' "$out"
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
done
if [ $skipped -gt 0 ]; then
    echo "tests: $passed passed, $failed failed, $skipped skipped"
else
    echo "tests: $passed passed, $failed failed"
fi
[ $failed = 0 ] || status=1
exit $status
