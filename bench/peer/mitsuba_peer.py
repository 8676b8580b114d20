#!/usr/bin/env python3
"""Render a vbrender scene (scenes/*.json) with Mitsuba 3.

Translates every shape (quad, triangles, sphere, mesh with transform) and
material (diffuse, emitter, mirror, dielectric) of common/scene.c into the same
world-space triangles, written as PLY files (smooth normals where scene.c has
them), so Mitsuba renders the image vbrender converges to.

Peer renderer for speed and accuracy benchmarks. Run inside bench/venv with
bench/peer/env.sh sourced (see bench/peer/README.md):

  mitsuba_peer.py SCENE.json --mode speed  --spp N --threads T [--runs K]
  (SCENE may also be a Mitsuba scene file, SCENE.xml: loaded as it is, with
  --sampler for its sampler's type, --spp for $spp and --width for $res)
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
--sampler picks Mitsuba's sampler; counts it would round are refused.
--isa avx2 runs Mitsuba as an AVX2-only host would, on a host with AVX-512:
Dr.Jit's LLVM backend compiles for Haswell at 8 lanes, and its bundled
Embree is capped at AVX2 (bench/peer/embree_isa.c, preloaded: the script
runs itself again with it; MITSUBA_PEER_EMBREE_SHIM from env.sh).
Diagnostics go to stderr.
"""
import argparse
import json
import math
import os
import re
import statistics
import sys
import tempfile
import time


SAMPLERS = ["independent", "stratified", "multijitter", "orthogonal", "ldsampler"]


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
    ap.add_argument("--sampler", default="independent", choices=SAMPLERS,
                    help="Mitsuba sampler (default independent)")
    ap.add_argument("--variant", default=os.environ.get("MITSUBA_PEER_VARIANT", "llvm_ad_rgb"))
    ap.add_argument("--isa", choices=["native", "avx2"], default="native",
                    help="native: what the host runs; avx2: as an AVX2-only host (llvm variants)")
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
    if a.isa != "native" and not a.variant.startswith("llvm"):
        ap.error("--isa avx2 needs an llvm variant")
    return a


# ---- --isa avx2: the peer as an AVX2-only host runs it ------------------

# Dr.Jit's LLVM target for an AVX2 host (drjit-core's jit_llvm_set_target,
# not in its Python API), and the features it must not use.
AVX2_CPU = b"haswell"
AVX2_FEATURES = b"-avx512f,-avx512vl,-avx512dq,-avx512bw,-avx512cd,+avx2,+fma"
AVX2_LANES = 8


def preload_embree_shim():
    """Runs this script again with the shim that caps Mitsuba's Embree at
    AVX2 preloaded (it must be there before Mitsuba's libraries load)."""
    if os.environ.get("VB_EMBREE_ISA"):
        return
    import importlib.util
    spec = importlib.util.find_spec("mitsuba")
    shim = os.environ.get("MITSUBA_PEER_EMBREE_SHIM", "")
    if spec is None or not shim or not os.path.exists(shim):
        raise SystemExit("mitsuba_peer.py: --isa avx2 needs mitsuba and the Embree shim "
                         "(run bench/peer/setup.sh, then source bench/peer/env.sh)")
    env = dict(os.environ)
    env["VB_EMBREE_ISA"] = "isa=avx2"
    env["VB_EMBREE_LIB"] = os.path.join(os.path.dirname(spec.origin), "libembree3.so")
    env["LD_PRELOAD"] = shim + (":" + env["LD_PRELOAD"] if env.get("LD_PRELOAD") else "")
    os.execve(sys.executable, [sys.executable] + sys.argv, env)


