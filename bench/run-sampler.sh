#!/usr/bin/env bash
# run-sampler.sh - relMSE at equal samples per pixel of --sampler sobol
# against --sampler independent (issue 10, item 2), written to
# bench/results/sampler.json with a table on stdout.
#
# Each scene is copied to bench/work/sampler/ at SIZE x SIZE pixels and
# rendered uniformly (--adaptive none, G = 32) at each spp with both
# samplers and SEEDS seeds; each image is compared (`vbrender compare`,
# relMSE) with an independent-sampler reference at REF_SPP (seed 1000001,
# kept in bench/work/sampler/ while the scene copy is unchanged).
#
# The reference's own error adds to every measured relMSE (E[(a - r)^2] =
# E[(a - t)^2] + E[(r - t)^2] for independent a and r). Independent
# sampling's relMSE falls as 1/N, so the smallest-spp independent run, m at
# N spp, gives the reference's own as m N / (REF_SPP + N); "relmse" below is
# the measured value less that, "relmse_raw" the measured one.
#
# The peer, where bench/venv has Mitsuba 3 (bench/peer/setup.sh): the same
# scene, spp and seeds with Mitsuba's multijitter sampler (its best at equal
# time in the error study), against the same reference, so the table says
# how our error per sample compares with Mitsuba's. BENCH_SAMPLER_PEER=0
# leaves it out.
#
# Knobs (environment): BENCH_SAMPLER_SIZE (64), BENCH_SAMPLER_REF_SPP
# (32768), BENCH_SAMPLER_SEEDS (6), BENCH_SAMPLER_THREADS (2),
# BENCH_SAMPLER_CASES (scene:spp,spp,... list, see below),
# BENCH_SAMPLER_PEER (1). "s" columns are wall seconds per render on a
# shared host: indicative only.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"

SIZE="${BENCH_SAMPLER_SIZE:-64}"
REF_SPP="${BENCH_SAMPLER_REF_SPP:-32768}"
SEEDS="${BENCH_SAMPLER_SEEDS:-6}"
THREADS="${BENCH_SAMPLER_THREADS:-2}"
CASES="${BENCH_SAMPLER_CASES:-cornell-box:64,256,1024 caustic:64,256,1024 dark-bright:64,256}"
PEER="${BENCH_SAMPLER_PEER:-1}"
VB=bin/vbrender
WORK=bench/work/sampler
RESULTS=bench/results

if [ ! -x "$VB" ]; then
    echo "run-sampler.sh: $VB is missing (run 'make')" >&2
    exit 1
fi
mkdir -p "$WORK" "$RESULTS"

# The scene at SIZE x SIZE, mesh paths made absolute; rewritten only when it
# changes, so a cached reference stays valid.
sized_scene() {
    python3 - "$1" "$SIZE" "$WORK" <<'EOF'
import json, os, sys
name, size, work = sys.argv[1], int(sys.argv[2]), sys.argv[3]
src = os.path.join("scenes", name + ".json")
d = json.load(open(src))
d["camera"]["width"] = d["camera"]["height"] = size
for sh in d["shapes"]:
    if "file" in sh and not os.path.isabs(sh["file"]):
        sh["file"] = os.path.abspath(os.path.join("scenes", sh["file"]))
dst = os.path.join(work, "%s-%d.json" % (name, size))
text = json.dumps(d, indent=1)
if not os.path.exists(dst) or open(dst).read() != text:
    open(dst, "w").write(text)
print(dst)
EOF
}

PEER_PY=""
if [ "$PEER" = 1 ] && [ -f bench/peer/env.sh ]; then
    # shellcheck disable=SC1091
    source bench/peer/env.sh
    PEER_PY="${MITSUBA_PEER_PYTHON:-}"
fi
SAMPLERS="independent sobol"
[ -n "$PEER_PY" ] && SAMPLERS="$SAMPLERS mitsuba-multijitter"

render() { # scene out spp sampler seed
    if [ "$4" = mitsuba-multijitter ]; then
        "$PEER_PY" bench/peer/mitsuba_peer.py "$1" --mode render --spp "$3" --threads "$THREADS" \
            --seed "$5" --sampler multijitter --out "$2" >/dev/null 2>>"$WORK/render.log"
        return
    fi
    "$VB" render "$1" -o "$2" --spp "$3" --granularity 32 --adaptive none --sampler "$4" \
        --seed "$5" --threads "$THREADS" --progress none >/dev/null 2>>"$WORK/render.log"
}

