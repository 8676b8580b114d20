#!/usr/bin/env python3
"""Render vbrender's Cornell box scene (scenes/cornell-box.json) with Mitsuba 3.

Peer renderer for speed and accuracy benchmarks. Run inside bench/venv with
bench/peer/env.sh sourced (see bench/peer/README.md):

  mitsuba_peer.py SCENE.json --mode speed  --spp N --threads T [--runs K]
  mitsuba_peer.py SCENE.json --mode render --spp N --threads T --seed S --out FILE.exr
  mitsuba_peer.py SCENE.json --mode sweep  --spp-list 16,32,... --threads T --seed S --out-dir DIR
  mitsuba_peer.py SCENE.json --mode agree  --spp N --passes K --threads T --seed S --out FILE.exr

speed prints one JSON object on stdout; render writes a float32 linear RGB EXR and
prints a JSON object (seconds, mean RGB, left/right column red means) on stdout.
sweep renders once per spp value (a warm-up render at that spp first, then the
timed one with another seed), writes DIR/mitsuba-SPP.exr and prints JSON with the
seconds of each timed render (for error-against-time curves; bench/error/).
agree renders K independent passes of N spp (seeds S..S+K-1) and writes their
mean (R, G, B) plus the per-channel variance of that mean estimated from the
spread of the passes (channels varR, varG, varB), to check that Mitsuba and
vbrender converge to the same image.
Diagnostics go to stderr.
"""
import argparse
import json
import os
import statistics
import struct
import sys
import tempfile
import time


def parse_args():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", help="path to vbrender scene JSON")
    ap.add_argument("--mode", choices=["speed", "render", "sweep", "agree"], required=True)
    ap.add_argument("--spp", type=int, default=0)
    ap.add_argument("--spp-list", default="", help="comma-separated spp values (sweep mode)")
    ap.add_argument("--out-dir", help="output folder (sweep mode)")
    ap.add_argument("--passes", type=int, default=4, help="independent renders (agree mode)")
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", help="output EXR (render mode)")
    ap.add_argument("--runs", type=int, default=3, help="timed renders (speed mode)")
    ap.add_argument("--width", type=int, help="override camera width")
    ap.add_argument("--height", type=int, help="override camera height")
    ap.add_argument("--variant", default=os.environ.get("MITSUBA_PEER_VARIANT", "llvm_ad_rgb"))
    a = ap.parse_args()
    if a.mode in ("render", "agree") and not a.out:
        ap.error("--out is required in render and agree modes")
    if a.mode == "sweep":
        try:
            a.spps = [int(x) for x in a.spp_list.split(",") if x.strip()]
        except ValueError:
            ap.error("--spp-list must be comma-separated integers")
        if not a.spps or min(a.spps) < 1 or not a.out_dir:
            ap.error("sweep mode needs --spp-list (values >= 1) and --out-dir")
        a.spp = a.spps[0]
    if a.spp < 1 or a.threads < 1 or a.runs < 1 or a.passes < 2:
        ap.error("--spp, --threads and --runs must be >= 1, --passes >= 2")
    return a


def write_ply(path, verts):
    """Binary PLY with one quad = triangles (v0,v1,v2), (v0,v2,v3).

    The winding is kept, so the face normal is cross(v1-v0, v2-v0) exactly as in
    vbrender; Mitsuba's area emitter emits on the side of that normal."""
    header = ("ply\nformat binary_little_endian 1.0\n"
              "element vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
              "element face 2\nproperty list uchar int vertex_indices\nend_header\n")
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        for v in verts:
            f.write(struct.pack("<3f", *map(float, v)))
        for tri in ((0, 1, 2), (0, 2, 3)):
            f.write(struct.pack("<B3i", 3, *tri))


def build_scene_dict(mi, scene, tmpdir, spp, seed, width=None, height=None):
    cam = scene["camera"]
    w = int(width or cam["width"])
    h = int(height or cam["height"])
    mats = scene["materials"]
    T = mi.ScalarTransform4f
    # Mitsuba's look_at maps camera-local +x to cross(up, dir) ("left"), and its
    # film x axis runs the other way, so a plain look_at already gives the
    # physically correct, non-mirrored image (red wall at x~556 on the left,
    # same as vbrender). Verified by the left/right column check in --mode render.
    to_world = T().look_at(origin=cam["position"], target=cam["look_at"], up=cam["up"])
    d = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": -1},
        "sensor": {
            "type": "perspective",
            "fov_axis": "y",
            "fov": float(cam["fov"]),
            "to_world": to_world,
            "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
            "film": {
                "type": "hdrfilm",
                "width": w,
                "height": h,
                "rfilter": {"type": "box"},
                "pixel_format": "rgb",
                "component_format": "float32",
            },
        },
    }
    for i, sh in enumerate(scene["shapes"]):
        if sh["type"] != "quad":
            raise SystemExit(f"unsupported shape type {sh['type']!r} (only quads)")
        if len(sh["vertices"]) != 4:
            raise SystemExit(f"shape {i}: quad needs 4 vertices")
        path = os.path.join(tmpdir, f"shape{i}.ply")
        write_ply(path, sh["vertices"])
        m = mats[sh["material"]]
        s = {"type": "ply", "filename": path, "face_normals": True}
        if m["type"] == "diffuse":
            s["bsdf"] = {"type": "diffuse",
                         "reflectance": {"type": "rgb", "value": [float(x) for x in m["albedo"]]}}
        elif m["type"] == "emitter":
            # vbrender's emitter material does not reflect: give it a black BSDF.
            s["bsdf"] = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}
            s["emitter"] = {"type": "area",
                            "radiance": {"type": "rgb", "value": [float(x) for x in m["radiance"]]}}
        else:
            raise SystemExit(f"unsupported material type {m['type']!r}")
        d[f"shape{i:03d}"] = s
    return d, w, h


