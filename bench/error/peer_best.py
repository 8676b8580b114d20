"""Equal time against Mitsuba 3 at its best sampler (issue 24, item 5).

The study (study.py) times Mitsuba with one sampler, multijitter, chosen
once on two scenes. A peer must be compared at its best on each scene, so
this runs, per scene (VB_PEER_SCENES, default every shipped scene: each
scenes/*.json, and each scenes/mitsuba/*.xml as mitsuba/NAME, which both
renderers read as it is, at $res = the study's size), at the study's size,
references and timing guard:

- ours: `vbrender render` with our defaults (2 workers x 1 thread), max
  2 VB_PEER_SPP samples a pixel (the adaptive default stops many pixels
  early: its curve must reach the time Mitsuba took for VB_PEER_SPP), its
  error curve against the reference, on the job's own clock: from its
  first task handed out, so the workers' loading of the scene counts, the
  processes' start and the client's and the master's check of the scene
  do not;
- Mitsuba 3 (llvm_ad_rgb, 2 threads, warm: mitsuba_peer.py's sweep renders
  each count once untimed first) with each of its five samplers, at the
  sample counts that sampler takes as they are (orthogonal: squares of
  primes; ldsampler: powers of 4; stratified: squares; multijitter: a x a or
  a x (a + 1)), up to VB_PEER_SPP;
- Mitsuba's best sampler on the scene: the lowest relMSE at equal time
  (geometric mean over 5 times spread over the range every sampler's sweep
  covers), so the choice is made on the scene itself;
- our relMSE over that sampler's at the times it took for its last two
  counts, and its time over ours to equal relMSE (geometric mean over the
  levels both reach: above 1, we are faster);
- the same with Mitsuba's loading of the scene (timed once in its process,
  mitsuba_peer.py's seconds_load) added to each of its times, since our
  clock counts our workers' loading: what a user waits for from either;
- VB_PEER_SEEDS (default 3) runs of ours and of Mitsuba's best sampler,
  each with its own seed (the best chosen on the first seed's sweeps): the
  figures above are those of the mean curves (each count's relMSE and
  seconds averaged over the seeds for Mitsuba; ours averaged at the first
  run's times), so one render's noise does not make the reading (one run
  a count moved its last points by up to 30 %); each seed's own figures
  are kept beside them, and the table gives their range;
- a log-log plot of relMSE against seconds, every curve:
  bench/results/error/peer-best-<scene>.png.

Writes bench/results/peer-best.json (a run of some scenes replaces theirs
and keeps the others' while the settings and the host are the same; a file
of other settings is moved to peer-best-<its commit>.json) and the table between the
bench:peer-best markers of bench/RESULTS.md. Alone: `bash bench/error/run.sh
--peer-best` (VB_STUDY_SIZE, VB_STUDY_REF_SPP as the study; about 3 minutes
a scene at 64x64 on 2 cores, after its reference); `--from-json` rewrites the
table from the JSON.
"""
import json
import math
import os
import re
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import study as S  # noqa: E402  (the study's settings, references and helpers)

# every shipped scene: our own format (scenes/*.json, by name) and Mitsuba's
# (scenes/mitsuba/*.xml, as mitsuba/NAME)
SCENES = os.environ.get("VB_PEER_SCENES", ",".join(S.shipped_scenes())).split(",")
MAX_SPP = int(os.environ.get("VB_PEER_SPP", "1024"))
SEED = 31
# runs of ours and of Mitsuba's best sampler, seeds SEED + k (Mitsuba) and
# the study's seed + k (ours), k < SEEDS
SEEDS = max(1, int(os.environ.get("VB_PEER_SEEDS", "3")))
OUT = os.path.join(S.WORK, "quick", "peer-best.json") if S.QUICK else \
    os.path.join(S.ROOT, "bench", "results", "peer-best.json")
RUNS = os.path.join(S.WORK, "quick", "peer-best") if S.QUICK else os.path.join(S.WORK, "peer-best")
MARK_BEGIN, MARK_END = "<!-- bench:peer-best:begin -->", "<!-- bench:peer-best:end -->"


