#!/usr/bin/env python3
"""Print the distributed benchmark's tables and put them into bench/RESULTS.md.

Reads bench/results/*.json, takes the file(s) with "benchmark":
"distributed" (the newest by date if there are several), prints markdown to
stdout and rewrites the block between <!-- bench:distributed:begin --> and
<!-- bench:distributed:end --> in bench/RESULTS.md. If that file or the markers are
missing it says so and leaves every file alone. Standard library only.

    bench/update-results-distributed.py [--results DIR] [--readme FILE]
"""
import argparse
import glob
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from results_page import latest_result, replace_block  # noqa: E402

BEGIN = "<!-- bench:distributed:begin -->"
END = "<!-- bench:distributed:end -->"
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# Thesis table 4.1 (seconds, Cornell box), G = 1, 8, 16, 32, 64.
THESIS_GRAN = {1: [3258.9, 1871.5, 1743.6, 1706.7, 1680.3], 8: [881.4, 248.8, 226.0, 214.9, 210.0]}
THESIS_G = [1, 8, 16, 32, 64]


def si(x, digits=2):
    if x is None:
        return "-"
    for div, unit in ((1e9, " G"), (1e6, " M"), (1e3, " k")):
        if abs(x) >= div:
            return f"{x / div:.{digits}f}{unit}"
    return f"{x:.0f}"


def pct(x, digits=1):
    return "-" if x is None else f"{100 * x:.{digits}f}%"


def layout_text(layout):
    n, t = len(layout), layout[0]
    if all(x == t for x in layout):
        return f"{n} x {t}"
    return "+".join(str(x) for x in layout)


def load(results_dir):
    return latest_result(results_dir, "distributed", "update-results-distributed.py")


def throughput_table(d):
    cores = d["machine"]["cores"]
    lines = [
        "| Scene | Sampling | Workers x threads | Seconds | Samples | Rays/s | Rays/s per thread | "
        "Rays per CPU second | Rays per worker (mean) | Std dev | Std dev / mean | Idle | CPU use |",
        "|---|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|",
    ]
    for r in d["throughput"]:
        over = "†" if r["threads"] > cores or r["workers"] > cores else ""
        sd = r["worker_rays_stdev"]
        sdp = r["worker_rays_stdev_percent"]
        lines.append(
            f"| {r['scene']} | {'adaptive' if r['adaptive'] == 'thesis' else 'uniform'} | "
            f"{layout_text(r['layout'])}{over} | {r['seconds']:.2f}{'*' if r['disturbed'] else ''} | "
            f"{si(r['samples'])} | {si(r['rays_per_second'])} | {si(r['rays_per_second_per_thread'])} | "
            f"{si(r.get('rays_per_cpu_second'))} | "
            f"{si(r['worker_rays_mean'])} | {si(sd) if sd is not None else '-'} | "
            f"{'-' if sdp is None else f'{sdp:.2f}%'} | "
            f"{pct(r['idle_fraction'])} | {pct(r['cpu_utilization'], 0)} |")
    return "\n".join(lines)


def granularity_table(d):
    g = {r["granularity"]: r for r in d["granularity"]}
    ref = g.get(32)
    lines = [
        "| G | Seconds | Samples/s | Samples per CPU second | Pixel-layer results/s | Time / time at G = 32 | "
        "CPU time / CPU time at G = 32 | Thesis, 1 slave: time / G = 32 | Thesis, 8 slaves |",
        "|--:|--:|--:|--:|--:|--:|--:|--:|--:|",
    ]
    for G in sorted(g):
        r = g[G]
        th = ["-", "-"]
        if G in THESIS_G:
            i = THESIS_G.index(G)
            th = [f"{row[i] / row[3]:.2f}" for row in (THESIS_GRAN[1], THESIS_GRAN[8])]
        rel = f"{r['seconds'] / ref['seconds']:.2f}" if ref else "-"
        crel = f"{r['cpu_seconds'] / ref['cpu_seconds']:.2f}" if ref and ref["cpu_seconds"] > 0 else "-"
        lines.append(f"| {G} | {r['seconds']:.2f}{'*' if r['disturbed'] else ''} | {si(r['samples_per_second'])} | "
                     f"{si(r.get('samples_per_cpu_second'))} | {si(r['pixel_layers'] / r['seconds'])} | {rel} | "
                     f"{crel} | {th[0]} | {th[1]} |")
    return "\n".join(lines)


