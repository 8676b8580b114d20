#!/usr/bin/env python3
"""Does --target-error E --confidence C hold on every pixel? (issue 24, item 2)

For each shipped scene (VB_COV_SCENES: scenes/*.json by name and the
Mitsuba files as mitsuba/NAME) at SIZE x SIZE pixels, E in VB_COV_E and C in VB_COV_C:
the share of pixels within E of an independent reference, counted as the
issue counts it:

- every pixel whose reference is above 1e-3 of the image mean counts, dark
  ones included;
- a pixel is missed when |x - ref| > E ref + 2 sigma_ref, sigma_ref the
  reference's own standard error, from its replicates: the reference is the
  mean of REF_REPLICATES independent renders (seeds), each a Sobol sequence
  per pixel, and sigma_ref^2 = sum (m_r - ref)^2 / (R (R - 1));
- pixels whose reference is too noisy to judge (sigma_ref > E ref / 2) are
  counted and reported, and left out of the share.

Each reference pixel gets at least VB_COV_REF_FLOOR layers of G = 32 in all
(2^18 samples by default), more where a pilot says a noise of E_min / 5 needs
them, up to VB_COV_REF_CAP (2^20 samples). bench_batches traces the layers
(bit for bit what the master's tasks trace), target.py's simulation applies
the shipped rule to them, and the real `vbrender render --target-error E
--confidence C` runs on the same seed: its share is the one reported, its
samples per pixel checked against the simulation's, and its count of pixels
that stopped by the rule against those that ran to the cap.

    bench/venv/bin/python bench/error/coverage.py     (after make all)
Writes bench/results/coverage.json and prints the coverage table.
"""
import json
import os
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import study as S  # noqa: E402  (the shipped scenes)
import target as T  # noqa: E402  (bench_batches runs, the rule's simulation)