relmse() { # image reference
    "$VB" compare "$1" "$2" | awk '$1 == "relMSE" { print $2 }'
}

rows="$WORK/rows.txt"
: >"$rows"
for case in $CASES; do
    scene_name="${case%%:*}"
    spps="${case#*:}"
    scene=$(sized_scene "$scene_name")
    ref="$WORK/$scene_name-$SIZE-ref$REF_SPP.exr"
    if [ ! -f "$ref" ] || [ "$scene" -nt "$ref" ]; then
        echo "== $scene_name: reference, $REF_SPP spp independent" >&2
        start=$(date +%s.%N)
        render "$scene" "$ref" "$REF_SPP" independent 1000001
        echo "   $(echo "$(date +%s.%N) - $start" | bc) s" >&2
    fi
    for spp in ${spps//,/ }; do
        for sampler in $SAMPLERS; do
            for seed in $(seq 1 "$SEEDS"); do
                out="$WORK/$scene_name-$SIZE-$sampler-$spp-s$seed.exr"
                start=$(date +%s.%N)
                render "$scene" "$out" "$spp" "$sampler" "$seed"
                secs=$(echo "$(date +%s.%N) - $start" | bc)
                r=$(relmse "$out" "$ref")
                echo "$scene_name $spp $sampler $seed $r $secs" >>"$rows"
                echo "   $scene_name $spp spp $sampler seed $seed: relMSE $r (${secs} s)" >&2
            done
        done
    done
done

python3 - "$rows" "$REF_SPP" "$SIZE" "$SEEDS" "$RESULTS/sampler.json" <<'EOF'
import json, sys, subprocess
rows_path, ref_spp, size, seeds, out = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
runs = {}
for line in open(rows_path):
    scene, spp, sampler, seed, r, secs = line.split()
    runs.setdefault((scene, int(spp), sampler), []).append((float(r), float(secs)))
scenes = []
for (scene, _, _) in runs:
    if scene not in scenes:
        scenes.append(scene)
table, res = [], {"size": size, "reference_spp": ref_spp, "seeds": seeds, "granularity": 32,
                  "adaptive": "none", "scenes": {}}
try:
    res["commit"] = subprocess.check_output(["git", "rev-parse", "HEAD"], text=True).strip()
except Exception:
    pass
for scene in scenes:
    spps = sorted({k[1] for k in runs if k[0] == scene})
    n0 = spps[0]
    m0 = sum(r for r, _ in runs[(scene, n0, "independent")]) / seeds
    own = m0 * n0 / (ref_spp + n0)  # the reference's own relMSE
    entry = {"reference_own_relmse_est": own, "spp": {}}
    for spp in spps:
        e = {}
        for sampler in ("independent", "sobol", "mitsuba-multijitter"):
            rs = runs.get((scene, spp, sampler))
            if not rs:
                continue
            raw = sum(r for r, _ in rs) / len(rs)
            e[sampler] = {"relmse_raw": raw, "relmse": max(raw - own, 1e-12),
                          "per_seed_raw": [r for r, _ in rs],
                          "seconds": sum(s for _, s in rs) / len(rs)}
        e["ratio_independent_over_sobol"] = e["independent"]["relmse"] / e["sobol"]["relmse"]
        e["ratio_raw"] = e["independent"]["relmse_raw"] / e["sobol"]["relmse_raw"]
        peer = e.get("mitsuba-multijitter")
        if peer:
            e["ratio_mitsuba_over_sobol"] = peer["relmse"] / e["sobol"]["relmse"]
        entry["spp"][str(spp)] = e
        table.append((scene, spp, e["independent"]["relmse"], e["sobol"]["relmse"],
                      e["ratio_independent_over_sobol"], e["ratio_raw"],
                      "%.4g" % peer["relmse"] if peer else "-",
                      "%.2fx" % e["ratio_mitsuba_over_sobol"] if peer else "-",
                      e["independent"]["seconds"], e["sobol"]["seconds"], own))
    res["scenes"][scene] = entry
json.dump(res, open(out, "w"), indent=1)
print("| scene | spp | relMSE independent | relMSE sobol | indep/sobol | (raw) "
      "| relMSE Mitsuba multijitter | Mitsuba/sobol | s indep | s sobol | ref own relMSE |")
print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
for t in table:
    print("| %s | %d | %.4g | %.4g | %.2fx | %.2fx | %s | %s | %.1f | %.1f | %.2g |" % t)
EOF
echo "run-sampler.sh: wrote $RESULTS/sampler.json" >&2