def main():
    a = parse_args()
    import drjit as dr
    import mitsuba as mi
    import numpy as np

    dr.set_thread_count(a.threads)
    mi.set_variant(a.variant)
    mi.set_log_level(mi.LogLevel.Warn)
    dr.set_thread_count(a.threads)  # again, in case the backend reset it on init

    with open(a.scene) as f:
        scene_json = json.load(f)
    with tempfile.TemporaryDirectory(prefix="mitsuba_peer_") as tmp:
        sd, w, h = build_scene_dict(mi, scene_json, tmp, a.spp, a.seed, a.width, a.height)
        scene = mi.load_dict(sd)

    def render(seed, spp=None):
        t0 = time.perf_counter()
        img = mi.render(scene, spp=spp or a.spp, seed=seed)
        arr = np.array(img, dtype=np.float32)  # forces evaluation
        dr.sync_thread()
        return time.perf_counter() - t0, arr

    info = {"variant": a.variant, "threads": a.threads, "spp": a.spp, "width": w, "height": h,
            "version": mi.__version__, "drjit_version": dr.__version__,
            "drjit_thread_count": dr.thread_count()}
    if a.variant.startswith("llvm"):
        info["libllvm"] = os.environ.get("DRJIT_LIBLLVM_PATH", "")

    if a.mode == "speed":
        twarm, _ = render(a.seed)  # compiles / loads kernels
        times = []
        for k in range(a.runs):
            t, _ = render(a.seed + 1 + k)
            times.append(t)
            print(f"run {k}: {t:.3f} s", file=sys.stderr)
        best = min(times)
        med = statistics.median(times)
        sps = w * h * a.spp / best
        info.update({"seconds_warmup": twarm, "seconds_best": best, "seconds_median": med,
                     "seconds_all": times, "samples_per_second": sps,
                     "samples_per_second_per_core": sps / a.threads})
        print(json.dumps(info))
        return

    if a.mode == "sweep":
        os.makedirs(a.out_dir, exist_ok=True)
        runs = []
        for i, spp in enumerate(a.spps):
            twarm, _ = render(a.seed + 1000 + i, spp)  # kernel for this spp, caches
            t, arr = render(a.seed + i, spp)
            out = os.path.join(a.out_dir, f"mitsuba-{spp}.exr")
            mi.Bitmap(arr, mi.Bitmap.PixelFormat.RGB).write(out)
            runs.append({"spp": spp, "seed": a.seed + i, "seconds": t, "seconds_warmup": twarm,
                         "samples": w * h * spp, "out": out,
                         "mean_rgb": [float(x) for x in arr.reshape(-1, 3).mean(axis=0)]})
            print(f"spp {spp}: {t:.3f} s (warm-up {twarm:.3f} s)", file=sys.stderr)
        info.update({"seed": a.seed, "runs": runs})
        print(json.dumps(info))
        return

    if a.mode == "agree":
        s1 = None
        s2 = None
        total = 0.0
        for k in range(a.passes):
            t, arr = render(a.seed + k)
            arr = arr.astype(np.float64)
            s1 = arr if s1 is None else s1 + arr
            s2 = arr * arr if s2 is None else s2 + arr * arr
            total += t
            print(f"pass {k}: {t:.3f} s", file=sys.stderr)
        K = a.passes
        mean = s1 / K
        var_of_mean = np.maximum(s2 / K - mean * mean, 0.0) * K / (K - 1) / K
        out = np.concatenate([mean, var_of_mean], axis=2).astype(np.float32)
        mi.Bitmap(out, mi.Bitmap.PixelFormat.MultiChannel,
                  ["R", "G", "B", "varR", "varG", "varB"]).write(a.out)
        info.update({"seed": a.seed, "passes": K, "out": a.out, "seconds": total,
                     "mean_rgb": [float(x) for x in mean.reshape(-1, 3).mean(axis=0)],
                     "nonfinite_pixels": int((~np.isfinite(mean)).any(axis=2).sum())})
        print(json.dumps(info))
        return

    t, arr = render(a.seed)
    mi.Bitmap(arr, mi.Bitmap.PixelFormat.RGB).write(a.out)
    left_r = float(arr[:, :20, 0].mean())
    right_r = float(arr[:, -20:, 0].mean())
    info.update({"seed": a.seed, "out": a.out, "seconds": t,
                 "mean_rgb": [float(x) for x in arr.reshape(-1, 3).mean(axis=0)],
                 "left20_mean_r": left_r, "right20_mean_r": right_r,
                 "red_on_left": left_r > right_r,
                 "nonfinite_pixels": int((~np.isfinite(arr)).any(axis=2).sum())})
    print(f"seconds {t:.3f}", file=sys.stderr)
    print(json.dumps(info))


if __name__ == "__main__":
    main()
