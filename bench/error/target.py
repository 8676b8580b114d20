#!/usr/bin/env python3
"""Does --target-error E --confidence C hold? Candidate stopping rules, simulated
on the exact batch means the master sees (issue 10, item 3).

For each scene and E (the scene resized to the size VB_TARGET_SIZES gives for
that E: smaller for the smallest E, whose reference must be 25x deeper):
  1. pilot: 64 layers of G = 32 samples (its own seed) give each pixel's spread
     of layer means, used only to size the next two steps;
  2. reference: an independent seed, each pixel traced for as many layers as
     its pilot spread says it needs for a noise of E_min / 5 (relative, at
     the rule's scale |mean| + 1e-3), capped at VB_TARGET_REF_LAYERS; its
     own noise is measured from its layers and stated per pixel;
  3. run: the study's seed 7, every pixel's layer means up to a cap
     (VB_TARGET_RUN_LAYERS, fewer where the pilot says far fewer are needed);
  4. each rule is simulated exactly as master/sched.c runs it with
     --adaptive none: a pixel's layer l+2 is decided when layer l completes,
     from its state after the last layer it took (so a pixel the rule stops
     still takes the layer already decided, and starts again if that layer
     undoes it); the image is the mean of the layers it took;
  5. for each (rule, E): the share of non-black pixels (reference luminance
     > 1e-3) within E (ref + 1e-3) of the reference, counting only pixels
     whose reference noise is at most E / 5 (that count is stated; the noise
     judged, like the shipped rule, by the largest relative variance in the
     pixel's 5x5 window, since a reference pixel can miss rare bright paths
     too), the
     samples used, and the samples uniform sampling needs to reach the same
     share (the fewest layers n for which uniform's share >= the rule's).

bench_batches (bench/bench_batches.c) does the tracing; nothing here renders
through the daemons, so the figures say what the rule does, not the network.
The real master is checked against this simulation by the study (study.py).

Writes bench/results/target.json and prints a table per E.
"""
import hashlib
import json
import math
import os
import subprocess
import sys
import time
import warnings

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
BATCHES = os.path.join(ROOT, "build", "bench", "bench_batches")
WORK = os.path.join(ROOT, "bench", "work", "target")


def env_int(name, default):
    return int(os.environ.get(name, default))


CFG = {
    "sizes": {float(k): int(v) for k, v in (x.split(":") for x in
              os.environ.get("VB_TARGET_SIZES", "0.02:16,0.05:32,0.1:32").split(","))},
    "granularity": 32,
    "pilot_layers": 64,
    "ref_layers": env_int("VB_TARGET_REF_LAYERS", 40000),
    "run_layers": env_int("VB_TARGET_RUN_LAYERS", 8192),
    "errors": [float(x) for x in os.environ.get("VB_TARGET_E", "0.02,0.05,0.1").split(",")],
    "confidence": 0.95,
    "threads": env_int("VB_TARGET_THREADS", 2),
    "seeds": {"pilot": 1000004, "reference": 1000003, "reference_floor": 1000005, "run": 7},
    "scenes": os.environ.get("VB_TARGET_SCENES", "cornell-box,cornell-glass,caustic,dark-bright").split(","),
}
MASTER = os.environ.get("VB_TARGET_MASTER", "1") == "1"
EPS = 1e-3  # master/sched.h SCHED_TARGET_EPS
BLACK = 1e-3


def log(msg):
    print(f"[target {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


# ---- Student t, as common/stats.c computes it --------------------------------
def _beta_cf(a, b, x):
    tiny, eps = 1e-300, 1e-15
    qab, qap, qam = a + b, a + 1, a - 1
    c, d = 1.0, 1 - qab * x / qap
    d = 1 / (d if abs(d) >= tiny else tiny)
    h = d
    for m in range(1, 301):
        m2 = 2 * m
        for aa in (m * (b - m) * x / ((qam + m2) * (a + m2)),
                   -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))):
            d = 1 + aa * d
            d = 1 / (d if abs(d) >= tiny else tiny)
            c = 1 + aa / c
            c = c if abs(c) >= tiny else tiny
            h *= d * c
        if abs(d * c - 1) < eps:
            break
    return h


