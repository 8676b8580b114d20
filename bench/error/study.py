#!/usr/bin/env python3
"""make bench-error: rendering error against wall time and samples (issue 4, section 3).

Run through bench/error/run.sh (it sets up bench/venv with Mitsuba 3, numpy and
matplotlib). Steps:

 1. References: each scene (a copy resized to VB_STUDY_SIZE under bench/work/error/)
    rendered uniformly at VB_STUDY_REF_SPP as two independent halves (seeds 1000001
    and 1000002), averaged, cached in bench/refs/ with a JSON that holds the commands
    and the reference's own estimated error (from the difference of the halves).
 2. Study runs, 2 workers x 1 thread, seed 7, --reference REF: uniform at
    VB_STUDY_UNIFORM_SPP; every adaptive mode (thesis, variance, relerr) in two
    settings: "long" (max VB_STUDY_ADAPTIVE_SPP, VB_STUDY_UNIFORM_LAYERS uniform
    layers) and "5.3.2" (max VB_STUDY_THESIS_SPP, the default half uniform layers,
    the thesis's section 5.3.2). Each run's OUT.error.json is its error curve.
 2b. The same with the independent sampler (--sampler independent): uniform, and
    the default mode (relerr) at the long setting.
 3. Mitsuba 3 peer on every scene (bench/peer/mitsuba_peer.py, VB_STUDY_MITSUBA_SAMPLER):
    agreement of high-count renders with our reference, a timed sweep, and our runs
    against it at equal time (2 cores each): our relMSE at Mitsuba's 256- and
    1024-spp times, and time to equal relMSE.
 4. --target-error at E = 0.02, 0.05, 0.1: bench/error/target.py (its own
    references, candidate rules simulated on the master's layer means, the real
    master checked against the simulation); writes bench/results/target.json.
 4b. Options the thesis left open (issue 4, section 2), modes thesis and relerr at the long
    setting: --uniform-layers 2, half the layers, --random-selection, --dilate against the long runs
    ("base", reused) and uniform; blotch share and base-vs-dilate heat maps. Only with
    VB_STUDY_OPTIONS=1 (else the last measured table is carried over, with its commit);
    `study.py --only options` runs this part alone on top of bench/results/error.json.
 5. bench/results/error.json, PNG plots under bench/results/error/, the bench/RESULTS.md
    section between <!-- bench:error:begin/end -->, tables printed.

Errors are reported "reference-corrected": the relMSE (MSE) against the reference
minus the reference's own estimated relMSE (MSE). Both are kept in the JSON.
"""
import hashlib
import json
import math
import os
import platform
import re
import resource
import shutil
import statistics
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
os.chdir(ROOT)
VB = os.path.join(ROOT, "bin", "vbrender")
T_START = time.time()


def env_int(name, default):
    return int(os.environ.get(name, default))


def env_float(name, default):
    return float(os.environ.get(name, default))


QUICK = os.environ.get("VB_STUDY_QUICK", "0") == "1"
CFG = {
    "quick": QUICK,
    "size": env_int("VB_STUDY_SIZE", 64 if QUICK else 128),
    "ref_spp": env_int("VB_STUDY_REF_SPP", 2048 if QUICK else 16384),
    "uniform_spp": env_int("VB_STUDY_UNIFORM_SPP", 256 if QUICK else 2048),
    "adaptive_spp": env_int("VB_STUDY_ADAPTIVE_SPP", 512 if QUICK else 4096),
    "adaptive_uniform_layers": env_int("VB_STUDY_UNIFORM_LAYERS", 2 if QUICK else 8),
    "thesis_spp": env_int("VB_STUDY_THESIS_SPP", 256 if QUICK else 1024),
    "granularity": 32,
    "workers": 2,
    "threads": 2,
    "seed": 7,
    "ref_seeds": [1000001, 1000002],
    "confidence": env_float("VB_STUDY_TARGET_C", 0.95),
    # sample counts multijitter takes (a x a or a x (a+1)), about 2x apart
    "mitsuba_spps": [int(x) for x in os.environ.get(
        "VB_STUDY_MITSUBA_SPPS", "16,30,64,132,256" if QUICK else "16,30,64,132,256,506,1024,2070").split(",")],
    "mitsuba_agree_spp": env_int("VB_STUDY_AGREE_SPP", 256 if QUICK else 1024),
    "mitsuba_agree_passes": env_int("VB_STUDY_AGREE_PASSES", 4 if QUICK else 8),
    "mitsuba_seed": 500,
    "quiet_wait_s": env_float("VB_STUDY_QUIET_WAIT", 30),
    "quiet_budget_s": env_float("VB_STUDY_QUIET_BUDGET", 240),
    "quiet_cores": 0.3,
    "busy_retry_cores": 0.25,
    "scenes": os.environ.get("VB_STUDY_SCENES",
                             "cornell-box,cornell-glass,happy-buddha,caustic,dark-bright").split(","),
    # Mitsuba at its best: multijitter had the lowest relMSE at equal time on
    # the Cornell box and the glass scene (bench/peer/README.md)
    "mitsuba_sampler": os.environ.get("VB_STUDY_MITSUBA_SAMPLER", "multijitter"),
    "mitsuba_marks": [256, 1024],
    "default_mode": "relmse",  # common/defaults.h JOB_DEFAULT_ADAPTIVE
}
MODES = ["thesis", "variance", "relerr", "relmse"]
INDEP = ["--sampler", "independent"]
HARD = {"caustic", "dark-bright"}
EPS = 1e-2          # compare.h COMPARE_EPS
WORK = os.path.join(ROOT, "bench", "work", "error")
# The quick smoke run writes under bench/work/ (git-ignored), never over the full results.
RESULTS_JSON = os.path.join(WORK, "quick", "error.json") if QUICK else \
    os.path.join(ROOT, "bench", "results", "error.json")
PLOTS = os.path.join(WORK, "quick", "error") if QUICK else os.path.join(ROOT, "bench", "results", "error")
REFS = os.path.join(ROOT, "bench", "refs")
# the quick run's images apart from the full run's (the options study reads the long runs' images)
RUNS = os.path.join(WORK, "quick", "runs") if QUICK else os.path.join(WORK, "runs")
UPDATE_README = os.environ.get("VB_STUDY_README", "0" if QUICK else "1") == "1"


def log(msg):
    print(f"[{time.time() - T_START:7.1f} s] {msg}", file=sys.stderr, flush=True)


# ---------------------------------------------------------------- EXR I/O
import mitsuba as mi  # noqa: E402  (scalar variant, for Bitmap only)

mi.set_variant("scalar_rgb")


def read_exr(path):
    b = mi.Bitmap(path)
    names = [f.name for f in b.struct_()]
    a = np.array(b, dtype=np.float64)
    if a.ndim == 2:
        a = a[:, :, None]
    return {n: a[:, :, i] for i, n in enumerate(names)}


def write_exr(path, chans):
    names = list(chans)
    arr = np.stack([chans[n] for n in names], axis=2).astype(np.float32)
    tmp = path + ".tmp.exr"
    mi.Bitmap(arr, mi.Bitmap.PixelFormat.MultiChannel, names).write(tmp)
    os.replace(tmp, path)


def rgb(ch):
    return np.stack([ch["R"], ch["G"], ch["B"]], axis=2)


def lum(x):
    return 0.3 * x[..., 0] + 0.59 * x[..., 1] + 0.11 * x[..., 2]


def relmse(a, r):
    return float(np.mean((a - r) ** 2 / (r * r + EPS)))


def mse(a, r):
    return float(np.mean((a - r) ** 2))


# ---------------------------------------------------------------- CPU accounting
HZ = os.sysconf("SC_CLK_TCK")
NCPU = os.cpu_count() or 1


def cpu_busy():
    with open("/proc/stat") as f:
        v = [int(x) for x in f.readline().split()[1:]]
    busy = v[0] + v[1] + v[2] + v[5] + v[6] + (v[7] if len(v) > 7 else 0)
    return busy, busy + v[3] + v[4]


QUIET_SPENT = [0.0]


def wait_quiet():
    """Waits (at most quiet_wait_s, quiet_budget_s over the whole study) until other
    processes use < quiet_cores cores."""
    t0 = time.time()
    cores = None
    while True:
        b0, a0 = cpu_busy()
        time.sleep(1.0)
        b1, a1 = cpu_busy()
        cores = NCPU * (b1 - b0) / max(1, a1 - a0)
        waited = time.time() - t0
        if cores < CFG["quiet_cores"] or waited >= CFG["quiet_wait_s"] or \
                QUIET_SPENT[0] + waited >= CFG["quiet_budget_s"]:
            QUIET_SPENT[0] += max(0.0, waited - 1.0)
            return {"waited_s": round(waited, 1), "busy_cores_before": round(cores, 2)}


def run_measured(cmd, timed):
    """Runs cmd; returns (CompletedProcess, stats) with wall, our CPU and other CPU."""
    quiet = wait_quiet() if timed else None
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    b0, _ = cpu_busy()
    w0 = time.perf_counter()
    p = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - w0
    b1, _ = cpu_busy()
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    ours = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    other = max(0.0, (b1 - b0) / HZ - ours)
    st = {"wall_s": wall, "cpu_s": ours, "other_cpu_cores": other / max(wall, 1e-9), "quiet": quiet}
    if p.returncode != 0:
        sys.stderr.write(p.stdout + p.stderr)
        raise SystemExit(f"command failed ({p.returncode}): {' '.join(cmd)}")
    return p, st


