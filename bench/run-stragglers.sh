#!/usr/bin/env bash
# run-stragglers.sh - what a misbehaving worker costs a job, written to
# bench/results/stragglers.json with tables on stdout.
#
# Real daemons on loopback, as a user runs them (the master's defaults but
# --state none): one honest worker renders the Cornell box alone; then the
# same job runs beside a second worker of each kind (the fault build,
# build/tests/vbrender-worker-fault):
#   hoarder    takes tasks, heartbeats, never answers (VB_FAULT_HOARD)
#   malformed  every RESULT has a record of 0 rays (VB_FAULT_MALFORMED)
#   slow10     each task takes 10x its trace time (VB_FAULT_SLOW=10)
#   killed     an honest worker, kill -9'd once the job passes 30 % of its layers
#   honest     an honest worker (the fault-free pair: what backups cost there)
# For each: the job's seconds (the master's clock) against the honest
# worker alone, the backups issued and won, the tasks issued again, and
# whether the image equals the honest worker's alone (vbrender compare:
# RMSE and max 0).
#
# Then the choice of --backup-factor: the slow10, hoarder and honest pairs
# at factors 0 (no backups), 1.5, 2, 3, 4 and 6 (in the honest pair every
# backup that did not answer first is work thrown away).
#
# Each figure is the median of BENCH_STRAGGLERS_REPEATS runs (3). Knobs
# (environment): BENCH_STRAGGLERS_SPP (128), BENCH_STRAGGLERS_FACTORS
# ("0 1.5 2 3 4 6"), BENCH_STRAGGLERS_PORT (18110).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
SPP="${BENCH_STRAGGLERS_SPP:-128}"
REPEATS="${BENCH_STRAGGLERS_REPEATS:-3}"
FACTORS="${BENCH_STRAGGLERS_FACTORS:-0 1.5 2 3 4 6}"
PORT="${BENCH_STRAGGLERS_PORT:-18110}"
OUT=build/bench/out-stragglers
RESULTS=bench/results
VB=bin/vbrender
VBM=bin/vbrender-master
VBW=bin/vbrender-worker
CTL=build/bench/bench_ctl
FAULT=build/tests/vbrender-worker-fault
SCENE=scenes/cornell-box.json
SETTINGS="--spp $SPP --granularity 16 --seed 5"

for b in "$VB" "$VBM" "$VBW" "$CTL" "$FAULT"; do
    [ -x "$b" ] || { echo "run-stragglers.sh: $b is missing (make all $CTL $FAULT)" >&2; exit 1; }
