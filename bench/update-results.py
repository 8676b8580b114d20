#!/usr/bin/env python3
"""Print the core benchmark table and put it into bench/RESULTS.md.

Reads bench/results/*.json, takes the file(s) with "benchmark": "core" (the
newest by date if there are several), prints a markdown table to stdout and
rewrites the block between <!-- bench:core:begin --> and
<!-- bench:core:end --> in bench/RESULTS.md. If that file or the markers are
missing it says so and leaves every file alone. Standard library only.

    bench/update-results.py [--results DIR] [--readme FILE]
"""
import argparse
import glob
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from results_page import latest_result, replace_block  # noqa: E402

BEGIN = "<!-- bench:core:begin -->"
END = "<!-- bench:core:end -->"
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def mega(x, digits=2):
    return "-" if x is None else f"{x / 1e6:.{digits}f} M"


def ratio(a, b):
    return "-" if not a or not b else f"{a / b:.2f}"


def load_core(results_dir):
    return latest_result(results_dir, "core", "update-results.py")


def ceiling_table(core, peer_runs):
    """What ray casting alone allows on the scenes traced through Embree: the
    raw rate of our ray mix divided by our rays per sample is the samples/s we
    would reach with shading, sampling and bookkeeping free (issue 9)."""
    rows = []
    for r in core["runs"]:
        raw = r["raw_embree"]
        if r["threads"] != 1 or "path_watertight_user" not in raw:
            continue
        m = peer_runs.get((r["scene_name"], 1))
        rps = r["ours"]["rays_per_sample"]
        cells = []
        for key in ("path", "path_embree_packets", "path_own_bvh", "path_one_by_one", "path_sorted",
                    "path_watertight_user", "path_not_robust"):
            if key not in raw:  # results from before packets
                cells.append("-")
                continue
            mix = raw[key]["mix_rays_per_second_per_core"]
            cap = mix / rps
            cells.append(f"{mega(mix, 1)} ({ratio(cap, m['samples_per_second_per_core']) if m else '-'})")
        rows.append(f"| {r['scene_name']} | {rps:.2f} | " + " | ".join(cells) + " |")
    if not rows:
        return ""
    return "\n".join([
        "**The ceiling ray casting sets** (issue 9; 1 thread): our ray mix on each way of casting that "
        "stays watertight, and, in brackets, the samples/s it would allow with shading, sampling and "
        "bookkeeping free (mix / rays per sample) over Mitsuba 3's samples/s. \"The tracer's\": as the "
        "tracer casts them: by our watertight traversal of a BVH Embree builds (common/bvh.h, on an AVX2 "
        "host), or on a scene with smooth glass in Embree ROBUST packets of 8 consecutive rays; \"ROBUST "
        "packets\": Embree's packets, as the tracer cast every scene's rays before bvh.h; \"Our "
        "traversal\": bvh.h; \"one ray a call\": rtcIntersect1 / "
        "rtcOccluded1 on the ROBUST BVH. \"Sorted\": the same rays "
        "sorted by direction octant and origin Morton code, in packets (the sort not timed: the most a sorting "
        "wavefront tracer could gain from coherence). \"Watertight clusters\": an Embree BVH (default "
        "flags) over clusters of 16 triangles in Morton order, each tested by trilist's watertight "
        "kernel through Embree's user-geometry callbacks, one ray a call. \"Not ROBUST\": Embree's own test, which lets "
        "rays through cracks (the table below), for reference.",
        "",
        "| Scene | Rays/sample | The tracer's | ROBUST packets | Our traversal | ROBUST, one ray a call | "
        "ROBUST, sorted | Watertight clusters | Not ROBUST (leaks) |",
        "|---|--:|--:|--:|--:|--:|--:|--:|--:|",
    ] + rows)