def _inc_beta(a, b, x):
    if x <= 0:
        return 0.0
    if x >= 1:
        return 1.0
    bt = math.exp(math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log(1 - x))
    if x < (a + 1) / (a + b + 2):
        return bt * _beta_cf(a, b, x) / a
    return 1 - bt * _beta_cf(b, a, 1 - x) / b


def t_cdf(t, dof):
    tail = 0.5 * _inc_beta(dof / 2, 0.5, dof / (dof + t * t))
    return 1 - tail if t >= 0 else tail


_T = {}


def t_two_sided(conf, dof):
    key = (conf, dof)
    if key not in _T:
        target, lo, hi = 0.5 + conf / 2, 0.0, 1.0
        while t_cdf(hi, dof) < target and hi < 1e12:
            hi *= 2
        for _ in range(200):
            if hi - lo <= 1e-12 * hi:
                break
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if t_cdf(mid, dof) < target else (lo, mid)
        _T[key] = 0.5 * (lo + hi)
    return _T[key]


def t_table(conf, n):
    """t factor by batches nb (index nb; 0 and 1 are inf)."""
    return np.array([np.inf, np.inf] + [t_two_sided(conf, k - 1) for k in range(2, n + 1)])


# ---- data -----------------------------------------------------------------------
def sized_scene(name, size):
    """scenes/NAME.json at size x size pixels; mitsuba/NAME: Mitsuba's file
    scenes/mitsuba/NAME.xml (study.py's sized_xml), both in WORK."""
    if name.startswith("mitsuba/"):
        import study  # noqa: E402  (only here: the study's helpers for Mitsuba's files)
        return study.sized_xml(name, size, WORK)
    src = os.path.join(ROOT, "scenes", f"{name}.json")
    with open(src) as f:
        d = json.load(f)
    d["camera"]["width"] = d["camera"]["height"] = size
    for sh in d["shapes"]:
        if "file" in sh and not os.path.isabs(sh["file"]):
            sh["file"] = os.path.normpath(os.path.join(os.path.dirname(src), sh["file"]))
    os.makedirs(WORK, exist_ok=True)
    dst = os.path.join(WORK, f"{name}-{size}.json")
    text = json.dumps(d, indent=1)
    if not os.path.exists(dst) or open(dst).read() != text:
        with open(dst, "w") as f:
            f.write(text)
    return dst


# The master's replicates per pixel (common/defaults.h JOB_DEFAULT_REPLICATES): the
# runs a rule is simulated on mirror the master's jobs; a reference may take any.
REPLICATES = env_int("VB_TARGET_REPLICATES", 2)


def shown_path(p):
    """A path as a cache file's command records it: from the root when under it."""
    return os.path.relpath(p, ROOT) if p.startswith(ROOT) else p


def adopt_legacy(legacy, new, counts):
    """A cache file of before the counts named it: taken over (renamed) when
    its counts file holds exactly these counts."""
    if os.path.exists(new + ".f64") or not os.path.exists(legacy + ".f64"):
        return
    try:
        same = np.array_equal(np.fromfile(legacy + ".counts", dtype="<u4"), counts.astype("<u4"))
    except OSError:
        same = False
    if not same or not os.path.exists(legacy + ".f64.json"):
        return
    # its command named its output and counts files by the old name
    with open(legacy + ".f64.json") as f:
        meta = json.load(f)
    renamed = {shown_path(legacy + ext): shown_path(new + ext) for ext in (".f64", ".counts")}
    meta["want"]["cmd"] = [renamed.get(c, c) for c in meta["want"]["cmd"]]
    with open(new + ".f64.json", "w") as f:
        json.dump(meta, f)
    os.remove(legacy + ".f64.json")
    os.replace(legacy + ".f64", new + ".f64")
    os.replace(legacy + ".counts", new + ".counts")