def is_prime(p):
    return p >= 2 and all(p % d for d in range(2, int(p ** 0.5) + 1))


def sampler_counts(sampler, top):
    """The sample counts each Mitsuba sampler takes as they are, from 16 up to
    top, about 2x apart (mitsuba_peer.py refuses a count it would round)."""
    if sampler == "independent":
        c = [16 << k for k in range(12)]
    elif sampler == "stratified":
        c = [a * a for a in (4, 6, 8, 12, 16, 23, 32, 45, 64)]
    elif sampler == "multijitter":
        c = [16, 30, 64, 132, 256, 506, 1024, 2070, 4096]
    elif sampler == "orthogonal":
        c = [p * p for p in (5, 7, 11, 17, 23, 31, 47, 67) if is_prime(p)]
    elif sampler == "ldsampler":
        c = [16, 64, 256, 1024, 4096]
    else:
        raise ValueError(sampler)
    return [n for n in c if n <= top]


SAMPLERS = ["independent", "stratified", "multijitter", "orthogonal", "ldsampler"]


def mitsuba_sweep(name, scene, sampler, r, ref_meta, k=0):
    """Mitsuba's sweep of one sampler with seed SEED + k."""
    py = os.environ.get("MITSUBA_PEER_PYTHON", sys.executable)
    script = os.path.join(S.ROOT, "bench", "peer", "mitsuba_peer.py")
    size = str(S.CFG["size"])
    out_dir = os.path.join(RUNS, f"{name}-{sampler}" + (f"-seed{k}" if k else ""))
    cmd = [py, script, scene, "--mode", "sweep", "--threads", "2", "--width", size,
           "--height", size,
           "--sampler", sampler, "--spp-list", ",".join(map(str, sampler_counts(sampler, MAX_SPP))),
           "--seed", str(SEED + k), "--out-dir", out_dir]
    best = None
    for attempt in range(2):
        S.log(f"{name} mitsuba {sampler}{f' seed {SEED + k}' if k else ''}: "
              f"spp {sampler_counts(sampler, MAX_SPP)}")
        p, st = S.run_measured(cmd, timed=True)
        if best is None or st["other_cpu_cores"] < best[1]["other_cpu_cores"]:
            best = (p, st)
        if st["other_cpu_cores"] <= S.CFG["busy_retry_cores"]:
            break
        S.log(f"  other processes used {st['other_cpu_cores']:.2f} cores; again")
    p, st = best
    sw = json.loads(p.stdout.strip().splitlines()[-1])
    pts = []
    for run in sw["runs"]:
        raw = S.relmse(S.rgb(S.read_exr(run["out"])), r)
        pts.append({"spp": run["spp"], "seconds": run["seconds"], "relmse_raw": raw,
                    "relmse": max(raw - ref_meta["relmse_est"], 1e-12)})
    return {"runs": pts, "stats": st, "version": sw.get("version"), "load": sw.get("seconds_load"),
            "t": np.array([q["seconds"] for q in pts]), "relmse": np.array([q["relmse"] for q in pts])}


def best_sampler(curves):
    """The sampler with the lowest relMSE at equal time: geometric mean of
    each curve (log-log interpolation) at 5 times spread over the range
    every curve covers."""
    lo = max(float(c["t"][0]) for c in curves.values())
    hi = min(float(c["t"][-1]) for c in curves.values())
    if not hi > lo:  # no common range: the lowest relMSE x time at the last point
        return min(curves, key=lambda k: curves[k]["relmse"][-1] * curves[k]["t"][-1]), {}
    times = np.geomspace(lo, hi, 5)
    score = {}
    for k, c in curves.items():
        ys = [S.interp_loglog(c["t"], c["relmse"], float(t)) for t in times]
        score[k] = float(np.exp(np.mean(np.log(ys))))
    # a sweep with a non-finite image (a NaN score) is never the best
    return min(score, key=lambda k: score[k] if math.isfinite(score[k]) else math.inf), score


