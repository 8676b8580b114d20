#!/usr/bin/env bash
# run-durable.sh - what a durable master costs (vbrender-master --state),
# written to bench/results/durable.json, with a table on stdout.
#
#   1. Checkpoint overhead: the Cornell box at 256x256 and 1920x1080, uniform,
#      2 workers x 1 thread, a fixed time (--time-limit), once with --state none
#      and once with a state directory at the default checkpoint interval
#      (10 s). Throughput (samples/s) of each, and the checkpoints' own cost as
#      the master reports it: the fork (the only time the event loop waits)
#      and the writer child's CPU seconds, as a share of the cores' time.
#   2. Restart to busy: kill -9 of the master mid-job, restart with the same
#      flags; seconds until the job's sample count grows again.
#   3. Master memory against ended jobs: 10, 100 and 1000 small jobs, with
#      a state directory (images on disk) and with --state none (in memory).
#   4. Production resolutions: a running job's bytes a pixel, array by array
#      (build/bench/bench_memory, bench/results/memory.json); then the Cornell
#      box at 256x256, 1920x1080 and 3840x2160, 65,536 spp (2,048 layers),
#      the default sampler, 2 workers x 1 thread, the default checkpoint
#      interval, for BENCH_DUR_LIFE_S seconds each: every second the
#      master's RSS, the state directory's size and the bytes it has written
#      (journal and snapshots) against the results it has merged, on past the
#      job's first compaction (at most BENCH_DUR_LIFE_MAX_S, 900); the
#      checkpoint work's CPU (the writer's and the compactions'); at 4K an
#      A/B of the master's CPU with --state none, and a kill -9 and restart:
#      seconds until the job runs again.
#
# Knobs (environment): BENCH_DUR_SECONDS (25: time limit of each run in 1),
# BENCH_DUR_JOBS ("10 100 1000"), BENCH_DUR_LIFE_S (90: each run of 4),
# BENCH_DUR_PORT (18800).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
SECONDS_RUN="${BENCH_DUR_SECONDS:-25}"
JOBS="${BENCH_DUR_JOBS:-10 100 1000}"
LIFE="${BENCH_DUR_LIFE_S:-90}"
LIFE_MAX="${BENCH_DUR_LIFE_MAX_S:-900}"
PORT="${BENCH_DUR_PORT:-18800}"
OUT=build/bench/out-durable
RESULTS=bench/results
CORES=$(nproc)
VB=bin/vbrender
VBM=bin/vbrender-master
VBW=bin/vbrender-worker
CTL=build/bench/bench_ctl
MEMB=build/bench/bench_memory
for b in $VB $VBM $VBW $CTL $MEMB; do
    [ -x "$b" ] || { echo "run-durable.sh: $b is missing (make all build/bench/bench_ctl build/bench/bench_memory)" >&2; exit 1; }
done
rm -rf "$OUT"
mkdir -p "$OUT" "$RESULTS"
# shellcheck source=bench/lib.sh
. bench/lib.sh
rss_kib() { awk '/^VmRSS:/ { print $2 }' "/proc/$1/status"; }
samples_of() { "$CTL" "$CEP" status "$1" | python3 -c 'import json,sys; print(json.load(sys.stdin)["samples"])'; }
# restart_to_busy ID OUTFILE MASTER_ARGS...: kill -9 the master, start it
# again with the same arguments; writes "t0 t1 t2 s0": the restart, its
# first answer, the job's samples growing again, and where it resumed
restart_to_busy() {
    local id=$1 out=$2 t0 t1 s0 s
    shift 2
    kill -9 "$MPID"
    wait "$MPID" 2>/dev/null || true
    t0=$(date +%s.%N)
    start_master "$@"
    t1=$(date +%s.%N)
    s0=$(samples_of "$id")
    while :; do
        s=$(samples_of "$id")
        if python3 -c "import sys; sys.exit(0 if float('$s') > float('$s0') else 1)"; then break; fi
        sleep 0.02
    done
    echo "$t0 $t1 $(date +%s.%N) $s0" >"$out"
}
jget() { python3 -c 'import json,sys; d=json.load(open(sys.argv[1])); print(eval(sys.argv[2]))' "$@"; }
scene_of() { # scene_of W H FILE
    python3 - "$1" "$2" "$3" <<'PY'
import sys, re
w, h, out = sys.argv[1:4]
t = open("scenes/cornell-box.json").read()
t = t.replace('"width": 256, "height": 256', '"width": %s, "height": %s' % (w, h))
open(out, "w").write(t)
PY
}