def batches(scene, size, tag, layers, seed, counts=None, summary=False, replicates=None):
    """Runs bench_batches once (cached by its arguments) and returns the array."""
    npix = size * size
    replicates = REPLICATES if replicates is None else replicates
    rtag = "" if replicates == 1 else f"-rep{replicates}"
    key = f"{os.path.splitext(os.path.basename(scene))[0]}-{tag}-{layers}-{seed}{rtag}{'-sum' if summary else ''}"
    if counts is not None:
        # per-pixel counts name the file too: runs with another smallest E (the
        # coverage's references) have other counts under the same largest one,
        # and re-rendered over each other's files
        legacy = os.path.join(WORK, key)
        key += "-c" + hashlib.sha256(counts.astype("<u4").tobytes()).hexdigest()[:12]
        adopt_legacy(legacy, os.path.join(WORK, key), counts)
    out = os.path.join(WORK, key + ".f64")
    cmd = [BATCHES, scene, out, "--layers", str(layers), "--granularity", str(CFG["granularity"]),
           "--seed", str(seed), "--threads", str(CFG["threads"])]
    if replicates != 1:
        cmd += ["--replicates", str(replicates)]
    if counts is not None:
        cpath = os.path.join(WORK, key + ".counts")
        counts.astype("<u4").tofile(cpath)
        cmd += ["--counts", cpath]
    if summary:
        cmd.append("--summary")
    meta = out + ".json"
    want = {"cmd": [shown_path(c) for c in cmd],
            "counts_sum": None if counts is None else int(counts.sum())}
    if not (os.path.exists(out) and os.path.exists(meta) and json.load(open(meta)).get("want") == want):
        t0 = time.time()
        log(f"{key}: {want['counts_sum'] or layers * npix} pixel-layers")
        subprocess.run(cmd, check=True)
        with open(meta, "w") as f:
            json.dump({"want": want, "seconds": time.time() - t0}, f)
    a = np.fromfile(out, dtype="<f8")
    return a.reshape(3, npix, order="F") if summary else a.reshape(layers, npix)


REF_FLOOR = 2048  # layers every reference pixel gets at least (65,536 samples)
RUN_FLOOR = 1024  # layers of the run every pixel gets at least, for the uniform comparison


def merge_welford(a, b):
    """Two (n, mean, M2) per-pixel summaries of independent layers, as one."""
    na, ma, qa = a
    nb, mb, qb = b
    n = na + nb
    d = mb - ma
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(n > 0, ma + d * nb / np.maximum(n, 1), 0.0)
        m2 = qa + qb + d * d * na * nb / np.maximum(n, 1)
    return n, mean, m2


def prepare(name, size, emin):
    scene = sized_scene(name, size)
    g = CFG["granularity"]
    pilot = batches(scene, size, "pilot", CFG["pilot_layers"], CFG["seeds"]["pilot"])
    pm = pilot.mean(0)
    rel_sd = pilot.std(0, ddof=1) / (np.abs(pm) + EPS)
    need_ref = np.ceil((1.6 * rel_sd / (emin / 5)) ** 2)
    ref_counts = np.clip(need_ref, 64, CFG["ref_layers"]).astype(np.uint32)
    ref = batches(scene, size, "ref", CFG["ref_layers"], CFG["seeds"]["reference"], ref_counts, summary=True)
    # A pixel that looks smooth for the pilot's 64 layers may still have rare,
    # bright paths (a caustic): its noise, measured from its own layers, is
    # trusted only from REF_FLOOR layers on. The extra layers come from a
    # third seed (independent of the rest), merged in (Chan et al.).
    extra = np.maximum(REF_FLOOR - ref_counts.astype(np.int64), 0).astype(np.uint32)
    top = batches(scene, size, "ref-floor", REF_FLOOR, CFG["seeds"]["reference_floor"], extra, summary=True)
    n, mean, m2 = merge_welford(ref, top)
    # The reference's own noise, judged as the shipped rule judges a pixel:
    # a reference pixel that has not yet met a rare bright path its
    # neighbours have met looks precise and is low (the caustic scene's
    # floor beside the caustic: "0.1 %" from its own layers, 10 % low). Its
    # relative variance per layer is taken as the largest in its 5x5 window.
    own_rv = m2 / np.maximum(n - 1, 1) / (np.abs(mean) + EPS) ** 2
    rv = window(own_rv.reshape(size, size), 2, 0.0, np.max).ravel()
    ref_noise = np.sqrt(rv / n)
    # the run: 4x what a correct rule needs at E_min, by the pilot, within the cap
    need_run = np.ceil(4 * (2.5 * rel_sd / emin) ** 2)
    run_counts = np.clip(need_run, RUN_FLOOR, CFG["run_layers"]).astype(np.uint32)
    run = batches(scene, size, "run", CFG["run_layers"], CFG["seeds"]["run"], run_counts)
    return {"scene": scene, "size": size, "ref_mean": mean, "ref_layers": n, "ref_noise": ref_noise,
            "run": run, "run_counts": run_counts, "samples_per_layer": g}