def master_table(d):
    lines = [
        "| Transport | Sampling | Synthetic workers | Results merged | Seconds | Results/s | "
        "Master thread CPU | Results per master CPU second | Process CPU / wall |",
        "|---|---|--:|--:|--:|--:|--:|--:|--:|",
    ]
    for m in d["master"]:
        lines.append(
            f"| {m['transport']} | {'adaptive' if m['adaptive'] == 'thesis' else 'uniform'} | {m['workers']} | "
            f"{si(m['results'])} | {m['seconds']:.2f} | {si(m['results_per_second'])} | "
            f"{pct(m['master_cpu_utilization'], 0)} | {si(m['results_per_master_cpu_second'])} | "
            f"{m['process_cpu_seconds'] / m['wall_seconds']:.2f} |")
    return "\n".join(lines)


def growth_table(d):
    g = d.get("growth")
    if not g:
        return ""
    lines = ["| Setup | Worker cores kept busy (our core speed) |", "|---|--:|"]
    lines.append(f"| one master, G = {g['granularity']} (measured R) | {g['one_master_cores']:.0f} |")
    for e in g["late_granularity"]:
        if e["G"] != g["granularity"]:
            lines.append(f"| one master, late layers at G = {e['G']} | {e['cores']:.0f} |")
    for e in g["relay"]:
        lines.append(f"| master + {e['relays']} relays, each merging k = {e['k']} layers per result | "
                     f"{e['cores']:.0f} |")
    for e in g["sharded"]:
        lines.append(f"| {e['shards']} shard masters (image tiles), global threshold reduced per layer | "
                     f"{e['cores']:.0f} |")
    return "\n".join(lines)