# ---------------------------------------------------------------- scenes and references
def sha256_file(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        h.update(f.read())
    return h.hexdigest()


def shipped_scenes():
    """Every shipped scene: ours (scenes/*.json, by name), then Mitsuba's
    (scenes/mitsuba/*.xml, as mitsuba/NAME)."""
    return (sorted(f[:-5] for f in os.listdir(os.path.join(ROOT, "scenes")) if f.endswith(".json")) +
            sorted("mitsuba/" + f[:-4] for f in os.listdir(os.path.join(ROOT, "scenes", "mitsuba"))
                   if f.endswith(".xml")))


def sized_scene(name):
    """The scene at the study's size: scenes/NAME.json, or for mitsuba/NAME
    Mitsuba's file scenes/mitsuba/NAME.xml (sized_xml)."""
    return sized_xml(name) if name.startswith("mitsuba/") else sized_json(name)


def sized_xml(name, size=None, folder=None):
    """A copy of scenes/NAME.xml at the study's size, or size ($res), in
    the study's scene folder, or folder, that finds its files where the
    original does (a <path> to its folder, which both renderers read)."""
    size = CFG["size"] if size is None else size
    folder = os.path.join(WORK, "scenes") if folder is None else folder
    src = os.path.join(ROOT, "scenes", name + ".xml")
    with open(src) as f:
        text = f.read()
    text, n = re.subn(r'(<default\s+name="res"\s+value=")[^"]*"', r'\g<1>%d"' % size, text)
    if n != 1:
        raise SystemExit(f"{src}: no <default name=\"res\"> to set the size by")
    text = re.sub(r"(<scene\b[^>]*>)", r'\1\n    <path value="%s"/>' % os.path.dirname(src), text, count=1)
    os.makedirs(folder, exist_ok=True)
    dst = os.path.join(folder, f"{name.replace('/', '-')}-{size}.xml")
    if not os.path.exists(dst) or open(dst).read() != text:
        with open(dst, "w") as f:
            f.write(text)
    return dst


def sized_json(name):
    src = os.path.join(ROOT, "scenes", f"{name}.json")
    with open(src) as f:
        d = json.load(f)
    d["camera"]["width"] = d["camera"]["height"] = CFG["size"]
    for sh in d["shapes"]:
        if "file" in sh and not os.path.isabs(sh["file"]):
            sh["file"] = os.path.normpath(os.path.join(os.path.dirname(src), sh["file"]))
    os.makedirs(os.path.join(WORK, "scenes"), exist_ok=True)
    dst = os.path.join(WORK, "scenes", f"{name}-{CFG['size']}.json")
    text = json.dumps(d, indent=1)
    if not os.path.exists(dst) or open(dst).read() != text:
        with open(dst, "w") as f:
            f.write(text)
    return dst


def vb_cmd(scene, out, spp, adaptive, seed, workers, threads, extra=(), reference=None):
    c = [VB, "render", scene, "-o", out, "--spp", str(spp), "--granularity", str(CFG["granularity"]),
         "--adaptive", adaptive, "--seed", str(seed), "--workers", str(workers),
         "--threads", str(threads), "--progress", "none"] + list(extra)
    if reference:
        c += ["--reference", reference]
    return c


def rel(p):
    return os.path.relpath(p, ROOT)


def make_reference(name, scene):
    """Two independent uniform halves, averaged; cached under bench/refs/."""
    spp = CFG["ref_spp"]
    half = spp // 2
    base = f"{name}-{CFG['size']}x{CFG['size']}-{spp}spp"
    exr = os.path.join(REFS, base + ".exr")
    meta_path = os.path.join(REFS, base + ".json")
    scene_hash = sha256_file(scene)
    if os.path.exists(exr) and os.path.exists(meta_path) and os.environ.get("VB_STUDY_REFRESH_REFS") != "1":
        with open(meta_path) as f:
            meta = json.load(f)
        if meta.get("scene_sha256") == scene_hash and meta.get("seeds") == CFG["ref_seeds"]:
            log(f"reference {rel(exr)}: cached")
            meta["cached"] = True
            return exr, meta
    os.makedirs(REFS, exist_ok=True)
    halves, cmds, secs = [], [], []
    for k, seed in enumerate(CFG["ref_seeds"]):
        out = os.path.join(WORK, "refs", f"{base}-half{k}.exr")
        os.makedirs(os.path.dirname(out), exist_ok=True)
        cmd = vb_cmd(scene, out, half, "none", seed, CFG["workers"], CFG["threads"])
        log(f"reference {name} half {k}: {half} spp, seed {seed}")
        _, st = run_measured(cmd, timed=False)
        cmds.append(" ".join(rel(x) if x.startswith(ROOT) else x for x in cmd))
        secs.append(round(st["wall_s"], 2))
        halves.append(read_exr(out))
    h1, h2 = rgb(halves[0]), rgb(halves[1])
    r = 0.5 * (h1 + h2)
    var_ref = (h1 - h2) ** 2 / 4.0        # unbiased per pixel and channel, 1 dof
    lum_var = 0.25 * (halves[0]["variance"] + halves[1]["variance"])
    write_exr(exr, {"R": r[..., 0], "G": r[..., 1], "B": r[..., 2],
                    "samples": halves[0]["samples"] + halves[1]["samples"], "variance": lum_var})
    meta = {
        "scene": rel(scene), "scene_sha256": scene_hash, "width": CFG["size"], "height": CFG["size"],
        "spp": 2 * half, "seeds": CFG["ref_seeds"], "commands": cmds, "seconds": secs,
        "how": "mean of the two halves (each --adaptive none, half the spp, its own seed); "
               "study runs use seed %d" % CFG["seed"],
        # E[(h1-h2)^2/4] is the variance of the mean of the halves, per pixel and channel.
        "relmse_est": float(np.mean(var_ref / (r * r + EPS))),
        "mse_est": float(np.mean(var_ref)),
        "relmse_est_lum_variance_channel": float(np.mean(lum_var / (lum(r) ** 2 + EPS))),
        "half_vs_half_relmse": relmse(h1, h2),
        "mean_rgb": [float(x) for x in r.reshape(-1, 3).mean(axis=0)],
        "vbrender_commit": git_commit(),
        "cached": False,
    }
    meta["rmse_est"] = math.sqrt(meta["mse_est"])
    with open(meta_path, "w") as f:
        json.dump(meta, f, indent=1)
    log(f"reference {rel(exr)}: own relMSE ~{meta['relmse_est']:.3g}")
    return exr, meta


def image_bias(exr, ref_ch):
    """The image's mean luminance against the reference's: relative difference
    and in standard errors (from the per-pixel relMSE spread, a loose bound)."""
    a, r = lum(rgb(read_exr(exr))), lum(rgb(ref_ch))
    d = a - r
    se = float(np.std(d) / math.sqrt(d.size))
    return {"relative": float(d.mean() / max(r.mean(), 1e-12)), "in_se": float(d.mean() / max(se, 1e-30))}


def git_commit():
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              cwd=ROOT).stdout.strip()
    except OSError:
        return ""


# ---------------------------------------------------------------- study runs
def load_series(errjson, ref_meta):
    with open(errjson) as f:
        d = json.load(f)
    job = d.get("job", {})
    pts = [p for p in d["series"] if p[1] > 0 and p[0] > 0]
    if job.get("samples") and (not pts or job["samples"] > pts[-1][1]) and "relmse" in job:
        pts.append([job["seconds"], job["samples"], job["relmse"], job["rmse"], job.get("rays", 0)])
    pts.sort(key=lambda p: (p[0], p[1]))
    t = np.array([p[0] for p in pts], dtype=float)
    n = np.array([p[1] for p in pts], dtype=float)
    r_raw = np.array([p[2] for p in pts], dtype=float)
    e_raw = np.array([p[3] for p in pts], dtype=float)
    # rays traced so far (a fifth column since the result records carry them)
    rays = np.array([p[4] if len(p) > 4 else np.nan for p in pts], dtype=float)
    r = np.maximum(r_raw - ref_meta["relmse_est"], 1e-12)
    e = np.sqrt(np.maximum(e_raw ** 2 - ref_meta["mse_est"], 1e-24))
    return {"t": t, "n": n, "rays": rays, "relmse": r, "rmse": e, "relmse_raw": r_raw, "rmse_raw": e_raw,
            "job": job}


def study_run(name, scene, ref, ref_meta, tag, spp, adaptive, workers, threads, extra=(), seed=None):
    out = os.path.join(RUNS, f"{name}-{tag}.exr")
    os.makedirs(os.path.dirname(out), exist_ok=True)
    cmd = vb_cmd(scene, out, spp, adaptive, CFG["seed"] if seed is None else seed, workers, threads,
                 extra, ref)
    best = None
    for attempt in range(2):
        log(f"{name} {tag}: {adaptive}, max {spp} spp {' '.join(extra)}")
        p, st = run_measured(cmd, timed=True)
        st["attempt"] = attempt
        if best is None or st["other_cpu_cores"] < best[1]["other_cpu_cores"]:
            best = (p, st, read_series_copy(out, ref_meta))
        if st["other_cpu_cores"] <= CFG["busy_retry_cores"]:
            break
        log(f"  other processes used {st['other_cpu_cores']:.2f} cores; again")
    p, st, s = best
    ch = read_exr(out)
    s.update({"tag": tag, "adaptive": adaptive, "spp": spp, "extra": list(extra), "exr": out,
              "command": " ".join(rel(x) if x.startswith(ROOT) else x for x in cmd),
              "summary": p.stderr.strip().splitlines()[-1] if p.stderr.strip() else "",
              "stats": st, "samples_map": ch["samples"],
              "final_relmse_exr_raw": relmse(rgb(ch), rgb(read_exr(ref)))})
    s["cpu_utilization"] = st["cpu_s"] / max(1e-9, st["wall_s"] * threads)
    heat = out[:-4] + "-samples.png"
    if os.path.exists(heat) and adaptive != "none" and not tag.startswith(("peer", "opt-")):
        os.makedirs(os.path.join(PLOTS, "heat"), exist_ok=True)
        shutil.copy(heat, os.path.join(PLOTS, "heat", f"{name}-{tag}.png"))
    return s