# ---- rules ----------------------------------------------------------------------
class Rule:
    """A per-pixel stopping rule: 'fires' from Welford state after a layer."""

    def __init__(self, name, min_batches=4, confidence_scale=1.0, confirm=0, pool=0, pool_max=False,
                 neighbours=0, frozen=0, replicates=0, dof=None, ucb=0.0, doc=""):
        self.name, self.min_batches, self.confirm, self.doc = name, min_batches, confirm, doc
        # replicates > 0 (with frozen): a pixel's relative variance per layer from the
        # spread of its replicates' means over its first `frozen` layers (layer k is
        # replicate k mod R's), the window's mean taken (max if pool_max), the pixel
        # left out; the t factor's degrees of freedom `dof` (None: the layers')
        self.replicates, self.dof = replicates, dof
        self.ucb = ucb  # > 0: the window's mean plus ucb standard errors of it
        self.pool, self.pool_max = pool, pool_max  # window radius, max instead of mean
        # frozen > 0: every pixel's variance from its first `frozen` layers only, and the
        # window's largest taken over the neighbours, the pixel itself left out
        self.frozen = frozen
        self.neighbours = neighbours  # stops only when every pixel within this radius has fired
        self.confidence_scale = confidence_scale  # alpha divided by this

    def conf(self, C):
        return 1 - (1 - C) / self.confidence_scale


RULES = [
    Rule("window5-frozen8", pool=2, pool_max=True, frozen=8, min_batches=8,
         doc="as shipped with --replicates 1: the relative variance of a pixel's layer means taken as the "
             "largest among its 24 "
             "neighbours in the 5x5 window, each over its first 8 layers only (unbiased: a pixel's stop "
             "never depends on its own values)"),
    Rule("calibrated5", pool=2, frozen=16, min_batches=16, replicates=max(REPLICATES, 2), confidence_scale=2,
         ucb=1.0,
         doc="as shipped (replicates, the default): the replicates' spread over each pixel's first 16 layers "
             "(the calibrated error), its mean over the 24 neighbours of the 5x5 window, the pixel left "
             "out, plus one standard error of that mean; t with their degrees of freedom (R - 1 each), at "
             "half the alpha (1 - C) / 2"),
    Rule("calibrated8", pool=2, frozen=8, min_batches=8, replicates=max(REPLICATES, 2), confidence_scale=2,
         doc="calibrated5 over the first 8 layers, the neighbours' mean alone"),
    Rule("calibrated8-alpha", pool=2, frozen=8, min_batches=8, replicates=max(REPLICATES, 2),
         doc="calibrated8 at the confidence asked for, C itself"),
    Rule("calibrated32", pool=2, frozen=32, min_batches=32, replicates=max(REPLICATES, 2), confidence_scale=2,
         doc="calibrated8 over the first 32 layers"),
    Rule("calibrated8-max", pool=2, pool_max=True, frozen=8, min_batches=8, replicates=max(REPLICATES, 2),
         doc="calibrated8-alpha with the neighbours' largest instead of their mean"),
    Rule("window5", pool=2, pool_max=True,
         doc="the largest in the 5x5 window, the pixel included, over all layers taken (before the change)"),
    Rule("own", doc="the pixel's own: t half-width <= E (|mean| + 1e-3) after >= 4 layers (before issue 10)"),
    Rule("own-min8", min_batches=8, doc="own, after >= 8 layers"),
    Rule("own-min32", min_batches=32, doc="own, after >= 32 layers"),
    Rule("own-alpha/4", confidence_scale=4, doc="own, alpha spent over looks: confidence 1 - (1 - C)/4"),
    Rule("own-confirm", confirm=2, doc="own, firing again with at least twice the layers"),
    Rule("mean3", pool=1, doc="relative variance floored by its mean over the 3x3 window"),
    Rule("window3", pool=1, pool_max=True, doc="the largest in the 3x3 window"),
    Rule("nbr3", neighbours=1, doc="own, and a pixel stops only when every pixel of its 3x3 window has fired"),
    Rule("nbr5", neighbours=2, doc="the same over the 5x5 window"),
]
# as master/sched_target.c: the calibrated rule where the job has replicates
SHIPPED = RULES[1] if REPLICATES > 1 else RULES[0]