def table(core, max_triangles):
    peer = core.get("peer") or {}
    # (scene, threads) -> run; results before the peer ran on every scene
    # hold the Cornell box only, without "scene_name"
    peer_runs = {(r.get("scene_name", peer.get("scene", "cornell-box")), r["threads"]): r
                 for r in peer.get("runs", [])}
    variant = next(iter(peer_runs.values()), {}).get("variant", "")
    lines = [
        "| Scene | Threads | Ours samples/s/core | Ours rays/s/core | "
        "Raw ray casting rays/s/core (ext / shadow) | Ours / raw | "
        f"Mitsuba 3{' ' + variant if variant else ''} samples/s/core | Ours / Mitsuba | Peak memory |",
        "|---|--:|--:|--:|--:|--:|--:|--:|--:|",
    ]
    for r in core["runs"]:
        t = r["threads"]
        ours = r["ours"]
        listed = r.get("accel") == "trilist" and "path_triangle_list" in r["raw_embree"]
        raw = r["raw_embree"]["path_triangle_list" if listed else "path"]
        m = peer_runs.get((r["scene_name"], t))
        m_sps = m["samples_per_second_per_core"] if m else None
        lines.append(
            f"| {r['scene_name']} | {t}{'*' if r.get('disturbed') else ''} | {mega(ours['samples_per_second_per_core'])} | "
            f"{mega(ours['rays_per_second_per_core'])} | "
            f"{mega(raw['extension']['rays_per_second_per_core'], 1)} / "
            f"{mega(raw['shadow']['rays_per_second_per_core'], 1)}{' (list)' if listed else ''} | "
            f"{ratio(ours['rays_per_second'], raw['mix_rays_per_second'])} | "
            f"{mega(m_sps)}{'*' if m and m.get('disturbed') else ''} | {ratio(ours['samples_per_second_per_core'], m_sps)} | "
            f"{r['peak_rss_kb_render'] / 1024:.0f} MiB |")
    mach = core.get("machine", {})
    spp = core.get("settings", {}).get("spp", {})
    spp_text = ", ".join(f"{k} {v} spp" for k, v in spp.items())
    notes = [
        f"256x256, path integrator, independent numbers and Mitsuba's Russian roulette in both renderers (the same paths; "
        f"a job's own roulette traces longer ones, `bench_core --roulette ours`), {spp_text}, best of {core.get('settings', {}).get('runs')} runs; "
        f"{mach.get('cpu')}, {mach.get('cores')} cores, Embree {mach.get('embree')} ({mach.get('isa')}); "
        f"commit {core.get('commit')}, {core.get('date')}; whole benchmark {core.get('bench_seconds', 0):.0f} s.",
        "Raw ray casting: what the tracer casts rays with, alone, over 2M precomputed rays recorded from "
        "random walks from the camera, diffuse bounces and through glass (the rays our tracer traces), cast "
        "as the tracer casts them: by our watertight traversal of a BVH Embree builds (common/bvh.h), or "
        "on a scene with smooth glass by Embree's rtcIntersect8 / rtcOccluded8 on packets of 8 consecutive "
        "rays, "
        "or \"(list)\" the triangle list without a BVH (common/trilist.h) that the tracer "
        f"uses for scenes of up to {max_triangles} triangles; \"Ours / raw\" compares our rays/s, "
        "shading and sampling included, with the raw rate of our own extension/shadow mix "
        "(1 / sum(fraction / rate)). Peak memory: ru_maxrss of the benchmark process after the renders.",
    ]
    robust = [f"{r['scene_name']} "
              f"{mega(r['raw_embree'].get('path_embree_packets', r['raw_embree']['path'])['mix_rays_per_second_per_core'], 1)}"
              for r in core["runs"] if r["threads"] == 1]
    fast = [f"{r['scene_name']} {mega(r['raw_embree']['path_not_robust']['mix_rays_per_second_per_core'], 1)}"
            for r in core["runs"] if r["threads"] == 1 and "path_not_robust" in r["raw_embree"]]
    if fast:
        notes.append("Embree's BVH is built with RTC_SCENE_FLAG_ROBUST: the same ray mix runs at "
                     f"{', '.join(robust)} rays/s on it, and at {', '.join(fast)} rays/s without the flag "
                     "(1 thread, reference only).")
    sobol = sobol_table(core, peer_runs)
    if sobol:
        notes.append(sobol)
    avx2 = avx2_table(core)
    if avx2:
        notes.append(avx2)
    ceiling = ceiling_table(core, peer_runs)
    if ceiling:
        notes.append(ceiling)
    bars = bars_table(core)
    if bars:
        notes.append(bars)
    if any(r.get("disturbed") for r in core["runs"] + list(peer_runs.values())):
        notes.append("\\* another process used the CPU during this measurement, so its figure is low "
                     "(core.json: cpu_utilization under 0.95 even after extra runs, or other_cpu_cores "
                     "for the peer).")
    if core.get("peer") is None:
        notes.append(f"Mitsuba 3 peer not run: {core.get('peer_error', 'unknown reason')}.")
    else:
        notes.append("Mitsuba 3: the same scene (bench/peer/mitsuba_peer.py converts our JSON), spp and "
                     "threads, `path` integrator, best of its timed renders after a warm-up (bench/peer/).")
    text = "\n".join(lines) + "\n\n" + "\n\n".join(notes)
    return text