def cap_llvm_target(dr):
    """Dr.Jit's LLVM backend compiles for an AVX2 host from here on."""
    import ctypes
    core = ctypes.CDLL(os.path.join(os.path.dirname(dr.__file__), "libdrjit-core.so"))
    set_target = core._Z19jit_llvm_set_targetPKcS0_j
    set_target.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_uint32]
    set_target(AVX2_CPU, AVX2_FEATURES, AVX2_LANES)
    cpu = core._Z19jit_llvm_target_cpuv
    cpu.restype = ctypes.c_char_p
    if cpu() != AVX2_CPU:
        raise SystemExit(f"mitsuba_peer.py: Dr.Jit kept its LLVM target {cpu()!r}")
    return cpu().decode()


def embree_config_applied():
    """The config Mitsuba's Embree device got through the shim, or None."""
    import ctypes
    libc = ctypes.CDLL(None)
    libc.getenv.restype = ctypes.c_char_p
    v = libc.getenv(b"VB_EMBREE_ISA_APPLIED")
    return v.decode() if v else None


# ---- geometry: the world-space triangles common/scene.c builds ----------

def transform_of(sh):
    """(M, nm, t, flips) as parse_transform in common/scene.c: M = Rz Ry Rx S,
    nm = Rz Ry Rx S^-1 for normals, translate last, flips on an odd number of
    negative scale components."""
    import numpy as np
    tr = sh.get("transform") or {}
    unknown = set(tr) - {"scale", "rotate", "translate"}
    if unknown:
        raise SystemExit(f"unsupported transform keys {sorted(unknown)}")
    sc = tr.get("scale", 1)
    sc = [float(sc)] * 3 if isinstance(sc, (int, float)) else [float(x) for x in sc]
    rot = [float(x) for x in tr.get("rotate", [0, 0, 0])]
    t = np.array([float(x) for x in tr.get("translate", [0, 0, 0])])

    def rotation(axis, deg):
        a = deg * 3.14159265358979323846 / 180.0
        c, s = math.cos(a), math.sin(a)
        r = np.zeros((3, 3))
        i, j = (axis + 1) % 3, (axis + 2) % 3
        r[axis, axis] = 1
        r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
        return r

    M = np.diag(sc)
    nm = np.diag([1 / x for x in sc])
    for axis in range(3):
        R = rotation(axis, rot[axis])
        M = R @ M
        nm = R @ nm
    return M, nm, t, sc[0] * sc[1] * sc[2] < 0


def apply_transform(xf, pos, nrm, faces):
    """World-space float32 positions and normals (push_vertex) and faces with
    the winding reversed under a mirroring transform (push_triangle)."""
    import numpy as np
    M, nm, t, flips = xf
    pos = np.asarray(pos, dtype=np.float64)
    # the same sum order as push_vertex: m0*x + m1*y + m2*z + t
    w = pos[:, 0:1] * M[:, 0] + pos[:, 1:2] * M[:, 1] + pos[:, 2:3] * M[:, 2] + t
    out_p = w.astype(np.float32)
    out_n = None
    if nrm is not None:
        n = np.asarray(nrm, dtype=np.float64)
        wn = n[:, 0:1] * nm[:, 0] + n[:, 1:2] * nm[:, 1] + n[:, 2:3] * nm[:, 2]
        ln = np.sqrt((wn * wn).sum(axis=1, keepdims=True))
        if not (np.all(ln > 0) and np.all(np.isfinite(ln))):
            raise SystemExit("a vertex normal is zero or not finite (flat fallback unsupported)")
        out_n = (wn / ln).astype(np.float32)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if flips:
        faces = faces[:, [0, 2, 1]]
    return out_p, out_n, faces


