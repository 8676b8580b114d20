#!/usr/bin/env bash
# run-verify.sh - what verification by replication costs the master
# (vbrender-master --verify-share), written to bench/results/verify.json
# with a table on stdout.
#
# build/bench/bench_master runs a real master and synthetic workers that
# answer every task at once (their results are a pure function of the task,
# so two copies agree), over loopback tcp, each synthetic worker from its
# own address (copies go to workers of another identity). For each share
# (0, 0.01, 1) and worker count, BENCH_VERIFY_REPEATS runs; the run with the
# median results per master CPU second is kept. "results" are pixel-layer
# results merged into the film; with share 1 the workers send twice as many.
#
# Knobs (environment): BENCH_VERIFY_SHARES ("0 0.01 1"), BENCH_VERIFY_WORKERS
# ("2 4"), BENCH_VERIFY_REPEATS (3), BENCH_VERIFY_SIZE (1024),
# BENCH_VERIFY_SPP (1024), BENCH_VERIFY_PORT (17990).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
SHARES="${BENCH_VERIFY_SHARES:-0 0.01 1}"
WORKERS="${BENCH_VERIFY_WORKERS:-2 4}"
REPEATS="${BENCH_VERIFY_REPEATS:-3}"
SIZE="${BENCH_VERIFY_SIZE:-1024}"
SPP="${BENCH_VERIFY_SPP:-1024}"
PORT="${BENCH_VERIFY_PORT:-17990}"
OUT=build/bench/out-verify
RESULTS=bench/results
BM=build/bench/bench_master

if [ ! -x "$BM" ]; then
    echo "run-verify.sh: $BM is missing (run 'make $BM')" >&2
    exit 1
fi
mkdir -p "$OUT" "$RESULTS"
rm -f "$OUT"/*.json
for k in $WORKERS; do
    for p in $SHARES; do
        for r in $(seq 1 "$REPEATS"); do
            echo "bench_master: $k workers, share $p, run $r" >&2
            "$BM" --transport tcp --port "$PORT" --workers "$k" --size "$SIZE" --spp "$SPP" \
                --verify-share "$p" --json "$OUT/w$k-p$p-r$r.json" >/dev/null
        done
    done
done

python3 - "$OUT" "$RESULTS/verify.json" "$SHARES" "$WORKERS" "$REPEATS" <<'PY'
import json, sys
sys.path.insert(0, "bench")
from results_page import result_meta
out, dest = sys.argv[1], sys.argv[2]
shares, workers, repeats = sys.argv[3].split(), sys.argv[4].split(), int(sys.argv[5])
res = dict(result_meta("verify"), transport="tcp", repeats=repeats, runs=[])
print("| workers | share | merged results/s | results per master CPU s | vs share 0 | results sent | tasks verified | unverified | mismatches | master CPU use |")
print("|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|")
for k in workers:
    base = None
    for p in shares:
        runs = [json.load(open("%s/w%s-p%s-r%d.json" % (out, k, p, r))) for r in range(1, repeats + 1)]
        runs.sort(key=lambda d: d["results_per_master_cpu_second"])
        d = runs[len(runs) // 2]
        d["all_results_per_master_cpu_second"] = [x["results_per_master_cpu_second"] for x in runs]
        if base is None:
            base = d["results_per_master_cpu_second"]
        d["vs_share_0"] = d["results_per_master_cpu_second"] / base
        res["runs"].append(d)
        print("| %s | %s | %.3g | %.3g | %.2f | %.3g | %d | %d | %d | %.0f %% |" % (
            k, p, d["results_per_second"], d["results_per_master_cpu_second"], d["vs_share_0"],
            d["results_sent_by_workers"], d["tasks_verified"], d["tasks_unverified"], d["verify_mismatches"],
            100 * d["master_cpu_utilization"]))
json.dump(res, open(dest, "w"), indent=1)
print("\nwritten to " + dest)
PY
