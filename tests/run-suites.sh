#!/usr/bin/env bash
# Runs every Check suite and fuzz target given on the command line, then
# prints one closing line adding up the Check counts: "tests: N passed, M failed"
# (then ", K skipped" when K > 0 tests printed a line starting with "SKIPPED:").
# Usage: tests/run-suites.sh [-j N] SUITE... [-- FUZZ[:N]...]; a fuzz target
# runs its corpus and N mutations (20000 if not given). A SUITE written
# PATH:CASE runs only that Check case (CK_RUN_CASE takes one name, so a
# subset is one argument per case); PATH:* runs every case that `PATH --list`
# prints, each in a process of its own. With -j N, N of them run at once
# (the tests wait for events, not for times, so a loaded host only makes
# them slower); each one's output is printed whole, in the order given. The
# environment (VB_*) comes from the Makefile. Exits non-zero if anything
# failed. Each one's wall time is printed after it ("-- SUITE: N s", with
# its slowest Check cases from Check's XML log) and once more, all
# together, at the end (docs/TESTING.md keeps a table of them).
set -u
jobs=1
if [ "${1:-}" = -j ]; then
    jobs=$2
    shift 2
fi
work=$(mktemp -d "${TMPDIR:-/tmp}/run-suites.XXXXXX")
trap 'rm -rf "$work"' EXIT
passed=0
failed=0
skipped=0
status=0
times=""
failed_names=""
failure_lines=""
start_all=$(date +%s.%N)
# Seconds since $1 (date +%s.%N), to a tenth.
since() { awk -v a="$1" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }'; }

# The items to run: a kind (check or fuzz), a path, and a Check case ("":
# the whole suite) or a number of mutations.
kinds=()
paths=()
args=()
fuzz=0
for t in "$@"; do
    if [ "$t" = "--" ]; then fuzz=1; continue; fi
    if [ $fuzz = 1 ]; then
        n=20000
        case $t in *:*) n=${t##*:}; t=${t%:*} ;; esac
        kinds+=(fuzz); paths+=("$t"); args+=("$n")
        continue
    fi
    case "$t" in
        *:\*)
            p=${t%:\*}
            # (a suite without --list runs instead: its lines are not names)
            if ! list=$("$p" --list 2>&1) || [ -z "$list" ] ||
                printf '%s\n' "$list" | grep -qv '^[A-Za-z_][A-Za-z0-9_]*$'; then
                echo "$p: cannot list its cases (--list)"
                failed=$((failed + 1))
                continue
            fi
            for c in $list; do kinds+=(check); paths+=("$p"); args+=("$c"); done ;;
        *:*) kinds+=(check); paths+=("${t%%:*}"); args+=("${t#*:}") ;;
        *) kinds+=(check); paths+=("$t"); args+=("") ;;
    esac
done
count=${#kinds[@]}

# Runs item $1 into $work/$1.*; the .rc file, written last, marks it done.
run_item() {
    local i=$1 t0 rc
    t0=$(date +%s.%N)
    if [ "${kinds[i]}" = fuzz ]; then
        "${paths[i]}" tests/data/fuzz "${args[i]}" >"$work/$i.out" 2>&1
    elif [ -n "${args[i]}" ]; then
        CK_XML_LOG_FILE_NAME="$work/$i.xml" CK_RUN_CASE="${args[i]}" "${paths[i]}" \
            >"$work/$i.out" 2>&1
    else
        CK_XML_LOG_FILE_NAME="$work/$i.xml" "${paths[i]}" >"$work/$i.out" 2>&1
    fi
    rc=$?
    since "$t0" >"$work/$i.s"
    echo $rc >"$work/$i.rc.tmp" && mv "$work/$i.rc.tmp" "$work/$i.rc"
}

# Prints item $1 (done) and adds up its counts.
report_item() {
    local i=$1 t=${paths[$1]} c=${args[$1]} rc out s name slow line n f e k failed0
    rc=$(cat "$work/$i.rc")
    out=$(cat "$work/$i.out")
    s=$(cat "$work/$i.s")
    if [ "${kinds[i]}" = fuzz ]; then
        echo "== $t (corpus + $c mutations)"
        printf '%s\n' "$out"
        name=${t##*/}
        if [ "$rc" = 0 ]; then passed=$((passed + 1)); else failed=$((failed + 1)); status=1; failed_names="$failed_names $name"; fi
    else
        failed0=$failed
        if [ -n "$c" ]; then echo "== $t ($c)"; else echo "== $t"; fi
        printf '%s\n' "$out"
        slow=$(awk -F'[<>]' '/<id>/ { id = $3 } /<duration>/ && id != "" { printf "%s %s\n", $3, id; id = "" }' \
            "$work/$i.xml" 2>/dev/null |
            sort -rn | head -n 5 | awk '$1 >= 1 { printf "%s%s %.1f s", sep, $2, $1; sep = ", " }')
        [ -z "$slow" ] || [ -n "$c" ] || echo "-- slowest cases: $slow"
        k=$(printf '%s\n' "$out" | grep -c '^SKIPPED:')
        skipped=$((skipped + k))
        line=$(printf '%s\n' "$out" | grep -E 'Checks: [0-9]+, Failures: [0-9]+, Errors: [0-9]+' | tail -n 1)
        if [ -n "$line" ]; then
            n=$(echo "$line" | sed -E 's/.*Checks: ([0-9]+).*/\1/')
            f=$(echo "$line" | sed -E 's/.*Failures: ([0-9]+).*/\1/')
            e=$(echo "$line" | sed -E 's/.*Errors: ([0-9]+).*/\1/')
            passed=$((passed + n - f - e))
            failed=$((failed + f + e))
            if [ -n "$c" ] && [ "$n" = 0 ]; then
                # a renamed case would otherwise be skipped without a word
                echo "$t: no Check case named '$c'"
                failed=$((failed + 1))
            fi
        else
            echo "$t: no Check summary (crashed?)"
            failed=$((failed + 1))
        fi
        name=${t##*/}${c:+:$c}
        [ "$rc" = 0 ] || status=1
        if [ "$rc" != 0 ] || [ "$failed" != "$failed0" ]; then
            failed_names="$failed_names $name"
            failure_lines="$failure_lines$(printf '%s\n' "$out" | grep -E ':[0-9]+:[FE]:' | head -n 3)\n"
        fi
    fi
    echo "-- $name: $s s"
    times="$times$name $s\n"
}

# Starts the items, at most $jobs at once, and prints each (in order) as
# soon as it and those before it are done.
next=0
report_ready() {
    while [ $next -lt "$count" ] && [ -e "$work/$next.rc" ]; do
        report_item $next
        next=$((next + 1))
    done
}
for ((i = 0; i < count; i++)); do
    while [ "$(jobs -rp | wc -l)" -ge "$jobs" ]; do
        wait -n
        report_ready
    done
    run_item "$i" &
done
wait
report_ready

echo "seconds per suite:"
printf '%b' "$times" | awk '{ printf "  %-36s %7s\n", $1, $2 }'
echo "all suites: $(since "$start_all") s ($jobs at a time)"
if [ $skipped -gt 0 ]; then
    echo "tests: $passed passed, $failed failed, $skipped skipped"
else
    echo "tests: $passed passed, $failed failed"
fi
# (CI shows only the tail of the output: name what failed here, so that the
# failure's own lines, printed above, can be found)
if [ -n "$failed_names" ]; then
    printf '%b' "$failure_lines" | grep -v '^$'
    echo "failed:$failed_names"
fi
[ $failed = 0 ] || status=1
exit $status