# ---- 1. checkpoint overhead ------------------------------------------------------
declare -A SPP=([256x256]=4096 [1920x1080]=64)
for size in 256x256 1920x1080; do
    w=${size%x*}
    h=${size#*x}
    scene_of "$w" "$h" "$OUT/cornell-$size.json"
    for mode in none state; do
        tag="ckpt-$size-$mode"
        next_ports
        if [ $mode = none ]; then
            start_master "$OUT/$tag.log" --state none
        else
            start_master "$OUT/$tag.log" --state "$OUT/state-$size"
        fi
        start_workers 2
        id=$("$VB" submit "$OUT/cornell-$size.json" --spp "${SPP[$size]}" --adaptive none \
            --time-limit "$SECONDS_RUN" --master "$CEP" | tail -n 1)
        ckpt_bytes=0
        if [ $mode = state ]; then
            # one checkpoint file as written mid-run (the job's end removes it)
            sleep 12
            ckpt_bytes=$(stat -c %s "$OUT/state-$size/jobs/$id/checkpoint" 2>/dev/null || echo 0)
        fi
        "$CTL" "$CEP" wait "$id" 600 >"$OUT/$tag.status.json"
        "$CTL" "$CEP" workers >"$OUT/$tag.workers.json"
        echo "$ckpt_bytes" >"$OUT/$tag.bytes"
        stop_all "$MPID" "${WPIDS[@]}"
        echo "  $tag: $(jget "$OUT/$tag.status.json" 'round(d["samples_per_second"])') samples/s" >&2
    done
done

# ---- 2. restart to busy ------------------------------------------------------------
next_ports
start_master "$OUT/restart.log" --state "$OUT/state-restart" --checkpoint-s 1
start_workers 2
id=$("$VB" submit "$OUT/cornell-256x256.json" --spp 8192 --adaptive none --master "$CEP" | tail -n 1)
sleep 5
restart_to_busy "$id" "$OUT/restart.times" "$OUT/restart.log" --state "$OUT/state-restart" --checkpoint-s 1
"$VB" cancel "$id" --master "$CEP" >/dev/null
stop_all "$MPID" "${WPIDS[@]}"

# ---- 3. memory against ended jobs --------------------------------------------------
scene_of 16 16 "$OUT/tiny.json"
for mode in state none; do
    next_ports
    if [ $mode = none ]; then
        start_master "$OUT/mem-$mode.log" --state none --keep-finished 100000 --max-queued-per-client 100000
    else
        start_master "$OUT/mem-$mode.log" --state "$OUT/state-mem" --keep-finished 100000 --max-queued-per-client 100000
    fi
    start_workers 1
    done_jobs=0
    : >"$OUT/mem-$mode.txt"
    for target in $JOBS; do
        # one at a time, as jobs come and go on a long-running master: the
        # question is what an ended job leaves behind
        while [ "$done_jobs" -lt "$target" ]; do
            id=$("$VB" submit "$OUT/tiny.json" --spp 64 --master "$CEP" | tail -n 1)
            "$CTL" "$CEP" wait "$id" 600 >/dev/null
            done_jobs=$((done_jobs + 1))
        done
        sleep 1.5 # the last image reaches the disk and leaves memory
        echo "$target $(rss_kib "$MPID")" >>"$OUT/mem-$mode.txt"
        echo "  memory $mode: $target jobs, $(rss_kib "$MPID") KiB" >&2
    done
    stop_all "$MPID" "${WPIDS[@]}"
done

# ---- 4. production resolutions --------------------------------------------------
echo "== memory a pixel (bench_memory)" >&2
"$MEMB" --json "$RESULTS/memory.json" | tee "$OUT/memory.md"
cpu_s() { awk '{ print ($14 + $15) / 100 }' "/proc/$1/stat"; }
# one line a second: t, RSS KiB, state bytes, master CPU s, the master's counters
sample_run() { # sample_run TAG STATE_DIR|none ID SECONDS [COMPACTIONS MAX_SECONDS]
    # SECONDS at least; with COMPACTIONS, on until that many snapshots are written (MAX_SECONDS at most)
    local tag=$1 dir=$2 id=$3 secs=$4 want=${5:-0} most=${6:-0} t0 now snaps=0
    t0=$(date +%s.%N)
    : >"$OUT/$tag.samples"
    while :; do
        now=$(date +%s.%N)
        if python3 -c "import sys; t = $now - $t0; sys.exit(0 if t >= $secs and ($snaps >= $want or t >= $most) else 1)"; then break; fi
        local bytes=0
        [ "$dir" != none ] && bytes=$(du -sb "$dir" | cut -f1)
        printf '%s %s %s %s ' "$(python3 -c "print($now - $t0)")" "$(rss_kib "$MPID")" "$bytes" \
            "$(cpu_s "$MPID")" >>"$OUT/$tag.samples"
        "$CTL" "$CEP" workers | python3 -c 'import json,sys; print(json.dumps(json.load(sys.stdin)["master"]))' >>"$OUT/$tag.samples"
        snaps=$(tail -n 1 "$OUT/$tag.samples" | cut -d' ' -f5- | python3 -c 'import json,sys; print(int(json.load(sys.stdin).get("snapshots_written", 0)))')
        sleep 1
    done
    "$CTL" "$CEP" status "$id" >"$OUT/$tag.status.json"
}
for size in 256x256 1920x1080 3840x2160; do
    w=${size%x*}
    h=${size#*x}
    scene_of "$w" "$h" "$OUT/cornell-$size.json"
    modes="state"
    [ "$size" = 3840x2160 ] && modes="state none"
    for mode in $modes; do
        tag="prod-$size-$mode"
        echo "== $tag: $LIFE s" >&2
        next_ports
        dir=none
        [ $mode = state ] && dir="$OUT/state-prod-$size"
        start_master "$OUT/$tag.log" --state "$dir"
        start_workers 2
        id=$("$VB" submit "$OUT/cornell-$size.json" --spp 65536 --master "$CEP" | tail -n 1)
        if [ $mode = state ]; then
            # on past the job's first compaction, to see one at every size
            sample_run "$tag" "$dir" "$id" "$LIFE" 1 "$LIFE_MAX"
        else
            sample_run "$tag" "$dir" "$id" "$LIFE"
        fi
        if [ "$size" = 3840x2160 ] && [ $mode = state ]; then
            # restart: kill -9, start again, seconds until the job's samples grow
            restart_to_busy "$id" "$OUT/$tag.restart.times" "$OUT/$tag.restart.log" --state "$dir"
        fi
        "$VB" cancel "$id" --master "$CEP" >/dev/null || true
        stop_all "$MPID" "${WPIDS[@]}"
    done
done

python3 - "$OUT" "$RESULTS/durable.json" "$SECONDS_RUN" "$CORES" "$LIFE" <<'PY'
import json, sys
out, dest, secs, cores, life = sys.argv[1], sys.argv[2], float(sys.argv[3]), int(sys.argv[4]), float(sys.argv[5])
res = {"cores": cores, "time_limit_s": secs, "checkpoint_interval_s": 10, "checkpoint": [], "restart": {}, "memory": {}}
print("\nCheckpoint overhead (Cornell box, uniform, 2 workers x 1 thread, %g s each, checkpoints every 10 s)" % secs)
print("| image | samples/s, --state none | samples/s, --state DIR | A/B change | checkpoints | fork ms (max) | writer CPU s per checkpoint | writer CPU share of the cores | checkpoint file |")
print("|---|--:|--:|--:|--:|--:|--:|--:|--:|")
for size in ("256x256", "1920x1080"):
    a = json.load(open("%s/ckpt-%s-none.status.json" % (out, size)))
    b = json.load(open("%s/ckpt-%s-state.status.json" % (out, size)))
    m = json.load(open("%s/ckpt-%s-state.workers.json" % (out, size)))["master"]
    nbytes = int(open("%s/ckpt-%s-state.bytes" % (out, size)).read())
    writes = m.get("checkpoint_writes", 0)
    cpu = m.get("checkpoint_cpu_seconds", 0.0) / writes if writes else 0.0
    share = cpu / (10.0 * cores) if writes else 0.0
    ab = b["samples_per_second"] / a["samples_per_second"] - 1
    row = {"image": size, "sps_none": a["samples_per_second"], "sps_state": b["samples_per_second"],
           "ab_change": ab, "checkpoints": writes, "fork_ms": m.get("checkpoint_fork_ms_max", 0.0),
           "writer_seconds": m.get("checkpoint_wall_seconds", 0.0) / writes if writes else 0.0, "writer_cpu_s": cpu,
           "writer_share_of_cores": share, "state_bytes": nbytes}
    res["checkpoint"].append(row)
    print("| %s | %.0f | %.0f | %+.1f %% | %d | %.2f | %.3f | %.2f %% | %.1f MB |" % (
        size, row["sps_none"], row["sps_state"], 100 * ab, writes, row["fork_ms"], cpu, 100 * share, nbytes / 1e6))
t0, _, t1, s0 = open(out + "/restart.times").read().split()
res["restart"] = {"seconds_to_busy": float(t1) - float(t0), "samples_recovered": float(s0)}
print("\nRestart to busy: %.2f s from the new master's start to the job's samples growing (it resumed at %.0f samples)" %
      (float(t1) - float(t0), float(s0)))
print("\nMaster memory against ended jobs (16x16 jobs, RSS)")
print("| ended jobs | --state DIR | --state none |")
print("|--:|--:|--:|")
mem = {}
for mode in ("state", "none"):
    for line in open("%s/mem-%s.txt" % (out, mode)):
        n, kib = line.split()
        mem.setdefault(int(n), {})[mode] = int(kib)
for n in sorted(mem):
    print("| %d | %.1f MiB | %.1f MiB |" % (n, mem[n].get("state", 0) / 1024, mem[n].get("none", 0) / 1024))
res["memory"] = {str(n): v for n, v in mem.items()}

# 4. production resolutions
def samples(tag):
    rows = []
    for line in open("%s/%s.samples" % (out, tag)):
        t, rss, sbytes, cpu, m = line.split(" ", 4)
        rows.append((float(t), int(rss), int(sbytes), float(cpu), json.loads(m)))
    return rows
res["production"] = []
print("\nProduction resolutions (Cornell box, 65,536 spp = 2,048 layers, relmse, 2 workers x 1 thread, checkpoints every 10 s, %g s each)" % life)
print("| image | master RSS (max) | RSS a pixel | results merged | written: journal | written: snapshots | written / merged | state dir (max) | state dir / snapshot | checkpoint CPU, share of one core |")
print("|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|")
for size in ("256x256", "1920x1080", "3840x2160"):
    w, h = (int(v) for v in size.split("x"))
    rows = samples("prod-%s-state" % size)
    last = rows[-1][4]
    merged = last.get("results_bytes_merged", 0)
    jb = last.get("journal_bytes_written", 0)
    sb = last.get("snapshot_bytes_written", 0)
    cpu = last.get("checkpoint_cpu_seconds", 0.0)
    rss = max(r[1] for r in rows) * 1024
    sdir = max(r[2] for r in rows)
    st = json.load(open("%s/prod-%s-state.status.json" % (out, size)))
    snap = st.get("snapshot_bytes", 0) or 1
    row = {"image": size, "seconds": rows[-1][0], "rss_max_bytes": rss, "rss_bytes_per_pixel": rss / (w * h),
           "results_bytes_merged": merged, "journal_bytes_written": jb, "snapshot_bytes_written": sb,
           "written_over_merged": (jb + sb) / merged if merged else None, "state_dir_max_bytes": sdir,
           "checkpoint_cpu_s": cpu, "checkpoint_core_share": cpu / rows[-1][0], "snapshot_bytes": snap,
           "samples": st.get("samples"), "layers_done": st.get("layers_done"),
           "series": [{"t": r[0], "rss_kib": r[1], "state_bytes": r[2], "master_cpu_s": r[3],
                       "journal_bytes_written": r[4].get("journal_bytes_written", 0),
                       "snapshot_bytes_written": r[4].get("snapshot_bytes_written", 0),
                       "results_bytes_merged": r[4].get("results_bytes_merged", 0)} for r in rows]}
    if size == "3840x2160":
        none = samples("prod-%s-none" % size)
        a = none[-1][3] / none[-1][0]
        b = rows[-1][3] / rows[-1][0]
        row["ab_master_cpu_none"] = a
        row["ab_master_cpu_state"] = b
        t0, t1, t2, s0 = open("%s/prod-%s-state.restart.times" % (out, size)).read().split()
        row["restart_answers_s"] = float(t1) - float(t0)
        row["restart_busy_s"] = float(t2) - float(t0)
        row["restart_samples"] = float(s0)
    res["production"].append(row)
    print("| %s | %.0f MB | %.0f B | %.1f MB | %.1f MB | %.1f MB | %s | %.1f MB | %s | %.2f %% |" % (
        size, rss / 1e6, rss / (w * h), merged / 1e6, jb / 1e6, sb / 1e6,
        "%.2fx" % row["written_over_merged"] if merged else "-", sdir / 1e6,
        "%.2fx" % (sdir / snap), 100 * cpu / rows[-1][0]))
p4 = res["production"][-1]
print("\n4K A/B: the master's CPU (all its threads) %.3f of a core with --state, %.3f with --state none (%+.2f %% of a core)" % (
    p4["ab_master_cpu_state"], p4["ab_master_cpu_none"], 100 * (p4["ab_master_cpu_state"] - p4["ab_master_cpu_none"])))
print("4K restart: the master answers %.2f s after its start, the job runs again after %.2f s (resumed at %.0f samples)" % (
    p4["restart_answers_s"], p4["restart_busy_s"], p4["restart_samples"]))
json.dump(res, open(dest, "w"), indent=1)
print("\nwritten to " + dest)
PY