def icosphere(center, radius, sub):
    """shape_sphere in common/scene.c: each icosahedron face split into a
    (2^n)^2 grid by barycentric steps, every corner projected onto the
    sphere, no shared vertices; normals (p - c) / r."""
    import numpy as np
    g = (1.0 + math.sqrt(5.0)) / 2.0
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
             (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
             (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    ico = np.array([(-1, g, 0), (1, g, 0), (-1, -g, 0), (1, -g, 0), (0, -1, g), (0, 1, g),
                    (0, -1, -g), (0, 1, -g), (g, 0, -1), (g, 0, 1), (-g, 0, -1), (-g, 0, 1)])
    k = 1 << sub
    bary = []  # (i, j) corners of each sub-triangle, in scene.c's order
    for i in range(k):
        for j in range(k - i):
            bary.append(((i, j), (i + 1, j), (i, j + 1)))
            if i + j + 1 < k:
                bary.append(((i + 1, j), (i + 1, j + 1), (i, j + 1)))
    ab = np.array(bary, dtype=np.float64).reshape(-1, 2) / float(k)
    a, b = ab[:, 0:1], ab[:, 1:2]
    c = np.asarray(center, dtype=np.float64)
    pos, nrm = [], []
    for f in faces:
        A, B, C = ico[f[0]], ico[f[1]], ico[f[2]]
        n = A * (1 - a - b) + B * a + C * b
        ln = np.sqrt(n[:, 0:1] * n[:, 0:1] + n[:, 1:2] * n[:, 1:2] + n[:, 2:3] * n[:, 2:3])
        n = n / ln
        nrm.append(n)
        pos.append(c + float(radius) * n)
    pos = np.concatenate(pos)
    return pos, np.concatenate(nrm), np.arange(len(pos)).reshape(-1, 3)


def ply_has_normals(path):
    with open(path, "rb") as f:
        head = f.read(65536).split(b"end_header", 1)[0].decode("ascii", "replace")
    props = [ln.split()[-1] for ln in head.splitlines() if ln.startswith("property")]
    return {"nx", "ny", "nz"} <= set(props)


def load_obj(path):
    """common/obj.c: "v x y z" as float, "f a[/t[/n]] ..." as a triangle fan,
    negative indices relative to the vertices so far; the rest (vn too) is
    skipped. Mitsuba's obj loader refuses negative indices, hence our own."""
    import numpy as np
    pos, faces = [], []
    with open(path) as f:
        for line in f:
            w = line.split("#", 1)[0].split()
            if not w or w[0] not in ("v", "f"):
                continue
            if w[0] == "v":
                pos.append([float(x) for x in w[1:4]])
                continue
            idx = [int(c.split("/")[0]) for c in w[1:]]
            idx = [x + len(pos) if x < 0 else x - 1 for x in idx]
            if len(idx) < 3:
                raise SystemExit(f"{path}: a face with fewer than 3 vertices")
            faces += [(idx[0], idx[k - 1], idx[k]) for k in range(2, len(idx))]
    return np.array(pos, dtype=np.float32).astype(np.float64), None, faces


def load_mesh_file(mi, path):
    """Positions, normals (PLY nx ny nz only, as common/ply.c; OBJ vn are
    skipped there) and faces; PLY is read with Mitsuba's own loader."""
    import numpy as np
    if path.lower().endswith(".obj"):
        return load_obj(path)
    with open(path, "rb") as f:
        if f.read(3) != b"ply":
            raise SystemExit(f"{path}: neither PLY (magic) nor .obj")
    normals = ply_has_normals(path)
    m = mi.load_dict({"type": "ply", "filename": path, "face_normals": not normals})
    pos = np.array(m.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3)
    faces = np.array(m.faces_buffer(), dtype=np.int64).reshape(-1, 3)
    nrm = None
    if normals:
        nrm = np.array(m.vertex_normals_buffer(), dtype=np.float64).reshape(-1, 3)
    return pos, nrm, faces


def shape_geometry(mi, sh, i, scene_dir):
    """(positions, normals or None, faces) of shape i in world space."""
    kind = sh.get("type")
    if kind == "quad":
        if len(sh["vertices"]) != 4:
            raise SystemExit(f"shapes[{i}]: quad needs 4 vertices")
        pos, nrm, faces = sh["vertices"], None, [(0, 1, 2), (0, 2, 3)]
    elif kind == "triangles":
        pos, nrm, faces = sh["vertices"], None, sh["indices"]
    elif kind == "sphere":
        pos, nrm, faces = icosphere(sh["center"], sh["radius"], int(sh.get("subdivisions", 4)))
    elif kind == "mesh":
        path = sh["file"]
        if not os.path.isabs(path):
            path = os.path.join(scene_dir, path)
        pos, nrm, faces = load_mesh_file(mi, path)
    else:
        raise SystemExit(f"shapes[{i}]: unsupported shape type {kind!r}")
    return apply_transform(transform_of(sh), pos, nrm, faces)


def write_ply(path, pos, nrm, faces):
    """Binary PLY of float32 positions (and normals) and int32 triangles,
    winding kept: the face normal is cross(v1-v0, v2-v0) as in vbrender, and
    Mitsuba's area emitter emits on the side of that normal."""
    import numpy as np
    props = ["x", "y", "z"] + (["nx", "ny", "nz"] if nrm is not None else [])
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {len(pos)}\n"
              + "".join(f"property float {p}\n" for p in props)
              + f"element face {len(faces)}\n"
              "property list uchar int vertex_indices\nend_header\n")
    vert = pos if nrm is None else np.concatenate([pos, nrm], axis=1)
    face = np.zeros(len(faces), dtype=[("n", "u1"), ("v", "<i4", 3)])
    face["n"] = 3
    face["v"] = faces
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(np.ascontiguousarray(vert, dtype="<f4").tobytes())
        f.write(face.tobytes())


# ---- materials and the scene ---------------------------------------------

def rgb(v):
    return {"type": "rgb", "value": [float(x) for x in v]}


def material_dict(m, name):
    """BSDF (and area emitter) for one of our materials (common/material.h).
    Ours shade both sides of a surface; Mitsuba's diffuse and conductor only
    the front, hence twosided. Emitters are one-sided in both."""
    t = m.get("type")
    if t == "diffuse":
        return {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": rgb(m["albedo"])}}, None
    if t == "emitter":
        # does not reflect unless it has an albedo (then diffusely)
        bsdf = {"type": "twosided",
                "bsdf": {"type": "diffuse", "reflectance": rgb(m.get("albedo", [0, 0, 0]))}}
        return bsdf, {"type": "area", "radiance": rgb(m["radiance"])}
    if t == "mirror":
        return {"type": "twosided", "bsdf": {"type": "conductor", "material": "none",
                                             "specular_reflectance": rgb(m.get("reflectance", [1, 1, 1]))}}, None
    if t == "dielectric":
        # our ior is inside over outside, outside where the normal points
        return {"type": "dielectric", "int_ior": float(m.get("ior", 1.5)), "ext_ior": 1.0}, None
    raise SystemExit(f"material {name!r}: unsupported type {t!r}")


def sensor_dict(mi, cam, w, h, sampler, spp, seed):
    # Mitsuba's look_at maps camera-local +x to cross(up, dir) ("left"), and its
    # film x axis runs the other way, so a plain look_at already gives the
    # physically correct, non-mirrored image (red wall at x~556 on the left,
    # same as vbrender). Verified by the left/right column check in --mode render.
    to_world = mi.ScalarTransform4f().look_at(origin=cam["position"], target=cam["look_at"],
                                              up=cam.get("up", [0, 1, 0]))
    return {
        "type": "perspective", "fov_axis": "y", "fov": float(cam["fov"]), "to_world": to_world,
        "sampler": {"type": sampler, "sample_count": spp, "seed": seed},
        "film": {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "box"},
                 "pixel_format": "rgb", "component_format": "float32"},
    }


def build_scene_dict(mi, scene, scene_dir, tmpdir, spp, seed, width=None, height=None,
                     sampler="independent"):
    cam = scene["camera"]
    w = int(width or cam["width"])
    h = int(height or cam["height"])
    mats = scene["materials"]
    # our max_depth counts path segments as Mitsuba's does (1: emitters seen
    # directly); 0 is unlimited. Our "naive" integrator converges to the same
    # image as Mitsuba's path tracer, so it is not translated.
    depth = int(scene.get("render", {}).get("max_depth", 0))
    d = {"type": "scene", "integrator": {"type": "path", "max_depth": depth or -1},
         "sensor": sensor_dict(mi, cam, w, h, sampler, spp, seed)}
    for i, sh in enumerate(scene["shapes"]):
        name = sh.get("material")
        if name not in mats:
            raise SystemExit(f"shapes[{i}]: unknown material {name!r}")
        bsdf, emitter = material_dict(mats[name], name)
        pos, nrm, faces = shape_geometry(mi, sh, i, scene_dir)
        path = os.path.join(tmpdir, f"shape{i}.ply")
        write_ply(path, pos, nrm, faces)
        # smooth shading only where scene.c has vertex normals (sphere, PLY nx ny nz)
        s = {"type": "ply", "filename": path, "face_normals": nrm is None, "bsdf": bsdf}
        if emitter:
            s["emitter"] = emitter
        d[f"shape{i:03d}"] = s
    return d, w, h


def check_sample_counts(mi, sampler, spps):
    """Refuse counts Mitsuba's sampler would silently round (stratified,
    multijitter, ldsampler: squares / powers of two; orthogonal: squares of
    primes), so every render has exactly the spp asked for."""
    for n in spps:
        got = mi.load_dict({"type": sampler, "sample_count": n}).sample_count()
        if got != n:
            raise SystemExit(f"sampler {sampler!r} cannot take {n} spp (it would use {got}); "
                             "choose counts it accepts as they are")


def mode_speed(a, render, info, npix):
    twarm, _ = render(a.seed)  # compiles / loads kernels
    times = []
    for k in range(a.runs):
        t, _ = render(a.seed + 1 + k)
        times.append(t)
        print(f"run {k}: {t:.3f} s", file=sys.stderr)
    best = min(times)
    med = statistics.median(times)
    sps = npix * a.spp / best
    info.update({"seconds_warmup": twarm, "seconds_best": best, "seconds_median": med,
                 "seconds_all": times, "samples_per_second": sps,
                 "samples_per_second_per_core": sps / a.threads})


def mode_sweep(mi, a, render, info, npix):
    os.makedirs(a.out_dir, exist_ok=True)
    runs = []
    for i, spp in enumerate(a.spps):
        twarm, _ = render(a.seed + 1000 + i, spp)  # kernel for this spp, caches
        t, arr = render(a.seed + i, spp)
        out = os.path.join(a.out_dir, f"mitsuba-{spp}.exr")
        mi.Bitmap(arr, mi.Bitmap.PixelFormat.RGB).write(out)
        runs.append({"spp": spp, "seed": a.seed + i, "seconds": t, "seconds_warmup": twarm,
                     "samples": npix * spp, "out": out,
                     "mean_rgb": [float(x) for x in arr.reshape(-1, 3).mean(axis=0)]})
        print(f"spp {spp}: {t:.3f} s (warm-up {twarm:.3f} s)", file=sys.stderr)
    info.update({"seed": a.seed, "runs": runs})


def mode_agree(mi, np, a, render, info):
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


def mode_render(mi, np, a, render, info):
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


def load_xml(mi, a):
    """A Mitsuba scene file as it is, but for its sampler's type (--sampler)
    and, where given, its $res (--width). Its files are found beside it
    (the copy that Mitsuba loads lives in a temporary folder)."""
    with open(a.scene) as f:
        text = f.read()
    text, n = re.subn(r'<sampler\s+type="[^"]*"', f'<sampler type="{a.sampler}"', text, count=1)
    if n != 1:
        raise SystemExit(f"{a.scene}: no <sampler type=...> to set")
    mi.Thread.thread().file_resolver().append(os.path.dirname(os.path.abspath(a.scene)))
    params = {"spp": str(a.spp)}
    if a.width:
        params["res"] = str(a.width)
    with tempfile.TemporaryDirectory(prefix="mitsuba_peer_") as tmp:
        path = os.path.join(tmp, os.path.basename(a.scene))
        with open(path, "w") as f:
            f.write(text)
        scene = mi.load_file(path, **params)
    size = scene.sensors()[0].film().size()
    return scene, int(size[0]), int(size[1])


def main():
    a = parse_args()
    if a.isa == "avx2":
        preload_embree_shim()
    import drjit as dr
    import mitsuba as mi
    import numpy as np

    dr.set_thread_count(a.threads)
    mi.set_variant(a.variant)
    llvm_target = cap_llvm_target(dr) if a.isa == "avx2" else None
    mi.set_log_level(mi.LogLevel.Warn)
    dr.set_thread_count(a.threads)  # again, in case the backend reset it on init

    spps = a.spps if a.mode == "sweep" else [a.spp]
    check_sample_counts(mi, a.sampler, spps)
    scene_dir = os.path.dirname(os.path.abspath(a.scene))
    # Loading with one thread waits forever on envmap.xml (its environment
    # map's tasks wait on a pool of that one thread, 0 % CPU): load with two,
    # render with the count asked for (the renders' times leave loading out).
    dr.set_thread_count(max(2, a.threads))
    # seconds_load: Mitsuba's own loading of the scene (its parse, its
    # meshes read, its BVH built), which a user waits for before every
    # render of a scene, as for our workers' loading; for our JSON scenes
    # the conversion to Mitsuba's dictionary (and the PLY files it writes)
    # is ours and not counted, for its XML files the copy with the sampler
    # set (a few milliseconds at most) is
    def timed(load):
        t0 = time.perf_counter()
        out = load()
        dr.eval()
        dr.sync_thread()
        return out, time.perf_counter() - t0

    if a.scene.endswith(".xml"):
        (scene, w, h), t_load = timed(lambda: load_xml(mi, a))
    else:
        with open(a.scene) as f:
            scene_json = json.load(f)
        with tempfile.TemporaryDirectory(prefix="mitsuba_peer_") as tmp:
            sd, w, h = build_scene_dict(mi, scene_json, scene_dir, tmp, a.spp, a.seed, a.width,
                                        a.height, a.sampler)
            scene, t_load = timed(lambda: mi.load_dict(sd))
    dr.set_thread_count(a.threads)

    def render(seed, spp=None):
        t0 = time.perf_counter()
        img = mi.render(scene, spp=spp or a.spp, seed=seed)
        arr = np.array(img, dtype=np.float32)  # forces evaluation
        dr.sync_thread()
        return time.perf_counter() - t0, arr

    info = {"variant": a.variant, "sampler": a.sampler, "threads": a.threads, "spp": a.spp,
            "width": w, "height": h, "version": mi.__version__, "drjit_version": dr.__version__,
            "drjit_thread_count": dr.thread_count(), "seconds_load": t_load}
    if a.variant.startswith("llvm"):
        info["libllvm"] = os.environ.get("DRJIT_LIBLLVM_PATH", "")
    info["isa"] = a.isa
    if a.isa == "avx2":
        # the scene is loaded, so Mitsuba's Embree device exists
        applied = embree_config_applied()
        if not applied or "isa=avx2" not in applied:
            raise SystemExit("mitsuba_peer.py: Mitsuba's Embree was not capped at AVX2 (the shim "
                             "did not run)")
        info["llvm_target"] = llvm_target
        info["embree_config"] = applied
    if a.mode == "speed":
        mode_speed(a, render, info, w * h)
    elif a.mode == "sweep":
        mode_sweep(mi, a, render, info, w * h)
    elif a.mode == "agree":
        mode_agree(mi, np, a, render, info)
    else:
        mode_render(mi, np, a, render, info)
    print(json.dumps(info))


if __name__ == "__main__":
    main()
