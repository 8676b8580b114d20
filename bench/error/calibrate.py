#!/usr/bin/env python3
"""Does the per-pixel error we report predict the actual error? (issue 24, item 1)

For each shipped scene at SIZE x SIZE pixels and each N in SPPS, renders K
independent estimates of every pixel (`--adaptive none`, seeds apart: under
the sobol sampler a seed is an independent Owen scramble of each pixel's
sequence), in these designs:

- single: one sequence of N samples per pixel (today's default);
- R replicates, R in REPS: R sequences of N / R samples, the estimate their
  mean (the seed stands for the replicate's scramble, so this is exactly
  what random replication inside the renderer would give).

Truth is the mean of every render of the scene at that N (all unbiased); its
own variance is estimated from the spread of the estimates and subtracted.
For each design and each predictor of a pixel's variance:

- channel: the EXR `variance` channel (per-sample variance / n);
- reps: the spread of the R replicate means, sum (m_r - m)^2 / (R (R - 1));
- master R=r: the real `vbrender render --replicates r`, whose variance
  channel is the calibrated one the master ships (sched_error.c);
- pooled-W: channel x the ratio reps / channel summed over the W x W window
  around the pixel (the quasi-Monte Carlo gain, estimated with many degrees
  of freedom, the per-pixel shape from the channel);

it reports ratio = mean((x - t)^2) / mean(predicted) over pixels and
estimates, and the share with |x - t| <= 1.96 sqrt(predicted): the issue asks
for [0.8, 1.25] and [0.93, 0.97]. And for each design its relMSE over the
single sequence's: what replication costs.

Pixels count when the truth is above 1e-3 of the image mean. Luminance
throughout (the `variance` channel is luminance's).

    bench/venv/bin/python bench/error/calibrate.py      (after make all)
Environment: VB_CAL_SCENES (comma list), VB_CAL_SIZE (32), VB_CAL_SPPS
(256,1024), VB_CAL_K (16), VB_CAL_REPS (2,4,8), VB_CAL_WINDOWS (5,9),
VB_CAL_THREADS (all cores). A scene "mitsuba/NAME" is the shipped
scenes/mitsuba/NAME.xml at -D res=SIZE. Writes bench/results/calibration.json,
or the file VB_CAL_OUT names.
"""
import json
import os
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import target  # noqa: E402  (its resized scenes)

ROOT = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
VB = os.path.join(ROOT, "bin", "vbrender")
WORK = os.path.join(ROOT, "bench", "work", "calibrate")
OUT = os.environ.get("VB_CAL_OUT", os.path.join(ROOT, "bench", "results", "calibration.json"))


def env_list(name, default, conv=int):
    return [conv(x) for x in os.environ.get(name, default).split(",") if x]


SCENES = env_list("VB_CAL_SCENES", "cornell-box,cornell-glass,cornell-buddha,caustic,dark-bright",
                  str)
SIZE = int(os.environ.get("VB_CAL_SIZE", "32"))
SPPS = env_list("VB_CAL_SPPS", "256,1024")
K = int(os.environ.get("VB_CAL_K", "16"))
REPS = env_list("VB_CAL_REPS", "2,4,8")
WINDOWS = env_list("VB_CAL_WINDOWS", "5,9")
SHRINK = env_list("VB_CAL_SHRINK", "4,16")
SHIPPED = env_list("VB_CAL_SHIPPED", "2")  # the master's --replicates to check
THREADS = int(os.environ.get("VB_CAL_THREADS", str(os.cpu_count() or 1)))
T0 = time.time()

import mitsuba as mi  # noqa: E402  (scalar variant, for Bitmap only)

mi.set_variant("scalar_rgb")


def log(msg):
    print(f"[{time.time() - T0:7.1f} s] {msg}", file=sys.stderr, flush=True)


def read_exr(path):
    b = mi.Bitmap(path)
    names = [f.name for f in b.struct_()]
    a = np.array(b, dtype=np.float64)
    return {n: a[:, :, i] for i, n in enumerate(names)}


def scene_args(name):
    """The render's scene arguments: a JSON scene resized (target.py), or a shipped
    Mitsuba file ("mitsuba/NAME", scenes/mitsuba/NAME.xml) at -D res=SIZE."""
    if name.startswith("mitsuba/"):
        return [os.path.join(ROOT, "scenes", name + ".xml"), "-D", f"res={SIZE}"]
    return [target.sized_scene(name, SIZE)]


def render(scene, spp, seed, tag, replicates=1):
    """(luminance, variance channel) of one uniform render, cached by its settings."""
    rtag = "" if replicates == 1 else f"-rep{replicates}"
    out = os.path.join(WORK, "runs", f"{tag}-{spp}spp-seed{seed}{rtag}.exr")
    if not os.path.exists(out):
        os.makedirs(os.path.dirname(out), exist_ok=True)
        cmd = [VB, "render", *scene, "-o", out, "--spp", str(spp), "--adaptive", "none",
               "--seed", str(seed), "--threads", str(THREADS), "--progress", "none",
               "--replicates", str(replicates)]
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    c = read_exr(out)
    return 0.3 * c["R"] + 0.59 * c["G"] + 0.11 * c["B"], c["variance"]


def box_sum(a, w):
    """Sum over the w x w window around each pixel (clipped at the border)."""
    r = w // 2
    p = np.pad(a, r)
    c = p.cumsum(0).cumsum(1)
    c = np.pad(c, ((1, 0), (1, 0)))
    h, wd = a.shape
    return c[w:w + h, w:w + wd] - c[0:h, w:w + wd] - c[w:w + h, 0:wd] + c[0:h, 0:wd]