ROOT = T.ROOT
SIZE = int(os.environ.get("VB_COV_SIZE", "32"))
ERRORS = [float(x) for x in os.environ.get("VB_COV_E", "0.02,0.05,0.1").split(",")]
CONFS = [float(x) for x in os.environ.get("VB_COV_C", "0.9,0.95").split(",")]
SCENES = os.environ.get("VB_COV_SCENES", ",".join(S.shipped_scenes())).split(",")
REF_REPLICATES = 4
REF_FLOOR = int(os.environ.get("VB_COV_REF_FLOOR", str(2 ** 18 // 32)))  # layers, all replicates
REF_CAP = int(os.environ.get("VB_COV_REF_CAP", str(2 ** 20 // 32)))
# VB_COV_MASTER=0: the simulation alone (no master runs); VB_COV_RULES: the rules of
# target.py simulated besides the shipped one, each reported with its share and samples
MASTER = os.environ.get("VB_COV_MASTER", "1") == "1"
# the master's --adaptive: none (what the simulation replays, pixel for pixel), or a
# rule (relmse, the default): then its share alone, its samples not compared
ADAPTIVE = os.environ.get("VB_COV_ADAPTIVE", "none")
RULES = [r for r in T.RULES if r.name in os.environ.get("VB_COV_RULES", T.SHIPPED.name).split(",")]
SEEDS = {"pilot": 2000001, "reference": 2000011, "run": 7}
G = T.CFG["granularity"]
T0 = time.time()


def log(msg):
    print(f"[{time.time() - T0:7.1f} s] {msg}", file=sys.stderr, flush=True)


def reference(scene, emin):
    """(ref, sigma_ref, layers) per pixel: REF_REPLICATES seeds, equal layers each."""
    pilot = T.batches(scene, SIZE, "cov-pilot", 64, SEEDS["pilot"], replicates=1)
    pm = pilot.mean(0)
    rel_sd = pilot.std(0, ddof=1) / (np.abs(pm) + 1e-3)
    need = np.ceil((1.6 * rel_sd / (emin / 5)) ** 2)
    per = np.ceil(np.clip(need, REF_FLOOR, REF_CAP) / REF_REPLICATES).astype(np.uint32)
    means = []
    for r in range(REF_REPLICATES):
        s = T.batches(scene, SIZE, f"cov-ref{r}", int(per.max()), SEEDS["reference"] + r, per,
                      summary=True, replicates=1)
        means.append(s[1])  # each replicate's mean of its layer means (equal layers: its mean)
    m = np.array(means)
    ref = m.mean(0)
    sigma = np.sqrt(((m - ref) ** 2).sum(0) / (REF_REPLICATES * (REF_REPLICATES - 1)))
    return ref, sigma, per.astype(np.int64) * REF_REPLICATES, rel_sd


def judge(est, ref, sigma, E):
    counted = ref > 1e-3 * ref.mean()
    judgeable = counted & (sigma <= E * ref / 2)
    missed = np.abs(est - ref) > E * ref + 2 * sigma
    return {"counted": int(counted.sum()), "unjudgeable": int((counted & ~judgeable).sum()),
            "share": float(1 - missed[judgeable].mean()) if judgeable.any() else None,
            "missed": int((missed & judgeable).sum()),
            "missed_dark": int((missed & judgeable & (ref < ref[counted].mean() / 4)).sum())}


def master(scene, name, E, C, cap):
    out = os.path.join(T.WORK, f"cov-{name.replace('/', '-')}-{SIZE}-E{E}-C{C}-{ADAPTIVE}.exr")
    cmd = [os.path.join(ROOT, "bin", "vbrender"), "render", scene, "-o", out, "--spp", str(cap),
           "--adaptive", ADAPTIVE, "--seed", str(SEEDS["run"]), "--target-error", str(E),
           "--confidence", str(C), "--workers", "2", "--threads", "1", "--progress", "none"]
    t0 = time.time()
    p = subprocess.run(cmd, check=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    ch = T.read_exr(out)
    est = (0.3 * ch["R"] + 0.59 * ch["G"] + 0.11 * ch["B"]).ravel()
    return est, ch["samples"].ravel(), time.time() - t0, p.stdout.strip().splitlines()[-1:]


def main():
    rows = []
    for name in SCENES:
        scene = T.sized_scene(name, SIZE)
        ref, sigma, ref_layers, rel_sd = reference(scene, min(ERRORS))
        log(f"{name}: reference {ref_layers.sum() * G:.3g} samples, sigma_ref/ref median "
            f"{np.median(sigma / np.maximum(ref, 1e-30)):.4f}")
        # the simulated run's layers: 4x what a correct rule needs at the smallest E by
        # the pilot, within the cap (as target.py); the master runs to the cap itself
        data = {"scene": scene, "size": SIZE}
        need_run = np.ceil(4 * (2.5 * rel_sd / min(ERRORS)) ** 2)
        run_counts = np.clip(need_run, T.RUN_FLOOR, T.CFG["run_layers"]).astype(np.uint32)
        data["run"] = T.batches(scene, SIZE, "cov-run", T.CFG["run_layers"], SEEDS["run"], run_counts)
        data["run_counts"] = run_counts
        for E in ERRORS:
            for C in CONFS:
                rules = {}
                for rule in RULES:
                    r_est, r_layers = T.simulate(data, rule, E, C)
                    rules[rule.name] = dict(judge(r_est, ref, sigma, E), mean_spp=float(r_layers.mean() * G))
                    log(f"{name} E={E} C={C} simulated {rule.name}: share {rules[rule.name]['share']:.3f}, "
                        f"mean spp {rules[rule.name]['mean_spp']:.0f}")
                est, layers = T.simulate(data, T.SHIPPED, E, C)
                sim = judge(est, ref, sigma, E)
                capped_sim = int((layers >= T.CFG["run_layers"]).sum())
                if not MASTER:
                    rows.append({"scene": name, "E": E, "C": C, "size": SIZE, "simulated": sim,
                                 "simulated_rules": rules, "mean_spp": float(layers.mean() * G)})
                    continue
                m_est, spp, secs, summary = master(scene, name, E, C, T.CFG["run_layers"] * G)
                got = judge(m_est, ref, sigma, E)
                traced = layers < run_counts  # the simulation saw the whole story
                same = (float(np.mean(spp[traced] == layers[traced] * G)) if traced.any() and ADAPTIVE == "none"
                        else None)
                row = {"scene": name, "E": E, "C": C, "size": SIZE, "master": got, "simulated": sim,
                       "mean_spp": float(spp.mean()), "capped_pixels": int((spp >= T.CFG["run_layers"] * G).sum()),
                       "capped_simulated": capped_sim, "simulated_rules": rules, "pixels_with_simulated_samples": same,
                       "seconds": secs, "summary": summary,
                       "reference": {"samples": float(ref_layers.sum() * G),
                                     "sigma_rel_median": float(np.median(sigma / np.maximum(ref, 1e-30)))}}
                rows.append(row)
                log(f"{name} E={E} C={C}: share {got['share']:.3f} (goal {C}), missed {got['missed']} "
                    f"({got['missed_dark']} dark), unjudgeable {got['unjudgeable']} of {got['counted']}, "
                    f"mean spp {spp.mean():.0f}, capped {row['capped_pixels']}, same as simulated {same}")
    out = os.environ.get("VB_COV_OUT", os.path.join(ROOT, "bench", "results", "coverage.json"))
    with open(out, "w") as f:
        json.dump({"size": SIZE, "adaptive": ADAPTIVE, "ref_replicates": REF_REPLICATES, "ref_floor_layers": REF_FLOOR,
                   "ref_cap_layers": REF_CAP, "rule": T.SHIPPED.name, "rows": rows}, f, indent=1)
    print(f"{'scene':15s} {'E':>5s} {'C':>5s} {'share':>6s} {'ok':>3s} {'missed':>6s} {'dark':>5s} "
          f"{'unjudg.':>7s} {'counted':>7s} {'mean spp':>9s} {'capped':>6s}")
    for r in rows:
        g = r.get("master", r["simulated"])
        ok = "yes" if g["share"] is not None and g["share"] >= r["C"] else "NO"
        print(f"{r['scene']:15s} {r['E']:5.2f} {r['C']:5.2f} {g['share']:6.3f} {ok:>3s} {g['missed']:6d} "
              f"{g['missed_dark']:5d} {g['unjudgeable']:7d} {g['counted']:7d} {r['mean_spp']:9.0f} "
              f"{r.get('capped_pixels', -1):6d}")
    log(f"wrote {os.path.relpath(out, ROOT)}")


if __name__ == "__main__":
    main()