done
mkdir -p "$OUT" "$RESULTS"
rm -f "$OUT"/*
# shellcheck source=bench/lib.sh
. bench/lib.sh

json_field() { python3 -c 'import json,sys; print(json.load(sys.stdin)[sys.argv[1]])' "$1"; }

# run TAG KIND FACTOR: one master, the honest worker, the second worker of
# KIND ("" for none), one job; OUT/TAG.json holds its status and the
# comparison with OUT/alone.exr (when that exists).
run() {
    local tag=$1 kind=$2 factor=$3 env=() n=1 victim=""
    next_ports
    start_master "$OUT/$tag-master.log" --state none --backup-factor "$factor"
    "$VBW" --master "tcp://127.0.0.2:0;${WEP#tcp://}" --threads 1 --name honest 2>"$OUT/$tag-honest.log" &
    PIDS+=($!)
    case $kind in
    hoarder) env=(VB_FAULT_HOARD=1) ;;
    malformed) env=(VB_FAULT_MALFORMED=1) ;;
    slow10) env=(VB_FAULT_SLOW=10) ;;
    killed | honest) env=(VB_FAULT_NONE=1) ;;
    esac
    if [ -n "$kind" ]; then
        env "${env[@]}" "$FAULT" --master "tcp://127.0.0.3:0;${WEP#tcp://}" --threads 1 \
            --name "$kind" 2>"$OUT/$tag-fault.log" &
        victim=$!
        PIDS+=("$victim")
        n=2
    fi
    "$CTL" "$CEP" wait-workers "$n" 20 >/dev/null
    local job
    job=$("$VB" submit "$SCENE" $SETTINGS --master "$CEP" | tail -n 1)
    if [ "$kind" = killed ]; then # kill -9 once 30 % of the layers are done
        local layers done_=0
        layers=$("$CTL" "$CEP" status "$job" | json_field layers)
        while [ $((done_ * 10)) -lt $((layers * 3)) ]; do
            sleep 0.02
            done_=$("$CTL" "$CEP" status "$job" | json_field layers_done)
        done
        kill -9 "$victim"
    fi
    "$CTL" "$CEP" wait "$job" 600 >"$OUT/$tag-status.json"
    "$VB" fetch "$job" -o "$OUT/$tag.exr" --master "$CEP" >/dev/null
    local same=null
    if [ -e "$OUT/alone.exr" ] && [ "$tag" != alone ]; then
        if "$VB" compare "$OUT/$tag.exr" "$OUT/alone.exr" | grep -q '^max 0$'; then same=true; else same=false; fi
    fi
    python3 - "$OUT/$tag-status.json" "$tag" "$kind" "$factor" "$same" >"$OUT/$tag.json" <<'PY'
import json, sys
st = json.load(open(sys.argv[1]))
print(json.dumps({"tag": sys.argv[2], "kind": sys.argv[3] or "alone", "backup_factor": float(sys.argv[4]),
                  "seconds": st["seconds"], "backups": st["backups"], "backups_won": st["backups_won"],
                  "tasks_reissued": st["tasks_reissued"], "late_results": st["late_results"],
                  "task_seconds": st["task_seconds"], "same_image": json.loads(sys.argv[5]),
                  "state": st["state"]}))
PY
    { cleanup; wait; } 2>/dev/null || true # bash would report each kill
    PIDS=()
}

echo "run-stragglers.sh: the honest worker alone ($SETTINGS)" >&2
run alone "" 3
for r in $(seq 1 "$REPEATS"); do
    run "alone-r$r" "" 3
    for kind in hoarder malformed slow10 killed honest; do
        echo "run-stragglers.sh: beside a $kind worker, run $r" >&2
        run "$kind-r$r" "$kind" 3
    done
    for f in $FACTORS; do
        for kind in slow10 hoarder honest; do
            echo "run-stragglers.sh: $kind pair, --backup-factor $f, run $r" >&2
            run "$kind-f$f-r$r" "$kind" "$f"
        done
    done
done

python3 - "$OUT" "$RESULTS/stragglers.json" "$REPEATS" "$FACTORS" "$SETTINGS" <<'PY'
import json, statistics, sys
sys.path.insert(0, "bench")
from results_page import result_meta
out, dest, repeats, factors, settings = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4].split(), sys.argv[5]
def runs(tag):
    return [json.load(open("%s/%s-r%d.json" % (out, tag, r))) for r in range(1, repeats + 1)]
def med(rs, key):
    return statistics.median(r[key] for r in rs)
alone = med(runs("alone"), "seconds")
res = dict(result_meta("stragglers"), scene="scenes/cornell-box.json", settings=settings,
           repeats=repeats, alone_seconds=alone, kinds=[], factors=[])
print("Beside one honest worker (1 thread each), --backup-factor 3; medians of %d runs; the honest worker alone: %.2f s" % (repeats, alone))
print()
print("| second worker | job s | vs alone | backups (won) | tasks issued again | image identical |")
print("|---|--:|--:|--:|--:|--|")
for kind in ["hoarder", "malformed", "slow10", "killed", "honest"]:
    rs = runs(kind)
    s = med(rs, "seconds")
    row = {"kind": kind, "seconds": s, "vs_alone": s / alone, "backups": med(rs, "backups"),
           "backups_won": med(rs, "backups_won"), "tasks_reissued": med(rs, "tasks_reissued"),
           "same_image": all(r["same_image"] for r in rs), "all_seconds": [r["seconds"] for r in rs]}
    res["kinds"].append(row)
    print("| %s | %.2f | %.2fx | %.0f (%.0f) | %.0f | %s |" % (kind, s, s / alone, row["backups"],
          row["backups_won"], row["tasks_reissued"], "yes" if row["same_image"] else "NO"))
print()
print("Choosing --backup-factor: job seconds (and vs alone) beside a 10x slow worker, a hoarder and an honest one")
print()
print("| factor | slow10 s | backups (won) | hoarder s | backups (won) | honest pair s | backups (won) | images identical |")
print("|--:|--:|--:|--:|--:|--:|--:|--|")
for f in factors:
    row = {"backup_factor": float(f)}
    cells = []
    rs_all = []
    for kind in ["slow10", "hoarder", "honest"]:
        rs = runs("%s-f%s" % (kind, f))
        rs_all += rs
        row.update({kind + "_seconds": med(rs, "seconds"), kind + "_backups": med(rs, "backups"),
                    kind + "_backups_won": med(rs, "backups_won")})
        cells.append("%.2f (%.2fx) | %.0f (%.0f)" % (row[kind + "_seconds"], row[kind + "_seconds"] / alone,
                                                    row[kind + "_backups"], row[kind + "_backups_won"]))
    row["same_image"] = all(r["same_image"] for r in rs_all)
    res["factors"].append(row)
    print("| %s | %s | %s |" % (f if float(f) > 0 else "0 (off)", " | ".join(cells),
                                "yes" if row["same_image"] else "NO"))
json.dump(res, open(dest, "w"), indent=1)
print()
print("written: %s" % dest)
PY