def sobol_table(core, peer_runs):
    """Ours with the sobol sampler (a job's default) beside the independent
    numbers the table above measures."""
    runs = (core.get("sobol") or {}).get("runs")
    if not runs:
        return None
    indep = {(r["scene_name"], r["threads"]): r for r in core["runs"]}
    lines = [
        "**With the sampler a job gets by default.** The table above runs both renderers on "
        "independent numbers, the fastest sampler of each; a job's default is Owen-scrambled Sobol "
        "(`--sampler sobol`), whose pairs the wavefront engine computes ahead in vectors "
        "(`rng_sobol_fill`). Ours with it (`bench_core --sampler sobol`):",
        "",
        "| Scene | Threads | Ours, sobol samples/s/core | Sobol / independent | Ours, sobol / Mitsuba |",
        "|---|--:|--:|--:|--:|",
    ]
    for r in runs:
        key = (r["scene_name"], r["threads"])
        sps = r["ours"]["samples_per_second_per_core"]
        i = indep.get(key)
        m = peer_runs.get(key)
        lines.append(
            f"| {r['scene_name']} | {r['threads']}{'*' if r.get('disturbed') else ''} | {mega(sps)} | "
            f"{ratio(sps, i['ours']['samples_per_second_per_core']) if i else '-'} | "
            f"{ratio(sps, m['samples_per_second_per_core']) if m else '-'} |")
    return "\n".join(lines)


def avx2_table(core):
    """Both renderers again as an AVX2-only host runs them (run-core.sh's
    AVX2 pass on a host with AVX-512), beside the native figures."""
    avx2 = core.get("avx2")
    if not avx2:
        return ""
    key = lambda r: (r.get("scene_name"), r["threads"])  # noqa: E731
    native_ours = {key(r): r for r in core["runs"]}
    native_peer = {key(r): r for r in (core.get("peer") or {}).get("runs", [])}
    peer = {key(r): r for r in (avx2.get("peer") or {}).get("runs", [])}
    rows = []
    for r in avx2["runs"]:
        k = key(r)
        o = r["ours"]["samples_per_second_per_core"]
        m = peer.get(k, {}).get("samples_per_second_per_core")
        no = native_ours.get(k, {}).get("ours", {}).get("samples_per_second_per_core")
        nm = native_peer.get(k, {}).get("samples_per_second_per_core")
        star = lambda x: "*" if x and x.get("disturbed") else ""  # noqa: E731
        rows.append(f"| {k[0]} | {k[1]} | {mega(o)}{star(r)} | {mega(m)}{star(peer.get(k))} | "
                    f"**{ratio(o, m)}** | {ratio(no, nm)} | {ratio(o, no)} | {ratio(m, nm)} |")
    lines = [
        "**As an AVX2-only host runs them** (issue 23 asks for both ISAs; run-core.sh's AVX2 pass, on this "
        "host: the same clock and caches, only the instructions differ). Ours with its own SIMD kernels "
        "(the triangle list's, our BVH traversal's, and the diffuse shading's at 8 lanes, which natively "
        "takes 16 beside the list's AVX-512 kernel) built for AVX2 (`bench_core --isa avx2`; Embree is "
        "pinned to AVX2 and the rest is baseline x86-64 either way); Mitsuba with Dr.Jit's LLVM backend "
        "compiling for Haswell at 8 lanes and its bundled Embree capped at AVX2 "
        "(`mitsuba_peer.py --isa avx2`, bench/peer/embree_isa.c).",
        "",
        "| Scene | Threads | Ours samples/s/core (AVX2) | Mitsuba 3 (AVX2) | Ours / Mitsuba, AVX2 | "
        "Ours / Mitsuba, native | Ours AVX2 / native | Mitsuba AVX2 / native |",
        "|---|--:|--:|--:|--:|--:|--:|--:|",
    ] + rows
    if avx2.get("peer") is None:
        lines.append("")
        lines.append(f"Mitsuba 3 peer (AVX2) not run: {avx2.get('peer_error', 'unknown reason')}.")
    return "\n".join(lines)