def mean_mitsuba(sweeps):
    """Sweeps of one sampler with different seeds as one curve: each count's
    relMSE and seconds averaged (one sweep: itself)."""
    runs = [{"spp": q[0]["spp"], "seconds": float(np.mean([x["seconds"] for x in q])),
             "relmse": float(np.mean([x["relmse"] for x in q])),
             "relmse_seeds": [x["relmse"] for x in q]}
            for q in zip(*(w["runs"] for w in sweeps))]
    return dict(sweeps[0], runs=runs, t=np.array([q["seconds"] for q in runs]),
                relmse=np.array([q["relmse"] for q in runs]))


def mean_ours(runs):
    """Our runs of different seeds as one curve: relMSE averaged at the
    first run's times that every run covers (log-log interpolation; one
    run: its own points)."""
    lo = max(float(x["t"][0]) for x in runs)
    hi = min(float(x["t"][-1]) for x in runs)
    t = [float(v) for v in runs[0]["t"] if lo <= v <= hi]
    y = [float(np.mean([S.interp_loglog(x["t"], x["relmse"], v) for x in runs])) for v in t]
    return {"t": np.array(t), "relmse": np.array(y)}


def seed_range(per_seed, key):
    """min-max over the seeds' own comparisons of one figure, as text."""
    xs = [v for v in (key(c) for c in per_seed) if v]
    if len(xs) < 2:
        return "-"
    return f"{min(xs):.2f}-{max(xs):.2f}"


def compare(ours, mits):
    """Our curve against Mitsuba's best one: our relMSE over its at the times
    it took for its last two counts, and its time over ours to equal relMSE."""
    return S.curve_against_peer(ours, mits, mits["runs"][-2:])


def compare_loaded(ours, mits):
    """compare() with Mitsuba's loading of the scene added to each of its
    times, as our clock counts our workers' loading: what a user waits for
    from either renderer, its kernels compiled (warm) as before. None when
    the sweep did not time its load (an older mitsuba_peer.py)."""
    if mits.get("load") is None:
        return None
    runs = [dict(q, seconds=q["seconds"] + mits["load"]) for q in mits["runs"]]
    return compare(ours, dict(mits, runs=runs, t=mits["t"] + mits["load"]))


def plot(name, ours, curves, best, path, ref_meta):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4.2))
    ax.loglog(ours["t"], ours["relmse"], "-", color="C2", lw=2,
              label="vbrender, defaults" + (f" (mean of {SEEDS} seeds)" if SEEDS > 1 else ""))
    for i, (k, c) in enumerate(curves.items()):
        ax.loglog(c["t"], c["relmse"], "o-" if k == best else ".--", color=f"C{3 + i}",
                  lw=2 if k == best else 0.8, ms=4 if k == best else 3,
                  label=f"Mitsuba 3, {k}" + (" (its best here)" if k == best else ""))
    S.finish_time_plot(fig, ax, ref_meta, "seconds (2 cores each)",
                       f"{name}: relMSE against time, {S.CFG['size']}x{S.CFG['size']}", path)