def judge(x, pred, truth, truth_var, mask):
    """ratio and 1.96-sigma share over the estimates x[k] with predictions pred[k]."""
    err2 = (x - truth) ** 2 - truth_var  # the truth's own noise taken out (independent)
    ratio = float(np.mean(err2[:, mask]) / np.mean(pred[:, mask]))
    # the truth's noise widens the interval the same way
    share = float(np.mean(np.abs(x - truth)[:, mask] <= 1.96 * np.sqrt(pred + truth_var)[:, mask]))
    return ratio, share


def study_scene(name):
    scene = scene_args(name)
    name = name.replace("/", "-")
    rows = []
    for n in SPPS:
        seed0 = 1000
        single = [render(scene, n, seed0 + k, name) for k in range(K)]
        designs = {"single": (np.array([s[0] for s in single]), np.array([s[1] for s in single]),
                              None)}
        for r in REPS:
            if n % r:
                continue
            lum, var, reps = [], [], []
            for k in range(K):
                parts = [render(scene, n // r, seed0 + 100000 * r + r * k + j, name)
                         for j in range(r)]
                m = np.array([p[0] for p in parts])
                lum.append(m.mean(0))
                var.append(np.mean([p[1] for p in parts], 0) / r)
                reps.append(((m - m.mean(0)) ** 2).sum(0) / (r * (r - 1)))
            designs[f"R={r}"] = (np.array(lum), np.array(var), np.array(reps))
        # what ships: the master's own replicates and its calibrated variance channel
        for r in SHIPPED:
            runs = [render(scene, n, seed0 + 500000 + k, name, r) for k in range(K)]
            designs[f"master R={r}"] = (np.array([s[0] for s in runs]), np.array([s[1] for s in runs]),
                                        None)
        allx = np.concatenate([d[0] for d in designs.values()])
        truth = allx.mean(0)
        # each design's estimates have their own variance; the truth is the mean of all
        # of them: var(truth) = sum over designs of K var_d / (total)^2
        tv = sum(d[0].var(0, ddof=1) * len(d[0]) for d in designs.values()) / len(allx) ** 2
        mask = truth > 1e-3 * truth.mean()
        base = None
        for dname, (x, chan, reps) in designs.items():
            mse = float(np.mean(x.var(0, ddof=1)[mask]))
            relmse = float(np.mean((x.var(0, ddof=1) / (truth ** 2 + 1e-2))[mask]))
            if dname == "single":
                base = relmse
            row = {"scene": name, "spp": n, "design": dname, "K": K, "mse": mse,
                   "relmse": relmse, "relmse_over_single": relmse / base, "predictors": {}}
            # the best any predictor could do: each pixel's true variance, from the other
            # estimates (leave-one-out, so x is not judged by its own spread)
            kk = len(x)
            loo_mean = (x.sum(0) - x) / (kk - 1)
            loo_var = ((x * x).sum(0) - x * x - (kk - 1) * loo_mean ** 2) / (kk - 2)
            preds = {"oracle": loo_var, "channel": chan}
            if reps is not None:
                preds["reps"] = reps
                for w in WINDOWS:
                    gain = box_sum(reps.mean(0), w) / np.maximum(box_sum(chan.mean(0), w), 1e-300)
                    # per estimate: its own replicates' gain (not the mean over estimates)
                    g = np.array([box_sum(reps[k], w) / np.maximum(box_sum(chan[k], w), 1e-300)
                                  for k in range(len(x))])
                    preds[f"pooled-{w}"] = chan * g
                    # no per-pixel shape: the window's replicate spread alone (a pixel
                    # that has not met a rare bright path yet is judged by neighbours that have)
                    preds[f"window-{w}"] = np.array([box_sum(reps[k], w) for k in range(len(x))]) / \
                        np.maximum(box_sum(np.ones_like(reps[0]), w), 1)
                    del gain
                    # the pixel's own replicates and the pooled value, weighed by
                    # degrees of freedom (r - 1 against a prior worth SHRINK)
                    for a in SHRINK:
                        preds[f"shrink-{w}-{a}"] = (a * chan * g + (r - 1) * reps) / (a + r - 1)
            for pname, pred in preds.items():
                ratio, share = judge(x, pred, truth, tv, mask)
                row["predictors"][pname] = {"ratio": ratio, "share196": share}
            rows.append(row)
            log(f"{name} {n} spp {dname:7s} relMSE x{relmse / base:5.3f}  " +
                "  ".join(f"{p} {v['ratio']:6.3f}/{v['share196']:.3f}"
                          for p, v in row["predictors"].items()))
    return rows


def main():
    rows = []
    for name in SCENES:
        rows += study_scene(name)
    os.makedirs(os.path.dirname(OUT), exist_ok=True)
    with open(OUT, "w") as f:
        json.dump({"size": SIZE, "K": K, "rows": rows}, f, indent=1)
    print(f"{'scene':15s} {'spp':>5s} {'design':7s} {'relMSE/1':>8s}  predictor: ratio / 1.96-share")
    for r in rows:
        print(f"{r['scene']:15s} {r['spp']:5d} {r['design']:7s} {r['relmse_over_single']:8.3f}  " +
              "  ".join(f"{p} {v['ratio']:.3f}/{v['share196']:.3f}"
                        for p, v in r["predictors"].items()))


if __name__ == "__main__":
    main()
