#!/usr/bin/env python3
"""Check that mitsuba_peer.py renders the image vbrender converges to.

  check_peer.py agree SCENE.json [--size 64] [--ref-spp 4096] [--spp 1024 --passes 4]
  check_peer.py samplers SCENE.json [--size 64] [--ref-spp 4096] [--spp 256 --seeds 3]

Run with $MITSUBA_PEER_PYTHON (bench/peer/env.sh sourced) after `make all`.
Both make a resized copy of the scene (mesh paths made absolute, as
sized_scene() in bench/error/study.py) and a vbrender reference from K
uniform renders (seeds 1..K, independent sampler; their spread estimates its
noise).
agree: a `mitsuba_peer.py --mode agree` render against it, with the figures of
peer() in study.py: image means and their difference in standard errors,
relMSE against the noise-only expectation, 8x8-block z-test.
samplers: relMSE of single Mitsuba renders per sampler (mean over seeds, the
reference's own noise subtracted), and Mitsuba's speed per sampler (at the
scene's size given by --size; orthogonal at the square of a prime nearest --spp).
Prints one JSON object; renders go to a temp dir.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
PEER = os.path.join(ROOT, "bench", "peer", "mitsuba_peer.py")
EPS = 1e-2  # common/compare.h COMPARE_EPS, as study.py


def read_rgb(mi, path, names=("R", "G", "B")):
    b = mi.Bitmap(path)
    chans = [f.name for f in b.struct_()]
    a = np.array(b, dtype=np.float64)
    return np.stack([a[:, :, chans.index(n)] for n in names], axis=2)


def sized_scene(src, size, tmp):
    with open(src) as f:
        d = json.load(f)
    d["camera"]["width"] = d["camera"]["height"] = size
    for sh in d["shapes"]:
        if "file" in sh and not os.path.isabs(sh["file"]):
            sh["file"] = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(src)), sh["file"]))
    dst = os.path.join(tmp, os.path.basename(src))
    with open(dst, "w") as f:
        json.dump(d, f)
    return dst


def reference(mi, scene, spp, sampler, parts, tmp):
    """Mean of `parts` uniform vbrender renders (seeds 1..parts) and the
    variance of that mean from their spread."""
    imgs = []
    for k in range(parts):
        out = os.path.join(tmp, f"ref-part{k}.exr")
        subprocess.run([os.path.join(ROOT, "bin", "vbrender"), "render", scene, "-o", out,
                        "--spp", str(spp // parts), "--adaptive", "none", "--seed", str(1 + k),
                        "--workers", "1", "--threads", "2", "--progress", "none", "--sampler", sampler],
                       check=True, stdout=subprocess.DEVNULL)
        imgs.append(read_rgb(mi, out))
    imgs = np.stack(imgs)
    return imgs.mean(axis=0), imgs.var(axis=0, ddof=1) / parts


def peer(args):
    return json.loads(subprocess.run([sys.executable, PEER] + args, check=True,
                                     stdout=subprocess.PIPE, text=True).stdout.strip().splitlines()[-1])


def agreement_figures(mm, var_m, r, var_r):
    """peer()'s agreement figures in bench/error/study.py for image mm (variance
    of its mean var_m) against reference r (var_r): relMSE against the
    noise-only expectation, 8x8-block z-test, image means in standard errors.
    study.py may import this instead of its own copy of the block test."""
    B = 8
    H, W = r.shape[:2]
    hb, wb = H // B, W // B
    var = var_m + var_r
    d = (mm - r)[:hb * B, :wb * B].reshape(hb, B, wb, B, 3).mean(axis=(1, 3))
    vd = var[:hb * B, :wb * B].reshape(hb, B, wb, B, 3).sum(axis=(1, 3)) / (B * B) ** 2
    zb = d / np.sqrt(np.maximum(vd, 1e-30))
    mean_m, mean_r = mm.reshape(-1, 3).mean(axis=0), r.reshape(-1, 3).mean(axis=0)
    se = np.sqrt(var.reshape(-1, 3).sum(axis=0)) / (H * W)
    return {"mean_rgb_mitsuba": mean_m.tolist(), "mean_rgb_vbrender": mean_r.tolist(),
            "mean_rel_diff": ((mean_m - mean_r) / mean_r).tolist(),
            "mean_diff_in_sigma": ((mean_m - mean_r) / se).tolist(),
            "relmse": float(np.mean((mm - r) ** 2 / (r * r + EPS))),
            "relmse_expected_from_noise": float(np.mean(var / (r * r + EPS))),
            "block_z_chi2_per_dof": float(np.mean(zb ** 2)), "block_z_max_abs": float(np.abs(zb).max()),
            "blocks": int(zb.size), "blocks_over_4_sigma": int((np.abs(zb) > 4).sum())}


def agree(mi, a, scene, r, var_r, tmp):
    out = os.path.join(tmp, "agree.exr")
    info = peer([scene, "--mode", "agree", "--spp", str(a.spp), "--passes", str(a.passes),
                 "--threads", "2", "--seed", "900", "--sampler", a.sampler, "--out", out])
    res = agreement_figures(read_rgb(mi, out), read_rgb(mi, out, ("varR", "varG", "varB")), r, var_r)
    res.update({"mitsuba_seconds": info["seconds"], "nonfinite_pixels": info["nonfinite_pixels"]})
    return res


def nearest_prime_square(n):
    """Mitsuba's orthogonal sampler takes only squares of primes."""
    primes = [p for p in range(2, 200) if all(p % q for q in range(2, p))]
    return min((p * p for p in primes), key=lambda x: abs(x - n))