def window(img, radius, pad_value, reduce):
    """reduce over the (2 radius + 1)^2 window around each pixel; outside the image is pad_value."""
    w = img.shape[0]
    pad = np.pad(img, radius, constant_values=pad_value)
    k = 2 * radius + 1
    blocks = np.stack([pad[dy:dy + w, dx:dx + w] for dy in range(k) for dx in range(k)])
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return reduce(blocks, axis=0)


def window_without_centre(img, radius, pad_value):
    """The largest over each pixel's (2 radius + 1)^2 window, the pixel left out."""
    w = img.shape[0]
    pad = np.pad(img, radius, constant_values=pad_value)
    k = 2 * radius + 1
    blocks = np.stack([pad[dy:dy + w, dx:dx + w] for dy in range(k) for dx in range(k)
                       if (dy, dx) != (radius, radius)])
    return blocks.max(axis=0)


def window_mean_without_centre(img, radius, ucb=0.0):
    """The mean over each pixel's (2 radius + 1)^2 window, the pixel and the outside left
    out; ucb > 0: plus ucb standard errors of that mean (the neighbours' spread / sqrt(n))."""
    w = img.shape[0]
    pad = np.pad(img, radius, constant_values=np.nan)
    k = 2 * radius + 1
    blocks = np.stack([pad[dy:dy + w, dx:dx + w] for dy in range(k) for dx in range(k)
                       if (dy, dx) != (radius, radius)])
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        m = np.nanmean(blocks, axis=0)
        if ucb > 0:
            n = np.sum(~np.isnan(blocks), axis=0)
            m = m + ucb * np.nanstd(blocks, axis=0, ddof=1) / np.sqrt(n)
        return m


def calibrated_rv(run, rule):
    """Each pixel's relative variance per layer from its replicates over its first
    rule.frozen layers: sum_r (m_r - m)^2 / (R (R - 1)) (the variance of the mean of
    equal replicates) times the layers, over (|m| + eps)^2."""
    R, F = rule.replicates, rule.frozen
    first = run[:F]
    m_r = np.stack([first[r::R].mean(0) for r in range(R)])
    m = m_r.mean(0)
    var_mean = ((m_r - m) ** 2).sum(0) / (R * (R - 1))
    return var_mean * F / (np.abs(m) + EPS) ** 2


def simulate(data, rule, E, C):
    """Runs rule on the run's layer means; returns per-pixel (estimate, layers)."""
    run = data["run"]
    L, npix = run.shape
    w = data["size"]
    ttab = t_table(rule.conf(C), L + 1)
    if rule.replicates:
        crv = calibrated_rv(run, rule).reshape(w, w)
        cv = (window_without_centre(crv, rule.pool, 0.0) if rule.pool_max
              else window_mean_without_centre(crv, rule.pool, rule.ucb)).ravel()
        # as master/sched_target.c: t for the neighbours' R - 1 degrees of freedom each
        inside = window(np.ones((w, w)), rule.pool, 0.0, np.sum).ravel() - 1
        dof = (inside * (rule.replicates - 1)).astype(int) if rule.dof is None else np.full(npix, rule.dof)
        tpix = np.array([t_two_sided(rule.conf(C), int(d)) for d in dof])
    nb = np.zeros(npix, np.int64)
    mean = np.zeros(npix)
    m2 = np.zeros(npix)
    snap = np.zeros(npix, bool)  # converged, as of the last layer the pixel took
    first = np.zeros(npix, np.int64)  # confirm: layers when it first fired (0: not yet)
    fn = np.zeros(npix, np.int64)  # frozen: Welford over the first rule.frozen layers
    fmean = np.zeros(npix)
    fm2 = np.zeros(npix)
    decided = [np.ones(npix, bool), np.ones(npix, bool)]
    for layer in range(L):
        member = decided[layer] & ~np.isnan(run[layer])
        if not member.any() and not (layer + 1 < L and decided[layer + 1].any()):
            break
        x = run[layer, member]
        nb[member] += 1
        d = x - mean[member]
        mean[member] += d / nb[member]
        m2[member] += d * (x - mean[member])
        if rule.frozen:
            grow = member & (fn < rule.frozen)
            xf = run[layer, grow]
            fn[grow] += 1
            df = xf - fmean[grow]
            fmean[grow] += df / fn[grow]
            fm2[grow] += df * (xf - fmean[grow])
        # every pixel's state is judged at each decision (master/sched.c
        # mark_converged), its own state changed only by the layers it took
        k = nb
        with np.errstate(all="ignore"):
            scale = np.abs(mean) + EPS
            rv = np.where(k >= 2, m2 / (k - 1) / (scale * scale), np.where(k == 0, 0.0, np.inf))
            if rule.replicates:
                v = np.where(fn >= rule.frozen, cv, np.inf)
            elif rule.frozen:  # exactly as the master: frozen statistics, the neighbours' largest
                fscale = np.abs(fmean) + EPS
                frv = np.where(fn >= rule.frozen, fm2 / (fn - 1) / (fscale * fscale), np.inf)
                v = window_without_centre(frv.reshape(w, w), rule.pool, 0.0).ravel()
            elif rule.pool and rule.pool_max:  # the window's largest, 0 outside
                v = window(rv.reshape(w, w), rule.pool, 0.0, np.max).ravel()
            elif rule.pool:
                vb = np.where(k >= 2, rv, np.nan)
                v = np.maximum(rv, np.nan_to_num(window(vb.reshape(w, w), rule.pool, np.nan, np.nanmean).ravel(),
                                                 nan=np.inf))
            else:
                v = rv
            tk = tpix if rule.replicates else ttab[k]
            fires = (k >= rule.min_batches) & (tk * np.sqrt(v / np.maximum(k, 1)) <= E)
        if rule.confirm:
            newly = fires & (first == 0)
            first[newly] = k[newly]
            fires = fires & (first > 0) & (k >= rule.confirm * first)
        snap = fires
        if layer + 2 < L:
            stop = snap.copy()
            if rule.neighbours:
                stop = window(snap.reshape(w, w).astype(float), rule.neighbours, 1.0, np.min).ravel() > 0.5
            decided.append(~stop)
    return mean, nb