# Issue 23's bars: ours over Mitsuba's samples/s per core, natively and as an
# AVX2-only host runs both renderers.
ISSUE23_BARS = {"cornell-box": 1.5, "cornell-glass": 1.2, "cornell-buddha": 1.0}
# Ways of casting that stay watertight, as bench_core measures them on the
# recorded path rays (its raw_embree keys), for the best of them.
WATERTIGHT = {
    "path_triangle_list": "the list",
    "path": "the tracer's",
    "path_embree_packets": "ROBUST packets",
    "path_own_bvh": "our traversal",
    "path_one_by_one": "ROBUST, one a call",
    "path_sorted": "ROBUST on sorted rays, sort untimed",
    "path_watertight_user": "clusters",
}


def bars_table(core):
    """What issue 23's bars ask of the engine: for each scene, the ceiling
    (samples/s with shading, sampling and bookkeeping free: the casting's
    mix over our rays per sample) beside the bar, and the share of the time
    casting must take (ours over the ceiling) for the bar to hold. A bar
    over the ceiling cannot be reached by shading faster, only by faster
    watertight casting."""
    passes = [("native", core["runs"], core.get("peer") or {})]
    if core.get("avx2"):
        passes.append(("AVX2", core["avx2"]["runs"], core["avx2"].get("peer") or {}))
    rows = []
    for name, runs, peer in passes:
        m_runs = {(r.get("scene_name"), r["threads"]): r for r in peer.get("runs", [])}
        for r in runs:
            bar = ISSUE23_BARS.get(r["scene_name"])
            m = m_runs.get((r["scene_name"], r["threads"]))
            if bar is None or m is None:
                continue
            raw, rps = r["raw_embree"], r["ours"]["rays_per_sample"]
            m_sps = m["samples_per_second_per_core"]
            cap = lambda key: raw[key]["mix_rays_per_second_per_core"] / rps / m_sps  # noqa: E731
            listed = r.get("accel") == "trilist" and "path_triangle_list" in raw
            tracer = cap("path_triangle_list" if listed else "path")
            best = max((k for k in WATERTIGHT if k in raw), key=cap)
            ours = r["ours"]["samples_per_second_per_core"] / m_sps
            need = bar / tracer
            rows.append(
                f"| {r['scene_name']} | {r['threads']} | {name} | {bar:.1f} | {ours:.2f} | {tracer:.2f} | "
                f"{cap(best):.2f} ({WATERTIGHT[best]}) | "
                f"{cap('path_not_robust'):.2f} | {ours / tracer:.2f} | "
                f"{'**' if need > 1 else ''}{need:.2f}{'**' if need > 1 else ''} | {0.8 * tracer:.2f} |")
    if not rows:
        return ""
    return "\n".join([
        "**What issue 23's bars ask of the engine** (from the runs above; ceilings are samples/s over "
        "Mitsuba's with shading, sampling and bookkeeping free: a casting's rate on our recorded ray mix "
        "over our rays per sample). \"The tracer's\": the casting the tracer uses; \"fastest "
        "watertight\": the best of every watertight casting bench_core measures (the list, Embree ROBUST "
        "in packets or one ray a call, our traversal, watertight clusters, ROBUST on rays sorted by an "
        "untimed global sort); \"Embree not ROBUST\": its own test, which leaks, which we do not use. "
        "\"Bar needs\": ours over the tracer's ceiling for the bar to hold, so the share of the time "
        "casting must take; over 1 (bold) no shading can reach it, only faster watertight casting. "
        "\"0.8 of the ceiling\": ours over Mitsuba if shading, sampling and bookkeeping took a fifth "
        "of the time, issue 23's other goal.",
        "",
        "| Scene | Threads | Pass | Bar | Ours / Mitsuba | Ceiling, the tracer's | Ceiling, fastest "
        "watertight | Ceiling, Embree not ROBUST | Ours / ceiling | Bar needs | 0.8 of the ceiling |",
        "|---|--:|---|--:|--:|--:|--:|--:|--:|--:|--:|",
    ] + rows)