def table(R):
    c = R["config"]
    L = [f"vbrender with its defaults (`vbrender render`, 2 workers x 1 thread, max {c['max_spp']} spp) "
         f"against Mitsuba 3 (`llvm_ad_rgb`, path, 2 threads, warm) with each of its five samplers at the "
         f"counts each takes as it is, up to {c['max_spp']} spp, {c['size']}x{c['size']} pixels, "
         f"against the study's references "
         f"({c['ref_spp']} spp, their own error subtracted). Mitsuba's best: its lowest relMSE at equal time "
         f"on the scene. Ratios: our relMSE over its best's at the times it took for its last two counts "
         f"(below 1: we are ahead), and its time over ours to equal relMSE (above 1: we are faster). "
         f"Our time is the job's clock, from its first task (the workers' scene loading counts); "
         f"Mitsuba's renders are timed warm (its kernels compiled), without its loading of the scene; "
         f"two columns count its loading too (timed in the same process: its parse, meshes and "
         f"BVH), as ours counts ours. "
         + (f"Ours and Mitsuba's best sampler each ran {c['seeds']} times with their own seeds: the "
            f"figures are those of the mean curves (its best chosen on the first seed's sweeps), and the "
            f"last column gives the range of its time over ours between the seeds' own runs. "
            if c.get("seeds", 1) > 1 else "")
         + (f"Host: {c['host']}. " if c.get("host") else "") +
         f"Commit {R['commit']} (a row of an earlier run names its own), {R['date']}, {R['seconds']:.0f} s in all (`bench/error/peer_best.py`); plots "
         f"`bench/results/error/peer-best-<scene>.png`.", "",
         "| scene | Mitsuba's best | its relMSE at equal time, per sampler (independent, stratified, "
         "multijitter, orthogonal, ldsampler; geomean, best = 1) | ours / its best at its time for (spp) "
         "| its time / ours to equal relMSE | the same, its loading counted (its load) | "
         "ours / its best, its loading counted | its time / ours, each seed's runs |",
         "|---|---|---|---|--:|--:|---|--:|"]
    for name, sc in R["scenes"].items():
        sco = sc["score"]
        b = sco.get(sc["best"]) if sco else None
        per = " / ".join(f"{sco[k] / b:.2f}" if sco and b else "-" for k in SAMPLERS)
        cmp_ = sc["compare"]
        marks = ", ".join(f"{m['ratio']:.2f} ({m['mitsuba_spp']})" if m["ratio"] else f"- ({m['mitsuba_spp']})"
                          for m in cmp_["at_mitsuba_times"])
        geo = f"{cmp_['time_geomean']:.2f}" if cmp_["time_geomean"] else "-"
        # a row of an earlier run of the same settings says its commit
        at = f" ({sc['commit']})" if sc.get("commit") and sc["commit"] != R["commit"] else ""
        cl = sc.get("compare_loaded")
        if cl:
            geo_l = (f"{cl['time_geomean']:.2f}" if cl["time_geomean"] else "-") + \
                f" ({sc['mitsuba'][sc['best']]['load']:.3f} s)"
            marks_l = ", ".join(f"{m['ratio']:.2f}" if m["ratio"] else "-" for m in cl["at_mitsuba_times"])
        else:
            geo_l = marks_l = "-"
        seeds = seed_range(sc.get("compare_seeds", []), lambda x: x["time_geomean"])
        L.append(f"| {name}{at} | {sc['best']} | {per} | {marks} | {geo} | {geo_l} | {marks_l} | {seeds} |")
    return "\n".join(L)


def host_name():
    """The processor and its core count, as /proc/cpuinfo names them: a
    table's times are this host's."""
    try:
        with open("/proc/cpuinfo") as f:
            model = next((ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), "?")
    except OSError:
        model = "?"
    return f"{model}, {os.cpu_count()} cores"


def write_results_md(text):
    path = os.path.join(S.ROOT, "bench", "RESULTS.md")
    with open(path) as f:
        md = f.read()
    block = f"{MARK_BEGIN}\n{text}\n{MARK_END}"
    if MARK_BEGIN in md:
        md = re.sub(re.escape(MARK_BEGIN) + ".*?" + re.escape(MARK_END), lambda _: block, md, flags=re.S)
    else:
        md = md.rstrip("\n") + "\n\n## Equal time against Mitsuba 3 at its best (`bench/error/peer_best.py`)\n\n" + \
            block + "\n"
    with open(path, "w") as f:
        f.write(md)