def text(d):
    m = d["machine"]
    s = d["settings"]
    parts = []
    spp = ", ".join(f"{k} {v} spp" for k, v in s["spp"].items())
    parts.append("**Throughput and load balance** (thesis tables 5.2 to 5.13): 256x256, G = 32, "
                 f"{spp}; each run a fresh `vbrender-master` and `vbrender-worker` processes on loopback "
                 "tcp, the job submitted with `vbrender submit`.")
    parts.append(throughput_table(d))
    notes = [f"{m['cpu']}, {m['cores']} cores: every configuration runs 2 tracing threads in all"]
    if any(r["threads"] > m["cores"] or r["workers"] > m["cores"] for r in d["throughput"]):
        notes.append("† 4 worker processes of 1 thread on 2 cores: oversubscribed, so their busy time "
                     "includes time spent descheduled and \"Idle\" understates idle CPU")
    notes.append("Rays per worker: the master's per-worker counters (fresh master per run); std dev is the "
                 "population standard deviation over the workers. Idle: 1 - sum of worker busy seconds / "
                 "(seconds x threads). CPU use: CPU time of the master and worker processes / (seconds x cores); "
                 "rays per CPU second divides by that CPU time, so it holds even when another process took "
                 "CPU")
    if any(r["disturbed"] for r in d["throughput"] + d["granularity"]):
        notes.append("\\* another process took CPU during this run (our processes got under 85% of the cores, "
                     "retries included): its figures are low")
    notes.append("Thesis, for scale (Opteron 150, 2006, one process per CPU): about 142 k rays/s per processor "
                 "on the Cornell box and 43 k on the Happy Buddha; per-slave rays differ by a std dev of "
                 "0.05% to 0.3% of the mean")
    parts.append("; ".join(notes) + ".")
    if d["granularity"]:
        gs = s["granularity_runs"]
        parts.append(f"**Granularity vs time** (thesis table 4.1): Cornell box, uniform, {gs['spp']} spp, "
                     f"{layout_text(gs['layout'])} workers x threads.")
        parts.append(granularity_table(d))
        parts.append("A task here is a range of pixels of about 32k samples whatever G is (the thesis sent one "
                     "pixel per task), so G changes only the number of results the master merges and the "
                     "per-layer work of the workers, not the message count per sample.")
    if d["master"]:
        ms = s["master"]
        parts.append(f"**Master capacity**: `bench/bench_master.c`, a real master and synthetic workers (threads "
                     "speaking the wire protocol, answering each task at once without tracing) in one process; "
                     f"{ms['width']}x{ms['width']}, {ms['spp']} spp, G = 32 (tasks of 1024 pixels).")
        parts.append(master_table(d))
        keeps = d.get("master_keeps_busy", {})
        lines = []
        for mode, k in keeps.items():
            ours = f"{k['worker_cores_ours']:.0f}" if k.get("worker_cores_ours") else "-"
            lines.append(f"{'uniform' if mode == 'none' else 'adaptive'}: one master core merges "
                         f"{si(k['results_per_master_core'])} results/s, which keeps {ours} of our worker cores "
                         f"busy on the Cornell box at G = 32 ({si(d['core_samples_per_second_per_core'])} "
                         f"samples/s per core, so {si(d['core_samples_per_second_per_core'] / 32)} results/s "
                         f"per core) and {k['worker_cores_mitsuba_class']:.0f} Mitsuba-class cores "
                         "(47 k results/s each)")
        if lines:
            parts.append("; ".join(lines) + ". Target: 10 M results/s on one master core (about 200 "
                         "Mitsuba-class cores). \"Results per master CPU second\" divides by the CPU time of the "
                         "master's own thread (its pthread CPU clock), so it is the rate of one dedicated "
                         "master core; on this 2-core machine the master shares the CPU with the synthetic "
                         "workers and ZeroMQ's I/O thread, hence \"Master thread CPU\" below 100%. Core speed: "
                         f"{d.get('core_source')}.")
        if d.get("master_hotspots"):
            hs = ", ".join(f"{h['symbol']} {h['percent']:.0f}%" for h in d["master_hotspots"][:8])
            parts.append(f"Where the master thread's time goes (perf, inproc, 2 synthetic workers, uniform; "
                         f"percent of that thread's samples): {hs}.")
        elif d.get("perf_error"):
            parts.append(f"Master thread profile: {d['perf_error']}.")
    g = d.get("growth")
    if g:
        parts.append("**How the design grows past one master** (arithmetic on the figures above, not a "
                     "measurement):")
        parts.append(growth_table(d))
        parts.append("Assumptions: " + "; ".join(g["assumptions"]) +
                     f" ({g['network_megabytes_per_second_at_R']:.0f} MB/s). Late layers: results per sample "
                     "fall as 1/G, so a master keeps G/32 times the cores once the layers grow (at the cost of "
                     "coarser adaptive decisions). Relays: each relay runs the layers k at a time for its "
                     "workers and sends the master one merged record (sums, M2 by Chan's formula, the last "
                     "layer's eq. 4.1 statistic) per pixel per k layers; the master then makes its skip "
                     "decisions every k G samples. Shards: each shard master owns a set of pixel ranges and "
                     "runs the scheduler for them; the only global quantity is the per-layer threshold (eq. "
                     "4.3, a mean), reduced from one (sum, count) pair per shard per layer, and the scheduler's "
                     "two-layer lookahead leaves one layer of time for that reduction, so the decisions stay "
                     "exactly the thesis's.")
    parts.append(f"Commit {d['commit']}, {d['date']}; load average before/after {m['loadavg_before']} / "
                 f"{m['loadavg_after']}; whole benchmark {d['bench_seconds']:.0f} s, of which "
                 f"{d.get('quiet_wait_seconds', 0)} s waiting for other processes to leave the CPU "
                 "(`bench/run-distributed.sh`).")
    return "\n\n".join(parts)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", default=os.path.join(ROOT, "bench", "results"))
    ap.add_argument("--readme", default=os.path.join(ROOT, "bench", "RESULTS.md"))
    a = ap.parse_args()

    d = load(a.results)
    if d is None:
        print(f"update-results-distributed.py: no distributed results in {a.results} (run bench/run-distributed.sh)",
              file=sys.stderr)
        return 1
    body = text(d)
    print(body)

    replace_block(a.readme, BEGIN, END, body, "update-results-distributed.py")
    return 0


if __name__ == "__main__":
    sys.exit(main())