def read_series_copy(out, ref_meta):
    return load_series(out[:-4] + ".error.json", ref_meta)


# ---------------------------------------------------------------- curve arithmetic
def interp_loglog(x, y, xq):
    if xq is None or len(x) == 0 or xq < x[0] * (1 - 1e-9) or xq > x[-1] * (1 + 1e-9):
        return None
    xq = min(max(xq, x[0]), x[-1])
    return float(np.exp(np.interp(np.log(xq), np.log(x), np.log(y))))


def first_reach(x, y, level):
    """First x where y falls to level (log-log interpolation), or None."""
    for i in range(len(y)):
        if y[i] <= level:
            if i == 0:
                return float(x[0])
            f = (math.log(y[i - 1]) - math.log(level)) / max(1e-300, math.log(y[i - 1]) - math.log(y[i]))
            return float(math.exp(math.log(x[i - 1]) + f * (math.log(x[i]) - math.log(x[i - 1]))))
    return None


def by_samples(s, key):
    n, y = s["n"], s[key]
    keep = np.concatenate([[True], np.diff(n) > 0])
    return n[keep], y[keep]


def compare_curves(u, a, npix):
    """Adaptive run a against uniform run u (same scene, seed, reference)."""
    res = {}
    t_eq = float(min(a["t"][-1], u["t"][-1]))
    n_eq = float(min(a["n"][-1], u["n"][-1]))
    for key in ("relmse", "rmse"):
        ya = interp_loglog(a["t"], a[key], t_eq)
        yu = interp_loglog(u["t"], u[key], t_eq)
        res[f"{key}_equal_time"] = {"seconds": t_eq, "adaptive": ya, "uniform": yu,
                                    "ratio": ya / yu if ya and yu else None}
        na, ya_n = by_samples(a, key)
        nu, yu_n = by_samples(u, key)
        ya = interp_loglog(na, ya_n, n_eq)
        yu = interp_loglog(nu, yu_n, n_eq)
        res[f"{key}_equal_samples"] = {"samples": n_eq, "spp": n_eq / npix, "adaptive": ya, "uniform": yu,
                                       "ratio": ya / yu if ya and yu else None}
    # worst equal-time ratio once the skip rule is in effect
    ul = a["job"].get("uniform_layers", 0)
    n_start = npix * ul * CFG["granularity"]
    idx = np.nonzero(a["n"] >= n_start)[0]
    t0 = float(a["t"][idx[0]]) if len(idx) else t_eq
    worst = None
    if t0 < t_eq:
        for tq in np.geomspace(t0, t_eq, 40):
            ya, yu = interp_loglog(a["t"], a["relmse"], tq), interp_loglog(u["t"], u["relmse"], tq)
            if ya and yu and (worst is None or ya / yu > worst["ratio"]):
                worst = {"seconds": float(tq), "ratio": ya / yu}
    res["relmse_worst_equal_time_after_uniform_layers"] = worst
    # time and samples to reach uniform's final relMSE
    u_final = float(u["relmse"][-1])
    ta = first_reach(a["t"], a["relmse"], u_final)
    na_s, ya_s = by_samples(a, "relmse")
    na = first_reach(na_s, ya_s, u_final)
    res["reach_uniform_final"] = {
        "uniform_relmse": u_final, "uniform_seconds": float(u["t"][-1]), "uniform_samples": float(u["n"][-1]),
        "seconds": ta, "time_share": ta / float(u["t"][-1]) if ta else None,
        "samples": na, "samples_share": na / float(u["n"][-1]) if na else None}
    # time uniform needs to reach the adaptive run's final relMSE
    a_final = float(a["relmse"][-1])
    tu = first_reach(u["t"], u["relmse"], a_final)
    res["uniform_to_adaptive_final"] = {"adaptive_relmse": a_final, "adaptive_seconds": float(a["t"][-1]),
                                        "uniform_seconds": tu,
                                        "speedup": tu / float(a["t"][-1]) if tu else None}
    # time to equal relMSE at the lowest relMSE both runs reach: adaptive time / uniform time
    level = max(u_final, a_final)
    ta = first_reach(a["t"], a["relmse"], level)
    tu = first_reach(u["t"], u["relmse"], level)
    res["equal_relmse_time"] = {"relmse": level, "adaptive_seconds": ta, "uniform_seconds": tu,
                                "time_share": ta / tu if ta and tu else None}
    return res


# ---------------------------------------------------------------- plots
def curve_slope(s, key):
    """Log-log slope of error against samples over the run's last decade
    (-1: Monte Carlo's rate; steeper: the sampler's stratification pays)."""
    n, y = by_samples(s, key)
    keep = (n >= n[-1] / 10) & (y > 0)
    if keep.sum() < 3:
        return None
    return float(np.polyfit(np.log(n[keep]), np.log(y[keep]), 1)[0])


def plot_scene(name, runs, ref_meta, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    colors = {"none": "k", "thesis": "C0", "variance": "C1", "relerr": "C2", "relmse": "C3"}
    fig, axs = plt.subplots(2, 2, figsize=(9, 7))
    for (row, key) in enumerate(("relmse", "rmse")):
        for (col, xk) in enumerate(("t", "n")):
            ax = axs[row][col]
            for tag, s in runs.items():
                ls = ":" if tag.endswith("-indep") else "--" if tag.startswith("t532") else "-"
                x = s[xk] / (1 if xk == "t" else s["npix"])
                slope = curve_slope(s, key)
                ax.loglog(x, s[key], ls, color=colors[s["adaptive"]], lw=1.3,
                          label=s["label"] + (f", slope {slope:.2f}" if slope is not None and xk == "n" else ""))
            refv = ref_meta["relmse_est"] if key == "relmse" else ref_meta["rmse_est"]
            ax.axhline(refv, color="0.6", ls=":", lw=1, label="reference's own error")
            ax.set_xlabel("seconds" if xk == "t" else "samples per pixel (mean)")
            ax.set_ylabel("relMSE" if key == "relmse" else "RMSE")
            ax.grid(True, which="both", alpha=0.25)
    axs[0][0].legend(fontsize=7)
    fig.suptitle(f"{name}: error vs the reference (its own error subtracted), "
                 f"{CFG['size']}x{CFG['size']}, {CFG['workers']} workers x 1 thread", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=70)
    plt.close(fig)


def plot_heat(name, runs, ref_rgb, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    tags = [t for t in runs if runs[t]["adaptive"] != "none"]
    fig, axs = plt.subplots(2, 1 + len(MODES), figsize=(12, 5))
    img = np.clip(ref_rgb / (1 + ref_rgb), 0, 1) ** (1 / 2.2)
    axs[0][0].imshow(img, interpolation="nearest")
    axs[0][0].set_title("reference (Reinhard)", fontsize=8)
    u = [t for t in runs if runs[t]["adaptive"] == "none"]
    if u:
        s = runs[u[0]]
        err = np.sqrt(np.mean((rgb(read_exr(s["exr"])) - ref_rgb) ** 2 / (ref_rgb ** 2 + EPS), axis=2))
        im = axs[1][0].imshow(err, cmap="magma", vmax=np.percentile(err, 99), interpolation="nearest")
        axs[1][0].set_title("uniform: per-pixel rel. error", fontsize=8)
        fig.colorbar(im, ax=axs[1][0], fraction=0.046)
    for row, prefix in enumerate(("long", "t532")):
        sel = [t for t in tags if t.startswith(prefix)]
        vmax = max([runs[t]["samples_map"].max() for t in sel] or [1])
        for col, t in enumerate([t for t in sel if not t.endswith("-indep")][:len(MODES)]):
            s = runs[t]
            ax = axs[row][col + 1]
            im = ax.imshow(s["samples_map"], cmap="viridis", vmin=0, vmax=vmax, interpolation="nearest")
            ax.set_title(f"{s['label']}: mean {s['samples_map'].mean():.0f} spp", fontsize=8)
            fig.colorbar(im, ax=ax, fraction=0.046)
    for ax in axs.flat:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(f"{name}: samples per pixel", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=56)
    plt.close(fig)


def plot_peer(name, ours, mits, path, ref_meta):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4.2))
    for s, c in ours:
        ax.loglog(s["t"], s["relmse"], "-", color=c, label=s["label"])
    ax.loglog(mits["t"], mits["relmse"], "o-", color="C3",
              label=f"Mitsuba 3 llvm_ad_rgb, path, {CFG['mitsuba_sampler']}")
    finish_time_plot(fig, ax, ref_meta, "seconds (2 threads)", f"{name}: relMSE against time, 2 cores each",
                     path)


def finish_time_plot(fig, ax, ref_meta, xlabel, title, path):
    """A relMSE-against-seconds plot's reference line, axes, legend and file."""
    import matplotlib.pyplot as plt
    ax.axhline(ref_meta["relmse_est"], color="0.6", ls=":", label="reference's own error")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("relMSE vs vbrender reference")
    ax.grid(True, which="both", alpha=0.25)
    ax.legend(fontsize=7)
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=70)
    plt.close(fig)


