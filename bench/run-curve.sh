#!/usr/bin/env bash
# run-curve.sh - what CURVE costs the master: build/bench/bench_master over
# loopback tcp without keys, with --curve, and with --curve and more I/O
# threads in the master's context, in rounds of the three (so drifting load
# from other processes hits all alike), written to bench/results/curve.json
# with the per-run figures and the medians.
#
# The synthetic workers get a ZeroMQ context of their own
# (--worker-context own), as remote workers would: the master's I/O thread
# then does the master's half of the crypto only. Reported per pixel-layer
# result: the master thread's CPU (the event loop, with the per-message key
# check), the master's I/O thread's CPU (where ZeroMQ encrypts and
# decrypts; the busiest one when there are several) and the whole
# process's, and results per second end to end. On a host with a core to
# spare for each thread, the master's capacity is bounded by its busiest
# thread: that bound is reported too.
#
# Knobs (environment): BENCH_CURVE_PAIRS (5 rounds), BENCH_CURVE_WORKERS (4),
# BENCH_CURVE_IO_THREADS (3: the third configuration's),
# BENCH_CURVE_SIZE (1024), BENCH_CURVE_SPP (1024), BENCH_CURVE_PORT (17900:
# first port tried; busy ones are skipped).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"

PAIRS="${BENCH_CURVE_PAIRS:-5}"
WORKERS="${BENCH_CURVE_WORKERS:-4}"
IO_THREADS="${BENCH_CURVE_IO_THREADS:-3}"
SIZE="${BENCH_CURVE_SIZE:-1024}"
SPP="${BENCH_CURVE_SPP:-1024}"
PORT="${BENCH_CURVE_PORT:-17900}"
OUT=build/bench/out-curve
RESULTS=bench/results

BM=build/bench/bench_master
if [ ! -x "$BM" ]; then
    echo "run-curve.sh: $BM is missing (run 'make build/bench/bench_master')" >&2
    exit 1
fi
mkdir -p "$OUT" "$RESULTS"
rm -f "$OUT"/*.json
cp "$BM" "$OUT/bench_master" # a rebuild meanwhile cannot mix versions
BM=$OUT/bench_master

port_free() {
    ! (exec 3<>"/dev/tcp/127.0.0.1/$1") 2>/dev/null
}

load_before=$(cut -d' ' -f1-3 /proc/loadavg)
start=$(date +%s.%N)
for i in $(seq 1 "$PAIRS"); do
    for mode in off on on-io; do
        while ! port_free "$PORT" || ! port_free $((PORT + 1)); do PORT=$((PORT + 2)); done
        flag=""
        [ "$mode" = on ] && flag="--curve"
        [ "$mode" = on-io ] && flag="--curve --io-threads $IO_THREADS"
        echo "== round $i, CURVE $mode" >&2
        "$BM" --transport tcp --port "$PORT" --workers "$WORKERS" --size "$SIZE" --spp "$SPP" \
            --granularity 32 --worker-context own $flag --json "$OUT/curve-$mode-$i.json" >/dev/null
        PORT=$((PORT + 2))
    done
done
end=$(date +%s.%N)
commit=$(git rev-parse --short HEAD 2>/dev/null || echo unknown)

python3 - "$OUT" "$RESULTS/curve.json" "$start" "$end" "$commit" "$load_before" <<'PY'
import glob, json, os, platform, statistics, sys, time
out, path, start, end, commit, load_before = sys.argv[1:7]

def cpu_model():
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"

runs = {"off": [], "on": [], "on-io": []}
for mode in runs:
    for f in sorted(glob.glob(os.path.join(out, f"curve-{mode}-[0-9]*.json"))):
        with open(f) as fh:
            runs[mode].append(json.load(fh))

keys = ["results_per_second", "master_ns_per_result", "master_io_ns_per_result",
        "master_io_busiest_ns_per_result", "process_ns_per_result", "master_cpu_utilization",
        "wire_megabytes_per_second"]
median = {m: {k: statistics.median(r[k] for r in runs[m]) for k in keys} for m in runs}
off = median["off"]

def change(m, k):
    return (median[m][k] - off[k]) / off[k] if off[k] else None

# A master host with a spare core for each thread is bounded by its
# busiest thread: the event loop or an I/O thread.
def capacity(m):
    return 1e9 / max(m["master_ns_per_result"], m["master_io_busiest_ns_per_result"])

doc = {
    "benchmark": "curve",
    "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    "commit": commit,
    "machine": {"cpu": cpu_model(), "cores": os.cpu_count(), "kernel": platform.release(),
                "loadavg_before": load_before, "loadavg_after": " ".join(open("/proc/loadavg").read().split()[:3])},
    "settings": {"transport": "tcp over loopback", "worker_context": "own", "workers": runs["off"][0]["workers"],
                 "width": runs["off"][0]["width"], "spp": runs["off"][0]["spp"], "granularity": 32,
                 "rounds": len(runs["on"]), "io_threads_on_io": runs["on-io"][0]["master_io_threads"]},
    "bench_seconds": float(end) - float(start),
    "median": median,
    "change_vs_off": {m: {k: change(m, k) for k in keys} for m in ("on", "on-io")},
    "capacity_results_per_second_bound_by_busiest_master_thread": {
        m: {"value": capacity(median[m]), "change_vs_off": capacity(median[m]) / capacity(off) - 1} for m in runs},
    "runs": runs,
}
with open(path, "w") as fh:
    json.dump(doc, fh, indent=2)
    fh.write("\n")
def pct(c):
    return "" if c is None else f"{100 * c:+.1f} %"

io = doc["settings"]["io_threads_on_io"]
print(f"CURVE off / on / on with {io} I/O threads (medians of {len(runs['on'])} rounds, "
      f"{doc['settings']['workers']} synthetic workers, {os.cpu_count()} cores):")
for k in keys:
    print(f"  {k:32s} {off[k]:11.4g} {median['on'][k]:11.4g} {pct(change('on', k)):>9s} "
          f"{median['on-io'][k]:11.4g} {pct(change('on-io', k)):>9s}")
cap = doc["capacity_results_per_second_bound_by_busiest_master_thread"]
print(f"  {'busiest-master-thread bound':32s} {cap['off']['value']:11.4g} {cap['on']['value']:11.4g} "
      f"{pct(cap['on']['change_vs_off']):>9s} {cap['on-io']['value']:11.4g} {pct(cap['on-io']['change_vs_off']):>9s}")
print(f"wrote {path}")
PY