def evaluate(data, est, layers, E):
    ref = data["ref_mean"]
    valid = (ref > BLACK) & (data["ref_noise"] <= E / 5)
    ok = np.abs(est - ref) <= E * (np.abs(ref) + EPS)
    share = float(ok[valid].mean())
    return share, valid


def uniform_shares(data, valid, E):
    """Uniform sampling's share within E after n layers, for n = 1.. (index n - 1)."""
    run, ref = data["run"], data["ref_mean"]
    cnt = np.maximum(np.cumsum(~np.isnan(run), axis=0), 1)
    # a pixel past its traced layers keeps its last mean: the run traced each
    # pixel to 4x what the pilot says E_min needs, far past where it is within E
    est = np.cumsum(np.where(np.isnan(run), 0.0, run), axis=0) / cnt
    ok = np.abs(est - ref) <= E * (np.abs(ref) + EPS)
    return ok[:, valid].mean(axis=1)


def uniform_layers_for(curve, share_goal):
    """Fewest layers n at which uniform sampling's share reaches share_goal."""
    hit = np.nonzero(curve >= share_goal)[0]
    return int(hit[0]) + 1 if len(hit) else None


def read_exr(path):
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    b = mi.Bitmap(path)
    names = [f.name for f in b.struct_()]
    a = np.array(b, dtype=np.float64)
    return {n: a[:, :, i] for i, n in enumerate(names)}


def master_run(name, data, E, C, sim_layers):
    """The real thing: vbrender render --target-error E, 2 workers; its share,
    and whether its per-pixel samples are the simulation's (SHIPPED rule)."""
    cap = CFG["run_layers"] * CFG["granularity"]
    out = os.path.join(WORK, f"{name}-{data['size']}-E{E}.exr")
    cmd = [os.path.join(ROOT, "bin", "vbrender"), "render", data["scene"], "-o", out, "--spp", str(cap),
           "--granularity", str(CFG["granularity"]), "--adaptive", "none", "--seed", str(CFG["seeds"]["run"]),
           "--target-error", str(E), "--confidence", str(C), "--workers", "2", "--threads", "1",
           "--progress", "none"]
    t0 = time.time()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    secs = time.time() - t0
    ch = read_exr(out)
    est = (0.3 * ch["R"] + 0.59 * ch["G"] + 0.11 * ch["B"]).ravel()
    spp = ch["samples"].ravel()
    share, valid = evaluate(data, est, None, E)
    traced = sim_layers < data["run_counts"]  # the simulation saw the whole story
    same = spp[traced] == sim_layers[traced] * CFG["granularity"]
    return {"command": [os.path.relpath(c, ROOT) if c.startswith(ROOT) else c for c in cmd],
            "seconds": secs, "share": share, "mean_spp": float(spp[valid].mean()),
            "pixels_compared_with_simulation": int(traced.sum()),
            "pixels_with_simulated_samples": float(same.mean()) if len(same) else None}