def main():
    if "--from-json" in sys.argv:
        with open(OUT) as f:
            R = json.load(f)
        text = table(R)
        print(text)
        if not S.QUICK:
            write_results_md(text)
        return
    t0 = time.time()
    os.makedirs(RUNS, exist_ok=True)
    os.makedirs(S.PLOTS, exist_ok=True)
    config = {"size": S.CFG["size"], "ref_spp": S.CFG["ref_spp"], "max_spp": MAX_SPP,
              "granularity": S.CFG["granularity"], "workers": 2, "threads": 1,
              "mitsuba_threads": 2, "seed": SEED, "seeds": SEEDS, "host": host_name()}
    R = {"benchmark": "peer-best", "config": config, "scenes": {}, "seconds": 0.0}
    if os.path.exists(OUT):
        with open(OUT) as f:
            old = json.load(f)
        if old.get("config") == config:  # the other scenes' figures stay
            R = old
        else:
            # another size, count or host: its table is kept beside, not lost
            # (a run of two scenes used to replace a 15-scene table)
            kept = f"{OUT[:-5]}-{old.get('commit', 'old')}.json"
            os.replace(OUT, kept)
            S.log(f"{S.rel(OUT)} had other settings ({old.get('config')}): kept as {S.rel(kept)}")
    R.update({"commit": S.git_commit(), "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())})
    for name in SCENES:
        flat = name.replace("/", "-")  # a file name of its own for mitsuba/NAME
        scene = S.sized_scene(name)
        ref, ref_meta = S.make_reference(flat, scene)
        r = S.rgb(S.read_exr(ref))
        ours_runs = [S.study_run(flat, scene, ref, ref_meta, "peer-best-default" + (f"-seed{k}" if k else ""),
                                 2 * MAX_SPP, S.CFG["default_mode"], 2, 1, seed=S.CFG["seed"] + k)
                     for k in range(SEEDS)]
        curves = {k: mitsuba_sweep(flat, scene, k, r, ref_meta) for k in SAMPLERS}
        best, score = best_sampler(curves)
        best_runs = [curves[best]] + [mitsuba_sweep(flat, scene, best, r, ref_meta, k) for k in range(1, SEEDS)]
        ours, mits = mean_ours(ours_runs), mean_mitsuba(best_runs)
        cmp_ = compare(ours, mits)
        cmp_loaded = compare_loaded(ours, mits)
        per_seed = [compare(o, m) for o, m in zip(ours_runs, best_runs)]
        plot(name, ours, dict(curves, **{best: mits}), best,
             os.path.join(S.PLOTS, f"peer-best-{flat}.png"), ref_meta)
        R["scenes"][name] = {
            "best": best, "score": score, "compare": cmp_, "compare_loaded": cmp_loaded,
            "seeds": SEEDS, "compare_seeds": per_seed,
            "ours": {"t": ours["t"].tolist(), "relmse": ours["relmse"].tolist(),
                     "runs": [{"seed": S.CFG["seed"] + k, "t": o["t"].tolist(), "n": o["n"].tolist(),
                               "relmse": o["relmse"].tolist(), "command": o["command"],
                               "summary": o["summary"], "stats": o["stats"]}
                              for k, o in enumerate(ours_runs)]},
            "mitsuba": {k: {"runs": c["runs"], "stats": c["stats"], "version": c["version"],
                            "load": c["load"]}
                        for k, c in curves.items()},
            "mitsuba_best_seeds": [{"seed": SEED + k, "runs": c["runs"], "stats": c["stats"]}
                                   for k, c in enumerate(best_runs)],
            "mitsuba_best_mean": mits["runs"],
            "reference": {"exr": S.rel(ref), "relmse_est": ref_meta["relmse_est"]}}
        S.log(f"{name}: Mitsuba's best {best}; ours/its {[m['ratio'] for m in cmp_['at_mitsuba_times']]}, "
              f"its time/ours {cmp_['time_geomean']}")
        R["scenes"][name]["commit"] = R["commit"]
    R["seconds"] = R.get("seconds", 0.0) + time.time() - t0
    with open(OUT, "w") as f:
        json.dump(R, f, indent=1, default=float)
    text = table(R)
    print(text)
    if not S.QUICK:
        write_results_md(text)


if __name__ == "__main__":
    main()