# ---------------------------------------------------------------- target error
def target_study():
    """bench/error/target.py: --target-error at E = 0.02, 0.05, 0.1 on every
    scene it knows, simulated rules and the real master (its own references)."""
    out = os.path.join(WORK, "quick", "target.json") if QUICK else \
        os.path.join(ROOT, "bench", "results", "target.json")
    env = dict(os.environ, VB_TARGET_OUT=out)
    if QUICK:
        env.setdefault("VB_TARGET_E", "0.1")
        env.setdefault("VB_TARGET_SCENES", "cornell-box,dark-bright")
    log("target error: bench/error/target.py")
    t0 = time.time()
    subprocess.run([sys.executable, os.path.join(ROOT, "bench", "error", "target.py")], check=True, env=env)
    with open(out) as f:
        T = json.load(f)
    T["seconds"] = time.time() - t0
    return T


# ---------------------------------------------------------------- options the thesis left open
OPT_MODES = ["thesis", "relerr"]
BLOCK = 8          # blotch measure: 8x8-pixel blocks
BLOTCH_K = 3.0     # a block is a blotch when its relMSE exceeds BLOTCH_K x the image's


def opt_variants():
    layers = CFG["adaptive_spp"] // CFG["granularity"]
    return [("base", f"base: {CFG['adaptive_uniform_layers']} uniform layers", None),
            ("ul2", "--uniform-layers 2", ["--uniform-layers", "2"]),
            ("ulhalf", f"--uniform-layers {layers // 2} (half)", ["--uniform-layers", str(layers // 2)]),
            ("random", "--random-selection", ["--uniform-layers", str(CFG["adaptive_uniform_layers"]),
                                              "--random-selection"]),
            ("dilate", "--dilate", ["--uniform-layers", str(CFG["adaptive_uniform_layers"]), "--dilate"])]


def curve_from_rows(run):
    rows = np.array(run["series"]["rows"], dtype=float)
    return {"t": rows[:, 0], "n": rows[:, 1], "relmse": rows[:, 2], "rmse": rows[:, 3], "job": run["job"]}


def pixel_relerr(img, ref_rgb):
    """Per-pixel relative squared error, mean over channels (the relMSE's summand)."""
    return np.mean((img - ref_rgb) ** 2 / (ref_rgb ** 2 + EPS), axis=2)


def blotch_share(e):
    """Share of BLOCKxBLOCK blocks whose mean relative squared error exceeds BLOTCH_K x the image's."""
    H, W = e.shape
    hb, wb = H // BLOCK, W // BLOCK
    b = e[:hb * BLOCK, :wb * BLOCK].reshape(hb, BLOCK, wb, BLOCK).mean(axis=(1, 3))
    return float((b > BLOTCH_K * e.mean()).mean())


def base_image(name, scene, ref, ref_meta, m, saved):
    """The long run's image: the study's own file when it is that run (size and sample count), else
    rendered again untimed (same seed and settings) for the image measures only."""
    out = os.path.join(RUNS, f"{name}-long-{m}.exr")
    ej = out[:-4] + ".error.json"
    if os.path.exists(out) and os.path.exists(ej):
        with open(ej) as f:
            job = json.load(f).get("job", {})
        if job.get("width") == CFG["size"] and job.get("samples") == saved["job"]["samples"]:
            return out, False
    out = os.path.join(RUNS, "options", f"{name}-base-{m}.exr")
    os.makedirs(os.path.dirname(out), exist_ok=True)
    cmd = vb_cmd(scene, out, CFG["adaptive_spp"], m, CFG["seed"], CFG["workers"], CFG["threads"],
                 ["--uniform-layers", str(CFG["adaptive_uniform_layers"])], ref)
    log(f"{name} options base-{m}: image again (untimed)")
    run_measured(cmd, timed=False)
    return out, True


def options_study(R, scenes, refs):
    """Flag sequence, randomised selection and dilation, each against the long runs and uniform."""
    npix = CFG["size"] ** 2
    t0 = time.time()
    O = {"modes": OPT_MODES, "variants": {k: lbl for k, lbl, _ in opt_variants()},
         "max_spp": CFG["adaptive_spp"], "blotch": {"block": BLOCK, "k": BLOTCH_K},
         "scenes": {}}
    for name, scene in scenes.items():
        ref, meta = refs[name]
        ref_rgb = rgb(read_exr(ref))
        S = R["scenes"][name]
        u = curve_from_rows(S["runs"]["uniform"])
        res, maps = {}, {}

        for m in OPT_MODES:
            res[m] = {}
            for key, lbl, extra in opt_variants():
                if extra is None:
                    saved = S["runs"][f"long-{m}"]
                    a = curve_from_rows(saved)
                    exr, again = base_image(name, scene, ref, meta, m, saved)
                    rec = {"from": f"long-{m}", "command": saved["command"], "stats": saved["stats"],
                           "image_rendered_again": again}
                else:
                    s = study_run(name, scene, ref, meta, f"opt-{key}-{m}", CFG["adaptive_spp"], m,
                                  CFG["workers"], CFG["threads"], extra)
                    a, exr = s, s["exr"]
                    rec = {"command": s["command"], "summary": s["summary"], "stats": s["stats"]}
                ch = read_exr(exr)
                rec["image_samples"] = float(ch["samples"].sum())
                e = pixel_relerr(rgb(ch), ref_rgb)
                c = compare_curves(u, a, npix)
                rec.update({
                    "job": a["job"], "mean_spp": float(a["n"][-1] / npix), "seconds": float(a["t"][-1]),
                    "relmse": float(a["relmse"][-1]),
                    "relmse_equal_time": c["relmse_equal_time"], "relmse_equal_samples": c["relmse_equal_samples"],
                    "relmse_worst_equal_time_after_uniform_layers": c["relmse_worst_equal_time_after_uniform_layers"],
                    "equal_relmse_time": c["equal_relmse_time"],
                    "blotch_share": blotch_share(e),
                })
                if extra is not None:
                    rec["series"] = {"columns": "seconds samples relmse rmse",
                                     "rows": [[round(float(x), 4), int(n), g5(y), g5(z)]
                                              for x, n, y, z in zip(a["t"], a["n"], a["relmse"], a["rmse"])]}
                res[m][key] = rec
                if key in ("base", "dilate"):
                    maps[(m, key)] = (ch["samples"], np.sqrt(e))
        O["scenes"][name] = res
        plot_options_heat(name, maps, os.path.join(PLOTS, f"{name}-dilate.png"))
    O["seconds"] = time.time() - t0
    O["commit"] = git_commit()
    O["date"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    return O


def plot_options_heat(name, maps, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axs = plt.subplots(len(OPT_MODES), 4, figsize=(9, 2.3 * len(OPT_MODES)))
    for row, m in enumerate(OPT_MODES):
        smax = max(maps[(m, k)][0].max() for k in ("base", "dilate"))
        emax = max(np.percentile(maps[(m, k)][1], 99) for k in ("base", "dilate"))
        for col, (k, what) in enumerate([("base", 0), ("dilate", 0), ("base", 1), ("dilate", 1)]):
            ax = axs[row][col]
            v = maps[(m, k)][what]
            im = ax.imshow(v, cmap="viridis" if what == 0 else "magma", vmin=0,
                           vmax=smax if what == 0 else emax, interpolation="nearest")
            ax.set_title(f"{m} {k}: " + (f"spp, mean {v.mean():.0f}" if what == 0 else "rel. error"),
                         fontsize=7)
            ax.set_xticks([])
            ax.set_yticks([])
            fig.colorbar(im, ax=ax, fraction=0.046)
    fig.suptitle(f"{name}: base ({CFG['adaptive_uniform_layers']} uniform layers) vs --dilate, samples per pixel and per-pixel "
                 f"relative error", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=50)
    plt.close(fig)


# ---------------------------------------------------------------- Mitsuba peer
def peer_agreement(name, mm, var_m, r, ref_meta):
    """Mitsuba's K-pass mean against our reference (bench/peer/check_peer.py's
    figures: relMSE against what noise alone gives, an 8x8-block z-test and
    the image means)."""
    halves = [os.path.join(WORK, "refs", f"{name}-{CFG['size']}x{CFG['size']}-{CFG['ref_spp']}spp-half{k}.exr")
              for k in (0, 1)]
    if all(os.path.exists(h) for h in halves):
        h = [rgb(read_exr(x)) for x in halves]
        var_r = (h[0] - h[1]) ** 2 / 4
    else:  # halves gone: spread the estimated reference error evenly
        var_r = np.full_like(r, ref_meta["mse_est"])
    sys.path.insert(0, os.path.join(ROOT, "bench", "peer"))
    from check_peer import agreement_figures
    f = agreement_figures(mm, var_m, r, var_r)
    f["relmse_mitsuba_vs_ref"] = f.pop("relmse")
    f["block_count"] = f.pop("blocks")
    return f


def peer(name, scene, ref, ref_meta, runs):
    """Mitsuba 3 on one scene: agreement with our reference, a timed sweep, and
    our runs (2 workers x 1 thread: the same 2 cores as its 2 threads) against
    it at equal time."""
    py = os.environ.get("MITSUBA_PEER_PYTHON", sys.executable)
    script = os.path.join(ROOT, "bench", "peer", "mitsuba_peer.py")
    size = str(CFG["size"])
    common = ["--threads", "2", "--width", size, "--height", size, "--sampler", CFG["mitsuba_sampler"]]
    r = rgb(read_exr(ref))
    out = {"sampler": CFG["mitsuba_sampler"]}
    agree_exr = os.path.join(WORK, "peer", f"{name}-mitsuba-agree.exr")
    os.makedirs(os.path.dirname(agree_exr), exist_ok=True)
    cmd = [py, script, scene, "--mode", "agree", "--spp", str(CFG["mitsuba_agree_spp"]),
           "--passes", str(CFG["mitsuba_agree_passes"]), "--seed", "900", "--out", agree_exr] + common
    log(f"{name} mitsuba agree: {CFG['mitsuba_agree_passes']} x {CFG['mitsuba_agree_spp']} spp")
    p, _ = run_measured(cmd, timed=False)
    info = json.loads(p.stdout.strip().splitlines()[-1])
    m = read_exr(agree_exr)
    var_m = np.stack([m["varR"], m["varG"], m["varB"]], axis=2)
    out["agreement"] = dict(peer_agreement(name, rgb(m), var_m, r, ref_meta), mitsuba=info,
                            mitsuba_spp_total=CFG["mitsuba_agree_spp"] * CFG["mitsuba_agree_passes"])
    sweep_dir = os.path.join(WORK, "peer", f"{name}-sweep")
    cmd = [py, script, scene, "--mode", "sweep", "--spp-list", ",".join(map(str, CFG["mitsuba_spps"])),
           "--seed", str(CFG["mitsuba_seed"]), "--out-dir", sweep_dir] + common
    best = None
    for attempt in range(2):
        log(f"{name} mitsuba sweep: spp {CFG['mitsuba_spps']}")
        p, st = run_measured(cmd, timed=True)
        st["attempt"] = attempt
        if best is None or st["other_cpu_cores"] < best[1]["other_cpu_cores"]:
            best = (p, st)
        if st["other_cpu_cores"] <= CFG["busy_retry_cores"]:
            break
        log(f"  other processes used {st['other_cpu_cores']:.2f} cores; again")
    p, st = best
    sw = json.loads(p.stdout.strip().splitlines()[-1])
    pts = []
    for run in sw["runs"]:
        rr = relmse(rgb(read_exr(run["out"])), r)
        pts.append({"spp": run["spp"], "seconds": run["seconds"], "relmse_raw": rr,
                    "relmse": max(rr - ref_meta["relmse_est"], 1e-12),
                    "samples_per_second": run["samples"] / run["seconds"]})
    out["mitsuba_sweep"] = {"runs": pts, "stats": st, "variant": sw.get("variant"), "version": sw.get("version")}
    mits = {"t": np.array([q["seconds"] for q in pts]), "relmse": np.array([q["relmse"] for q in pts])}
    out["mitsuba_samples_per_second"] = float(np.median([q["samples_per_second"] for q in pts[-3:]]))
    out["ours"] = {tag: peer_compare(s, mits, pts) for tag, s in runs.items()}
    plot_peer(name, [(s, c) for s, c in ((runs.get("uniform"), "k"),
                                         (runs.get(f"long-{CFG['default_mode']}"), "C2"),
                                         (runs.get("uniform-indep"), "0.5")) if s], mits,
              os.path.join(PLOTS, f"peer-{name}.png"), ref_meta)
    return out


def peer_compare(s, mits, pts):
    """One of our runs against Mitsuba's sweep: our relMSE over Mitsuba's at
    the time Mitsuba took for each mark (256, 1024 spp), and Mitsuba's time
    over ours to equal relMSE at levels both reach."""
    c = curve_against_peer(s, mits, [q for q in pts if q["spp"] in CFG["mitsuba_marks"]])
    c["ours_samples_per_second"] = float(s["n"][-1] / s["t"][-1])
    return c


def curve_against_peer(s, mits, marks_at):
    """Our curve s (t, relmse) against a peer's (t, relmse): our relMSE over
    its at the times of its points marks_at (spp, seconds, relmse), and its
    time over ours to equal relMSE at 4 levels both reach, with their
    geometric mean."""
    marks = []
    for q in marks_at:
        ours = interp_loglog(s["t"], s["relmse"], q["seconds"])
        marks.append({"mitsuba_spp": q["spp"], "seconds": q["seconds"], "mitsuba": q["relmse"],
                      "ours": ours, "ratio": ours / q["relmse"] if ours else None})
    lo = max(float(np.min(s["relmse"])), float(np.min(mits["relmse"])))
    hi = min(float(np.max(s["relmse"])), float(np.max(mits["relmse"])))
    levels = []
    if hi > lo:
        for lev in np.geomspace(hi, lo, 6)[1:-1]:
            tm = first_reach(mits["t"], mits["relmse"], lev)
            to = first_reach(s["t"], s["relmse"], lev)
            if tm and to:
                levels.append({"relmse": float(lev), "mitsuba_s": tm, "ours_s": to, "ratio": tm / to})
    return {"at_mitsuba_times": marks, "time_levels": levels,
            "time_geomean": float(np.exp(np.mean([np.log(x["ratio"]) for x in levels]))) if levels else None}


# ---------------------------------------------------------------- tables
def fmt(x, nd=3):
    if x is None:
        return "-"
    if isinstance(x, float):
        if x != 0 and (abs(x) < 1e-2 or abs(x) >= 1e4):
            return f"{x:.{nd - 1}e}"
        return f"{x:.{nd}g}"
    return str(x)


def options_reading(O):
    """The reading of the options table; its figures come from O (equal-time relMSE ratios)."""
    def r(sc, m, k):
        return fmt(O["scenes"][sc][m][k]["relmse_equal_time"]["ratio"], 2)

    def b(sc, m, k):
        return f"{100 * O['scenes'][sc][m][k]['blotch_share']:.1f} %"
    if not all(x in O["scenes"] for x in ("cornell-box", "happy-buddha", "caustic", "dark-bright")):
        return ""
    half = O["variants"]["ulhalf"].split()[1]
    return (
        "How to read it. *Flag sequence.* The skip rule judges each pixel by the variance it saw in the "
        "uniform layers. After only 2 layers (64 samples) that estimate is poor where light arrives rarely, "
        "so such pixels are skipped too early: the run is shorter and wins where a few obvious noisy pixels "
        f"dominate (caustic: thesis {r('caustic', 'thesis', 'ul2')} vs {r('caustic', 'thesis', 'base')}, "
        f"relerr {r('caustic', 'relerr', 'ul2')} vs {r('caustic', 'relerr', 'base')}) but loses where dim "
        f"pixels are the noisy ones (dark-bright: thesis {r('dark-bright', 'thesis', 'ul2')} vs "
        f"{r('dark-bright', 'thesis', 'base')}, relerr {r('dark-bright', 'relerr', 'ul2')} vs "
        f"{r('dark-bright', 'relerr', 'base')}). Half the layers uniform ({half} layers: uniform's whole "
        "budget before any pixel is skipped) makes the run uniform up to the point of comparison, so its "
        "ratio is about 1 everywhere: no losses (dark-bright "
        f"{r('dark-bright', 'thesis', 'ulhalf')}), but no gains either (caustic "
        f"{r('caustic', 'thesis', 'ulhalf')} instead of {r('caustic', 'thesis', 'base')}); 8 layers is the "
        "useful middle. *Randomised selection* and *dilation* both give samples to pixels the rule would "
        "skip (mean spp up to several times the base's), which moves the result toward uniform: they help "
        "where the rule starves pixels (Cornell box thesis "
        f"{r('cornell-box', 'thesis', 'random')} / {r('cornell-box', 'thesis', 'dilate')} vs "
        f"{r('cornell-box', 'thesis', 'base')}, happy-buddha thesis {r('happy-buddha', 'thesis', 'random')} / "
        f"{r('happy-buddha', 'thesis', 'dilate')} vs {r('happy-buddha', 'thesis', 'base')}) and hurt where "
        f"concentrating samples pays (caustic relerr {r('caustic', 'relerr', 'random')} / "
        f"{r('caustic', 'relerr', 'dilate')} vs {r('caustic', 'relerr', 'base')}). Neither rescues thesis on "
        f"dark-bright ({r('dark-bright', 'thesis', 'random')} / {r('dark-bright', 'thesis', 'dilate')}): the "
        "fault there is the absolute-variance criterion, not how pixels are picked. *Blotches.* The base "
        "selection is speckled pixel by pixel, which 8x8 blocks average out; dilation fills the selected "
        "regions solid (heat maps), so the error drops inside them and the blocks outside stand out more "
        f"(Cornell box relerr {b('cornell-box', 'relerr', 'base')} to {b('cornell-box', 'relerr', 'dilate')}, "
        f"dark-bright relerr {b('dark-bright', 'relerr', 'base')} to {b('dark-bright', 'relerr', 'dilate')}); "
        f"only dark-bright thesis improves ({b('dark-bright', 'thesis', 'base')} to "
        f"{b('dark-bright', 'thesis', 'dilate')}). At this size and G = 32 we see no blotches or seams that "
        "dilation would remove.")


def tables(R):
    L = []
    c = R["config"]
    L.append(f"Error against a reference, {c['size']}x{c['size']}, {c['workers']} workers x 1 thread, "
             f"G = {c['granularity']}, seed {c['seed']}; references {c['ref_spp']} spp (two halves, seeds "
             f"{c['ref_seeds'][0]}/{c['ref_seeds'][1]}), their own error subtracted. Uniform: "
             f"{c['uniform_spp']} spp. Adaptive \"long\": max {c['adaptive_spp']} spp, "
             f"{c['adaptive_uniform_layers']} uniform layers. \"5.3.2\": max {c['thesis_spp']} spp, "
             f"half the layers uniform (thesis section 5.3.2). Ratios are adaptive / uniform "
             f"(below 1: adaptive is better). {R['machine']}; commit {R['commit']}; "
             f"whole study {R['total_seconds']:.0f} s{' (VB_STUDY_QUICK=1)' if c['quick'] else ''}.")
    L.append("")
    L.append("| scene | mode | mean spp | time to uniform's final relMSE (share of uniform's time) "
             "| time to equal relMSE, lowest both reach: adaptive / uniform "
             "| relMSE ratio, equal time (worst after the uniform layers) | relMSE ratio, equal samples "
             "| RMSE ratio, equal time |")
    L.append("|---|---|--:|--:|--:|--:|--:|--:|")
    for sc, S in R["scenes"].items():
        u = S["runs"]["uniform"]
        L.append(f"| {sc} | uniform | {u['mean_spp']:.0f} | {u['seconds']:.2f} s (1) | 1 | 1 | 1 | 1 |")
        for tag in [f"long-{m}" for m in MODES]:
            a = S["comparisons"][tag]
            run = S["runs"][tag]
            reach = a["reach_uniform_final"]
            rt = (f"{reach['seconds']:.2f} s ({reach['time_share']:.2f})" if reach["seconds"]
                  else f"not reached (final {run['relmse']:.3g} vs {reach['uniform_relmse']:.3g})")
            w = a["relmse_worst_equal_time_after_uniform_layers"]
            eq = a["equal_relmse_time"]
            L.append(f"| {sc} | {tag[5:]} | {run['mean_spp']:.0f} | {rt} | "
                     f"{fmt(eq['time_share'])} @ {eq['relmse']:.3g} | "
                     f"{fmt(a['relmse_equal_time']['ratio'])} ({fmt(w['ratio']) if w else '-'}) | "
                     f"{fmt(a['relmse_equal_samples']['ratio'])} | {fmt(a['rmse_equal_time']['ratio'])} |")
    L.append("")
    L.append(f"Thesis section 5.3.2 with error measured: max {c['thesis_spp']} spp adaptive against uniform "
             f"at the same total samples (from the uniform run's curve).")
    L.append("")
    L.append("| scene | mode | mean spp | relMSE adaptive | relMSE uniform, same total | ratio | RMSE ratio "
             "| relMSE ratio, equal time (worst) |")
    L.append("|---|---|--:|--:|--:|--:|--:|--:|")
    for sc, S in R["scenes"].items():
        for m in MODES:
            a = S["comparisons"][f"t532-{m}"]
            run = S["runs"][f"t532-{m}"]
            es = a["relmse_equal_samples"]
            w = a["relmse_worst_equal_time_after_uniform_layers"]
            L.append(f"| {sc} | {m} | {run['mean_spp']:.0f} | {fmt(es['adaptive'])} | {fmt(es['uniform'])} | "
                     f"{fmt(es['ratio'])} | {fmt(a['rmse_equal_samples']['ratio'])} | "
                     f"{fmt(a['relmse_equal_time']['ratio'])} ({fmt(w['ratio']) if w else '-'}) |")
    L.append("")
    L += sampler_mode_table(R)
    L += target_table(R.get("target"))
    busy = R.get("busy_runs", [])
    if busy:
        L.append("")
        L.append(f"Timed runs during which other processes used over {c['busy_retry_cores']} cores "
                 f"(after one retry): {', '.join(busy)}; their time axes are stretched.")
    O = R.get("options")
    if O:
        keys = list(O["variants"])
        L.append("")
        L.append("Options the thesis left open (issue 4, section 2), modes thesis and relerr, max "
                 f"{O['max_spp']} spp, same scenes, references, seed and workers as above; \"base\" is the "
                 "long run above, its curve reused"
                 + (" (its image rendered again, untimed, for the blotch measure: same sample counts)"
                    if any(S[m]["base"].get("image_rendered_again") and
                           S[m]["base"]["image_samples"] == S[m]["base"]["job"]["samples"]
                           for S in O["scenes"].values() for m in O["modes"]) else "")
                 + ". Each cell: relMSE / uniform's at equal time, at equal "
                 "samples, and the mean spp. Blotches: share of "
                 f"{O['blotch']['block']}x{O['blotch']['block']} blocks whose relMSE (against the reference, "
                 f"its own noise included) exceeds {O['blotch']['k']:g}x the image's. Options run in "
                 f"{O['seconds']:.0f} s (commit {O['commit']}).")
        L.append("")
        lbl = dict(O["variants"], base=f"base: {c['adaptive_uniform_layers']} uniform layers")
        L.append("| scene | mode | " + " | ".join(lbl[k] for k in keys)
                 + " | blotches: base / dilate |")
        L.append("|---|---|" + "--:|" * len(keys) + "--:|")
        for sc, S in O["scenes"].items():
            for m in O["modes"]:
                cells = []
                for k in keys:
                    q = S[m][k]
                    cells.append(f"{fmt(q['relmse_equal_time']['ratio'], 2)} / "
                                 f"{fmt(q['relmse_equal_samples']['ratio'], 2)} ({q['mean_spp']:.0f})")
                L.append(f"| {sc} | {m} | " + " | ".join(cells) + " | "
                         f"{100 * S[m]['base']['blotch_share']:.1f} % / {100 * S[m]['dilate']['blotch_share']:.1f} % |")
        busy = [f"{sc}/{m}/{k} ({q['stats']['other_cpu_cores']:.2f})" for sc, S in O["scenes"].items()
                for m in O["modes"] for k, q in S[m].items()
                if k != "base" and q["stats"]["other_cpu_cores"] > c["busy_retry_cores"]]
        if busy:
            L.append("")
            L.append(f"Option runs during which other processes used over {c['busy_retry_cores']} cores: "
                     f"{', '.join(busy)}.")
        L.append("")
        L.append(options_reading(O))
        L.append("")
        L.append("Heat maps, base vs --dilate: `bench/results/error/<scene>-dilate.png`.")
    L.append("")
    L.append("Targets (issues 4 and 10):")
    L.append("")
    for t in R["targets"]:
        L.append(f"- {'met' if t['met'] else 'MISSED'}: {t['text']}")
    L.append("")
    L.append("How to read it. thesis and variance compare an absolute variance with its mean over all "
             "pixels: where a few pixels have very large variance (the light's edge on the Cornell box, "
             "fireflies in the caustic) they hold the mean up and nearly all other pixels skip every "
             "adaptive layer (heat maps). That wins in RMSE, and in relMSE where a few fireflies "
             "dominate it (caustic: the win is largely those pixels being resampled), but loses in "
             "relMSE where the bright side's larger absolute variance draws the samples away from the "
             "dark side (dark-bright). relerr (t half-width / (mean + 0.1)) equalises the relative "
             "error, which gives pixels layers in proportion to their relative variance v and so ties "
             "uniform on relMSE at best; relmse (v / n^2, the relMSE the next layer takes off) gives "
             "layers in proportion to sqrt(v), the relMSE-optimal share (docs/ADAPTIVE.md). The bias "
             "column: adaptive modes give fewer layers to pixels whose own layers look steady, so where "
             "rare bright paths carry the light (glass, caustic) their image comes out low. Equal-samples ratios flatter modes whose chosen pixels cost more per sample "
             "(happy-buddha: background pixels are cheap), so time is the fair axis. Against Mitsuba "
             "the time ratio combines samples/s and error per sample (sampler and estimator).")
    L.append("")
    L.append("Plots: `bench/results/error/<scene>.png` (error vs time and samples, log-log), "
             "`<scene>-heat.png` (samples per pixel), `heat/` (vbrender's own heat maps), "
             "`peer-<scene>.png` (relMSE against time, ours and Mitsuba 3).")
    return "\n".join(L)


def sampler_mode_table(R):
    """Issue 10's report: per scene, sampler x mode at equal spp and equal
    time (against uniform Sobol), bias, and against Mitsuba 3."""
    c = R["config"]
    marks = c.get("mitsuba_marks", [256, 1024])
    L = ["", f"Sampler x mode, per scene (Sobol: Owen-scrambled, one sequence per pixel; independent: "
         f"`--sampler independent`). relMSE ratios against uniform Sobol (below 1: better); bias: image "
         f"mean luminance against the reference, relative (and in standard errors). Against Mitsuba 3 "
         f"({c.get('mitsuba_sampler', 'independent')} sampler, 2 threads; ours 2 workers x 1 thread, the same 2 "
         f"cores): our relMSE over Mitsuba's at the time Mitsuba took for "
         + " and ".join(f"{m} spp" for m in marks) + ", and Mitsuba's time over ours to equal relMSE "
         "(geomean over levels both reach; above 1: we are faster).", "",
         "| scene | sampler | mode | mean spp | relMSE slope vs samples (last decade) | relMSE ratio, equal spp "
         "| relMSE ratio, equal time | bias | "
         + " | ".join(f"ours / Mitsuba relMSE @ its {m}-spp time" for m in marks)
         + " | Mitsuba time / ours |", "|---|---|---|--:|--:|--:|--:|--:|" + "--:|" * len(marks) + "--:|"]
    P = R.get("peers", {})
    for sc, S in R["scenes"].items():
        for tag, run in S["runs"].items():
            if tag.startswith("t532"):
                continue
            sampler = "independent" if tag.endswith("-indep") else "sobol"
            mode = run["job"].get("adaptive", "none") if run.get("job") else "?"
            cmp = S["comparisons"].get(tag)
            eqs = fmt(cmp["relmse_equal_samples"]["ratio"]) if cmp else "1"
            eqt = fmt(cmp["relmse_equal_time"]["ratio"]) if cmp else "1"
            b = run.get("bias")
            bias = f"{100 * b['relative']:+.3f} % ({b['in_se']:+.1f})" if b else "-"
            o = P.get(sc, {}).get("ours", {}).get(tag)
            cells = []
            for m in marks:
                x = [q for q in (o or {}).get("at_mitsuba_times", []) if q["mitsuba_spp"] == m]
                cells.append(fmt(x[0]["ratio"]) if x else "-")
            L.append(f"| {sc} | {sampler} | {mode} | {run['mean_spp']:.0f} | "
                     f"{fmt(run.get('slope_relmse_vs_samples'), 2)} | {eqs} | {eqt} | {bias} | "
                     + " | ".join(cells) + f" | {fmt(o['time_geomean']) if o else '-'} |")
    if P:
        L += ["", "Mitsuba 3 against our references (agreement: K passes, mean and variance of the mean):", "",
              "| scene | Mitsuba spp | relMSE vs ours | expected from noise | 8x8-block chi2/dof | max abs z "
              "| image mean difference, R G B (sigma) | Mitsuba samples/s |", "|---|--:|--:|--:|--:|--:|---|--:|"]
        for sc, q in P.items():
            ag = q["agreement"]
            L.append(f"| {sc} | {ag['mitsuba_spp_total']} | {ag['relmse_mitsuba_vs_ref']:.3g} | "
                     f"{ag['relmse_expected_from_noise']:.3g} | {ag['block_z_chi2_per_dof']:.2f} | "
                     f"{ag['block_z_max_abs']:.1f} | "
                     + " ".join(f"{x:+.1f}" for x in ag["mean_diff_in_sigma"])
                     + f" | {q['mitsuba_samples_per_second'] / 1e6:.2f} M |")
    return L


def target_table(T):
    """bench/error/target.py's figures: the rule as shipped, simulated and run."""
    if not T:
        return []
    cf = T["config"]
    L = ["", f"`--target-error E --confidence {cf['confidence']}` (bench/error/target.py, image side by E "
         f"{cf['sizes']}, G = {cf['granularity']}, adaptive none): share of non-black pixels "
         f"within E (ref + 1e-3) of an independent reference whose own per-pixel noise (one standard "
         f"error, relative) is at most E/5 (pixels where it is not are left out and counted). "
         f"\"Master\": the real `vbrender render`, 2 workers; \"simulated\": the same rule on the same "
         f"layer means (bench_batches). Samples against uniform sampling reaching the same share.", "",
         "| scene | E | size | reference noise p99 / max | pixels checked | share (master) | share (simulated) "
         "| mean spp | uniform spp, same share | ratio | master's spp = simulated (pixels the simulation traced "
         "to the end) |",
         "|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|"]
    shipped = T.get("shipped", "window5")
    for sc, S in T["scenes"].items():
        for E, B in S["by_error"].items():
            r = B["rules"][shipped]
            m = B.get("master") or {}
            rn = B["reference_noise"]
            if not B["checked_pixels"]:
                L.append(f"| {sc} | {E} | {B['size']} | {rn['p99']:.4f} / {rn['max']:.4f} | 0 of {B['nonblack']}: "
                         f"no pixel's reference is within E/5 | - | - | {r['mean_spp']:.0f} | - | - | - |")
                continue
            L.append(f"| {sc} | {E} | {B['size']} | {rn['p99']:.4f} / {rn['max']:.4f} | {B['checked_pixels']} of "
                     f"{B['nonblack']} | {fmt(m.get('share'))} | {r['share']:.3f} | {r['mean_spp']:.0f} | "
                     f"{r['uniform_spp_same_share'] or '-'} | {fmt(r['samples_vs_uniform'])} | "
                     f"{fmt(m.get('pixels_with_simulated_samples'))} |")
    L += ["", "Rules measured (simulated share at each E; the shipped one first):", "",
          "| rule | " + " | ".join(f"{sc} {E}" for sc, S in T["scenes"].items() for E in S["by_error"]) + " |",
          "|---|" + "--:|" * sum(len(S["by_error"]) for S in T["scenes"].values())]
    for rn in T["rules"]:
        L.append(f"| {rn} | " + " | ".join(
            f"{S['by_error'][E]['rules'][rn]['share']:.3f} ({fmt(S['by_error'][E]['rules'][rn]['samples_vs_uniform'], 2)})"
            if S["by_error"][E]["checked_pixels"] else "-"
            for S in T["scenes"].values() for E in S["by_error"]) + " |")
    L += ["", "Each cell: share within E (samples / uniform's for the same share). " +
          "; ".join(f"{k}: {v}" for k, v in T["rules"].items()) + "."]
    return L


def update_readme(md, marker="error"):
    """Writes md between bench/RESULTS.md's <!-- bench:MARKER:begin/end --> (added
    after the error section, else the distributed or the core one, when missing)."""
    path = os.path.join(ROOT, "bench", "RESULTS.md")
    with open(path) as f:
        text = f.read()
    b, e = f"<!-- bench:{marker}:begin -->", f"<!-- bench:{marker}:end -->"
    block = f"{b}\n{md}\n{e}"
    if b in text and e in text:
        i, j = text.index(b), text.index(e) + len(e)
        text = text[:i] + block + text[j:]
    else:
        anchor = next((a for a in ("<!-- bench:error:end -->", "<!-- bench:distributed:end -->",
                                   "<!-- bench:core:end -->") if a in text and a != e), None)
        if anchor is None:
            log("bench/RESULTS.md: no anchor marker; section not written")
            return
        i = text.index(anchor) + len(anchor)
        text = text[:i] + "\n\n" + block + text[i:]
    tmp = path + ".bench-error.tmp"
    with open(tmp, "w") as f:
        f.write(text)
    os.replace(tmp, path)


def targets(R):
    """Issue 4, section 4: each target met or missed, with its figures."""
    T = []
    for sc in [s for s in R["scenes"] if s in HARD]:
        comps = R["scenes"][sc]["comparisons"]
        shares = {f"{m} {cfg}": comps[f"{cfg}-{m}"]["equal_relmse_time"]["time_share"]
                  for cfg in ("long", "t532") for m in MODES}
        okm = {m: v for m, v in shares.items() if v is not None}
        bm = min(okm, key=okm.get) if okm else None
        T.append({"met": bool(bm and okm[bm] <= 0.5),
                  "text": f"{sc}: best adaptive mode reaches uniform's relMSE in at most half the time "
                          f"(time to equal relMSE, at the lowest relMSE both reach): "
                          + (f"{bm} {okm[bm]:.2f} of uniform's time" if bm else "no common level")
                          + " (" + ", ".join(f"{m} {fmt(v)}" for m, v in shares.items()) + ")"})
    worst = []
    for sc, S in R["scenes"].items():
        for tag, c in S["comparisons"].items():
            if tag.startswith("uniform"):  # the other sampler's uniform run: not an adaptive mode
                continue
            w = c["relmse_worst_equal_time_after_uniform_layers"]
            e = c["relmse_equal_time"]["ratio"]
            worst.append((max(w["ratio"] if w else 0, e or 0), sc, tag))
    worst.sort(reverse=True)
    losers = [x for x in worst if x[0] > 1.05]
    T.append({"met": not losers,
              "text": "adaptive never loses to uniform by more than 5 % in relMSE at equal time "
                      "(any time after the uniform layers): worst "
                      + ", ".join(f"{sc} {tag} {r:.2f}" for r, sc, tag in worst[:4])
                      + (f"; {len(losers)} of {len(worst)} (scene, mode, setting) over 1.05" if losers else "")})
    TG = R.get("target")
    if TG:
        rows = [(sc, E, B) for sc, S in TG["scenes"].items() for E, B in S["by_error"].items()]
        share = [(B.get("master") or {}).get("share") for _, _, B in rows]
        C = TG["config"]["confidence"]
        share = [x if x is not None and x == x else None for x in share]  # NaN: no pixel checked
        T.append({"met": all(x is not None and x >= C for x in share),
                  "text": f"--target-error E --confidence {C}: share of non-black pixels within E >= C "
                          "(the real master): " + ", ".join(f"{sc} {E} {fmt(x)}" for (sc, E, _), x in zip(rows, share))})
    for sc in ("cornell-box", "cornell-glass"):
        o = R.get("peers", {}).get(sc, {}).get("ours", {}).get(f"long-{R['config'].get('default_mode', 'relerr')}")
        if not o:
            continue
        ratios = [q["ratio"] for q in o["at_mitsuba_times"]]
        T.append({"met": bool(ratios) and all(x is not None and x <= 0.5 for x in ratios),
                  "text": f"{sc}: our relMSE (default mode) at least 2x lower than Mitsuba 3's at its "
                          + " and ".join(f"{q['mitsuba_spp']}-spp time ({fmt(q['ratio'])})" for q in o["at_mitsuba_times"])})
    d = R["config"].get("default_mode", "relmse")
    dw = []
    for sc, S in R["scenes"].items():
        c = S["comparisons"].get(f"long-{d}")
        if c:
            w = c["relmse_worst_equal_time_after_uniform_layers"]
            dw.append((max(w["ratio"] if w else 0, c["relmse_equal_time"]["ratio"] or 0), sc))
    if dw:
        T.append({"met": all(r <= 1.05 for r, _ in dw),
                  "text": f"the default mode ({d}) never loses more than 5 % to uniform in relMSE at equal time "
                          "(final and any time after the uniform layers): "
                          + ", ".join(f"{sc} {r:.2f}" for r, sc in dw)})
    R["targets"] = T
    R["busy_runs"] = [f"{sc}/{tag} ({r['stats']['other_cpu_cores']:.2f})" for sc, S in R["scenes"].items()
                      for tag, r in S["runs"].items() if r["stats"]["other_cpu_cores"] > R["config"]["busy_retry_cores"]]
    for sc, q in R.get("peers", {}).items():
        st = q["mitsuba_sweep"]["stats"]
        if st["other_cpu_cores"] > R["config"]["busy_retry_cores"]:
            R["busy_runs"].append(f"{sc}/mitsuba sweep ({st['other_cpu_cores']:.2f})")


# ---------------------------------------------------------------- main
def write_json(R):
    text = json.dumps(jsonable(R), indent=1)
    # number lists (curve rows) on one line each
    text = re.sub(r"\[\s*([-0-9.eE+]+(?:,\s*[-0-9.eE+]+)*)\s*\]",
                  lambda m: "[" + re.sub(r",\s*", ", ", m.group(1)) + "]", text)
    tmp = RESULTS_JSON + ".tmp"
    with open(tmp, "w") as f:
        f.write(text + "\n")
    os.replace(tmp, RESULTS_JSON)


def g5(x):
    return float(f"{float(x):.5g}")


def jsonable(x):
    if isinstance(x, dict):
        return {k: jsonable(v) for k, v in x.items() if k != "samples_map"}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return [jsonable(v) for v in x.tolist()]
    if isinstance(x, (np.floating,)):
        return float(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    return x


def main():
    if "--from-json" in sys.argv:  # tables and README again from bench/results/error.json
        with open(RESULTS_JSON) as f:
            R = json.load(f)
        targets(R)
        md = tables(R)
        R["readme_markdown"] = md
        write_json(R)
        if UPDATE_README:
            update_readme(md)
        print(md)
        return
    os.makedirs(PLOTS, exist_ok=True)
    if "--only" in sys.argv:  # one part again on top of bench/results/error.json
        part = sys.argv[sys.argv.index("--only") + 1] if sys.argv.index("--only") + 1 < len(sys.argv) else ""
        if part not in ("options", "target"):
            raise SystemExit("study.py: --only takes 'options' or 'target'")
        with open(RESULTS_JSON) as f:
            R = json.load(f)
        if part == "target":  # bench/error/target.py again, on top of bench/results/error.json
            R["target"] = target_study()
            targets(R)
            md = tables(R)
            R["readme_markdown"] = md
            write_json(R)
            if UPDATE_README:
                update_readme(md)
            print(md)
            return
        for k in ("size", "ref_spp", "adaptive_spp", "adaptive_uniform_layers", "granularity", "workers",
                  "threads", "seed"):
            if R["config"][k] != CFG[k]:
                raise SystemExit(f"study.py --only options: {k} {CFG[k]} differs from the saved {R['config'][k]}")
        scenes = {n: sized_scene(n) for n in R["scenes"]}
        refs = {n: make_reference(n, scenes[n]) for n in scenes}
        R["options"] = options_study(R, scenes, refs)
        targets(R)
        md = tables(R)
        R["readme_markdown"] = md
        write_json(R)
        if UPDATE_README:
            update_readme(md)
        print(md)
        log(f"options done in {R['options']['seconds']:.0f} s: {rel(RESULTS_JSON)}")
        return
    cpu = ""
    try:
        cpu = re.search(r"model name\s*:\s*(.*)", open("/proc/cpuinfo").read()).group(1).strip()
    except (OSError, AttributeError):
        pass
    R = {"config": CFG, "machine": f"{cpu or platform.processor()}, {NCPU} cores", "commit": git_commit(),
         "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "scenes": {}}
    npix = CFG["size"] ** 2
    scenes = {n: sized_scene(n) for n in CFG["scenes"]}
    refs = {n: make_reference(n, scenes[n]) for n in scenes}
    R["references"] = {n: dict(refs[n][1], exr=rel(refs[n][0])) for n in refs}
    for name, scene in scenes.items():
        ref, meta = refs[name]
        ref_ch = read_exr(ref)
        runs = {}
        s = study_run(name, scene, ref, meta, "uniform", CFG["uniform_spp"], "none", CFG["workers"], CFG["threads"])
        s["label"] = f"uniform {CFG['uniform_spp']} spp"
        runs["uniform"] = s
        for m in MODES:
            s = study_run(name, scene, ref, meta, f"long-{m}", CFG["adaptive_spp"], m, CFG["workers"],
                          CFG["threads"], ["--uniform-layers", str(CFG["adaptive_uniform_layers"])])
            s["label"] = f"{m} long (max {CFG['adaptive_spp']})"
            runs[f"long-{m}"] = s
        for m in MODES:
            # half the layers uniform, as the thesis (explicit: only thesis has it by default)
            half = CFG["thesis_spp"] // CFG["granularity"] // 2
            s = study_run(name, scene, ref, meta, f"t532-{m}", CFG["thesis_spp"], m, CFG["workers"], CFG["threads"],
                          ["--uniform-layers", str(half)])
            s["label"] = f"{m} 5.3.2 (max {CFG['thesis_spp']})"
            runs[f"t532-{m}"] = s
        d = CFG["default_mode"]
        s = study_run(name, scene, ref, meta, "uniform-indep", CFG["uniform_spp"], "none", CFG["workers"],
                      CFG["threads"], INDEP)
        s["label"] = f"uniform {CFG['uniform_spp']} spp, independent sampler"
        runs["uniform-indep"] = s
        s = study_run(name, scene, ref, meta, f"long-{d}-indep", CFG["adaptive_spp"], d, CFG["workers"],
                      CFG["threads"], ["--uniform-layers", str(CFG["adaptive_uniform_layers"])] + INDEP)
        s["label"] = f"{d} long, independent sampler"
        runs[f"long-{d}-indep"] = s
        for s in runs.values():
            s["npix"] = npix
            s["mean_spp"] = float(s["n"][-1] / npix)
            s["seconds"] = float(s["t"][-1])
        comps = {tag: compare_curves(runs["uniform"], runs[tag], npix) for tag in runs if tag != "uniform"}
        plot_scene(name, runs, meta, os.path.join(PLOTS, f"{name}.png"))
        plot_heat(name, runs, rgb(ref_ch), os.path.join(PLOTS, f"{name}-heat.png"))
        out_runs = {}
        for tag, s in runs.items():
            out_runs[tag] = {
                "command": s["command"], "summary": s["summary"], "stats": s["stats"],
                "cpu_utilization": s["cpu_utilization"], "job": s["job"],
                "mean_spp": s["mean_spp"], "seconds": s["seconds"],
                "relmse": float(s["relmse"][-1]), "rmse": float(s["rmse"][-1]),
                "relmse_raw": float(s["relmse_raw"][-1]), "rmse_raw": float(s["rmse_raw"][-1]),
                "bias": image_bias(s["exr"], ref_ch),
                "slope_relmse_vs_samples": curve_slope(s, "relmse"),
                "series": {"columns": "seconds samples relmse rmse relmse_raw rmse_raw",
                           "rows": [[round(float(a), 4), int(b), g5(c), g5(d), g5(e), g5(f)]
                                    for a, b, c, d, e, f in zip(s["t"], s["n"], s["relmse"], s["rmse"],
                                                                s["relmse_raw"], s["rmse_raw"])]},
            }
        floor = min(float(np.min(s["relmse_raw"])) for s in runs.values())
        R["scenes"][name] = {"runs": out_runs, "comparisons": comps,
                             "reference_error_over_smallest_measured": meta["relmse_est"] / floor}
        R["_runs_" + name] = runs  # for the peer choice, dropped before writing
    R["peers"] = {}
    for name, scene in scenes.items():
        ref, meta = refs[name]
        R["peers"][name] = peer(name, scene, ref, meta, R["_runs_" + name])
    for k in [k for k in R if k.startswith("_runs_")]:
        del R[k]
    old = {}
    if os.path.exists(RESULTS_JSON):
        with open(RESULTS_JSON) as f:
            old = json.load(f)
    if os.environ.get("VB_STUDY_TARGET", "1") == "1" or not old.get("target"):
        R["target"] = target_study()
    else:
        # VB_STUDY_TARGET=0: the target-error table stays as last measured
        # (bench/results/target.json), for a change that cannot move it
        R["target"] = old["target"]
    if os.environ.get("VB_STUDY_OPTIONS", "0") == "1":
        R["options"] = options_study(R, scenes, refs)
    elif old.get("options"):
        # the options study (issue 4) is not rerun by default: its table stays,
        # with the commit it was measured at
        R["options"] = old["options"]
    targets(R)
    R["total_seconds"] = time.time() - T_START
    write_json(R)  # first: a fault in the tables below loses no measurement (--from-json)
    md = tables(R)
    R["readme_markdown"] = md
    write_json(R)
    if UPDATE_README:
        update_readme(md)
    print(md)
    log(f"done: {rel(RESULTS_JSON)}, plots in {rel(PLOTS)}/")


if __name__ == "__main__":
    main()