def samplers(mi, a, scene, r, var_r, tmp):
    ref_rel = float(np.mean(var_r / (r * r + EPS)))
    rows = {}
    for s in ("independent", "stratified", "multijitter", "orthogonal", "ldsampler"):
        spp = nearest_prime_square(a.spp) if s == "orthogonal" else a.spp
        rel = []
        for k in range(a.seeds):
            out = os.path.join(tmp, f"{s}-{k}.exr")
            peer([scene, "--mode", "render", "--spp", str(spp), "--threads", "2",
                  "--seed", str(100 + k), "--sampler", s, "--out", out])
            m = read_rgb(mi, out)
            rel.append(float(np.mean((m - r) ** 2 / (r * r + EPS))) - ref_rel)
        sp = peer([scene, "--mode", "speed", "--spp", str(spp), "--threads", "2", "--runs", "3",
                   "--sampler", s])
        rows[s] = {"spp": spp, "relmse": float(np.mean(rel)), "relmse_per_seed": rel,
                   "seconds_best": sp["seconds_best"], "samples_per_second": sp["samples_per_second"]}
    return {"reference_relmse_est": ref_rel, "samplers": rows}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", choices=["agree", "samplers"])
    ap.add_argument("scene")
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--ref-spp", type=int, default=4096)
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--passes", type=int, default=4)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--sampler", default="independent", help="Mitsuba's (agree)")
    # independent: pixels' errors are independent, as the block test and the
    # standard error of the image mean assume (sobol's need not be)
    ap.add_argument("--ref-parts", type=int, default=4, help="vbrender renders making the reference")
    ap.add_argument("--ref-sampler", default="independent", help="vbrender's")
    a = ap.parse_args()
    import mitsuba as mi
    mi.set_variant(os.environ.get("MITSUBA_PEER_VARIANT", "llvm_ad_rgb"))
    with tempfile.TemporaryDirectory(prefix="check_peer_") as tmp:
        scene = sized_scene(a.scene, a.size, tmp)
        r, var_r = reference(mi, scene, a.ref_spp, a.ref_sampler, a.ref_parts, tmp)
        res = (agree if a.what == "agree" else samplers)(mi, a, scene, r, var_r, tmp)
    res.update({"scene": os.path.basename(a.scene), "size": a.size, "ref_spp": a.ref_spp})
    print(json.dumps(res))


if __name__ == "__main__":
    main()