def trilist_table(results_dir):
    """The crossover of bench_trilist (bench/results/trilist.json), or ''."""
    path = os.path.join(results_dir, "trilist.json")
    try:
        with open(path) as f:
            t = json.load(f)
    except (OSError, ValueError):
        return ""
    lines = [
        f"**Triangle list or BVH** (`bench_trilist`, 1 thread, {t['kernel']} list kernel, Embree "
        f"{t.get('embree_isa', '')} ROBUST; {t['rays'] // 1000}k closest-hit rays from inside each closed "
        "mesh in random directions, and as many shadow rays between two inside points):",
        "",
        "| Mesh | Triangles | List ext M rays/s | Embree ext | List / Embree | List shadow | Embree shadow "
        "| List / Embree | Our BVH ext | Our BVH shadow |",
        "|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|",
    ]
    for m in t["meshes"]:
        lines.append(
            f"| {m['mesh']} | {m['triangles']} | {m['list_ext_mrays']:.2f} | {m['embree_ext_mrays']:.2f} | "
            f"{m['list_ext_mrays'] / m['embree_ext_mrays']:.2f} | {m['list_shadow_mrays']:.2f} | "
            f"{m['embree_shadow_mrays']:.2f} | {m['list_shadow_mrays'] / m['embree_shadow_mrays']:.2f} | "
            f"{m.get('own_bvh_ext_mrays', 0):.2f} | {m.get('own_bvh_shadow_mrays', 0):.2f} |")
    lines.append("")
    lines.append(f"The tracer uses the list up to {t['max_triangles']} triangles (TRILIST_MAX_TRIANGLES). "
                 "\"Our BVH\": our traversal of a BVH Embree builds (common/bvh.h), which the tracer uses "
                 "above that count, unless the scene has smooth glass.")
    k = t.get("leaks")
    if k:
        lines += [
            "",
            f"**Why the BVH stays ROBUST** (`bench_trilist`): {k['rays'] / 1e6:g} M closest-hit rays from random "
            f"points inside a closed {k['triangles']}-triangle icosphere (every edge shared exactly) in random "
            "directions; a ray that misses went through a crack between two triangles.",
            "",
            "| Embree scene flags | Rays through a crack | M rays/s |",
            "|---|--:|--:|",
            f"| default (what Mitsuba 3 uses) | {k['default']['misses']} | {k['default']['mrays']:.2f} |",
            f"| RTC_SCENE_FLAG_ROBUST (ours, on a scene with smooth glass) | {k['robust']['misses']} | {k['robust']['mrays']:.2f} |",
        ]
        own = k.get("own_bvh")
        if own:
            lines.append(
                f"| our traversal of Embree's BVH (common/bvh.h; {own['rays'] / 1e6:g} M rays, "
                f"{own['kernel']}; shadow segments not blocked: {own['shadow_unblocked']}) | {own['misses']} | "
                f"{own['mrays']:.2f} |")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", default=os.path.join(ROOT, "bench", "results"))
    ap.add_argument("--readme", default=os.path.join(ROOT, "bench", "RESULTS.md"))
    a = ap.parse_args()

    core = load_core(a.results)
    if core is None:
        print(f"update-results.py: no core results in {a.results} (run 'make bench')", file=sys.stderr)
        return 1
    # the list's limit as bench_trilist measured it (TRILIST_MAX_TRIANGLES)
    try:
        with open(os.path.join(a.results, "trilist.json")) as f:
            max_triangles = json.load(f)["max_triangles"]
    except (OSError, ValueError, KeyError):
        max_triangles = "TRILIST_MAX_TRIANGLES"
    text = table(core, max_triangles)
    crossover = trilist_table(a.results)
    if crossover:
        text += "\n\n" + crossover
    print(text)

    replace_block(a.readme, BEGIN, END, text, "update-results.py")
    return 0


if __name__ == "__main__":
    sys.exit(main())