def study_error(name, data, E, C):
    """Every rule at one E, the uniform comparison, and the real master."""
    nonblack = data["ref_mean"] > BLACK
    noise = data["ref_noise"][nonblack]
    rows = {}
    for rule in RULES:
        est, layers = simulate(data, rule, E, C)
        share, valid = evaluate(data, est, layers, E)
        capped = float((layers[valid] >= data["run_counts"][valid]).mean())
        rows[rule.name] = {"share": share, "mean_spp": float(layers[valid].mean() * CFG["granularity"]),
                           "capped_share": capped}
    curve = uniform_shares(data, valid, E)
    for r in rows.values():
        n = uniform_layers_for(curve, r["share"])
        r["uniform_spp_same_share"] = None if n is None else n * CFG["granularity"]
        r["samples_vs_uniform"] = None if n is None else r["mean_spp"] / (n * CFG["granularity"])
    est, layers = simulate(data, SHIPPED, E, C)
    log(f"{name} E={E}: " + ", ".join(f"{k} {v['share']:.3f}" for k, v in rows.items()))
    return {
        "size": data["size"], "pixels": int(nonblack.size), "nonblack": int(nonblack.sum()),
        "reference": {"layers_median": float(np.median(data["ref_layers"])),
                      "layers_max": float(data["ref_layers"].max()),
                      "samples": float(data["ref_layers"].sum() * CFG["granularity"])},
        "reference_noise": {"median": float(np.median(noise)), "p99": float(np.percentile(noise, 99)),
                            "max": float(noise.max()), "share_at_most_E_over_5": float((noise <= E / 5).mean())},
        "run_layers_cap": int(data["run_counts"].max()),
        "checked_pixels": int(valid.sum()), "rules": rows,
        "master": master_run(name, data, E, C, layers) if MASTER else None}


def main():
    C = CFG["confidence"]
    R = {"config": dict(CFG, sizes={str(k): v for k, v in CFG["sizes"].items()}), "shipped": SHIPPED.name,
         "rules": {r.name: r.doc for r in RULES}, "scenes": {}}
    by_size = {}
    for E in CFG["errors"]:
        by_size.setdefault(CFG["sizes"].get(E, 32), []).append(E)
    for name in CFG["scenes"]:
        S = {"by_error": {}}
        for size, errors in sorted(by_size.items()):
            data = prepare(name, size, min(errors))
            for E in errors:
                S["by_error"][str(E)] = study_error(name, data, E, C)
        S["by_error"] = {str(E): S["by_error"][str(E)] for E in CFG["errors"]}
        R["scenes"][name] = S
    print_tables(R)
    out = os.environ.get("VB_TARGET_OUT", os.path.join(ROOT, "bench", "results", "target.json"))
    with open(out, "w") as f:
        json.dump(R, f, indent=1)
    log(f"wrote {os.path.relpath(out, ROOT)}")


def print_tables(R):
    for name, S in R["scenes"].items():
        print(f"\n{name}")
        print(f"{'E':>5} {'size':>4} {'rule':<16} {'share':>7} {'master':>7} {'mean spp':>9} {'uniform spp':>11} "
              f"{'ratio':>6} {'capped':>7}  ref noise p99 / checked of non-black")
        for E, B in S["by_error"].items():
            m = B["master"] or {}
            for rn, r in B["rules"].items():
                u = r["uniform_spp_same_share"]
                ms = f"{m['share']:.3f}" if m and rn == R["shipped"] else ""
                print(f"{E:>5} {B['size']:>4} {rn:<16} {r['share']:7.3f} {ms:>7} {r['mean_spp']:9.0f} "
                      f"{u if u else '-':>11} {r['samples_vs_uniform'] or 0:6.2f} {r['capped_share']:7.3f}  "
                      f"{B['reference_noise']['p99']:.4f} / {B['checked_pixels']} of {B['nonblack']}")


if __name__ == "__main__":
    main()
