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
# how our error per sample compares with Mitsuba's. And Mitsuba's orthogonal
# sampler (orthogonal arrays of strength 2, Jarosz et al. 2019: every 2D
# projection stratified), which takes only squares of primes and silently
# rounds any other count up (1024 spp becomes 1369): it renders at the two
# squares of primes around each spp (961 and 1369 for 1024, 169 and 289 for
# 256, 49 and 121 for 64), and its relMSE at the spp itself is interpolated
# on log-log axes between them, so that every column is at equal spp.
# BENCH_SAMPLER_PEER=0 leaves the peer out.
#
# Knobs (environment): BENCH_SAMPLER_SIZE (64), BENCH_SAMPLER_REF_SPP
# (32768), BENCH_SAMPLER_SEEDS (6), BENCH_SAMPLER_THREADS (2),
# BENCH_SAMPLER_CASES (scene:spp,spp,... list, see below),
# BENCH_SAMPLER_PEER (1), BENCH_SAMPLER_VB (bin/vbrender: another build to
# measure). "s" columns are wall seconds per render on a
# shared host: indicative only.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"

SIZE="${BENCH_SAMPLER_SIZE:-64}"
REF_SPP="${BENCH_SAMPLER_REF_SPP:-32768}"
SEEDS="${BENCH_SAMPLER_SEEDS:-6}"
THREADS="${BENCH_SAMPLER_THREADS:-2}"
CASES="${BENCH_SAMPLER_CASES:-cornell-box:64,256,1024 cornell-glass:256,1024 caustic:64,256,1024 dark-bright:64,256}"
PEER="${BENCH_SAMPLER_PEER:-1}"
VB="${BENCH_SAMPLER_VB:-bin/vbrender}"
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
# sobol: our default, two replicates (--replicates 2); sobol-r1: one sequence
# a pixel (--replicates 1), so the table tells the sampler from what the
# calibrated error's replicates cost
SAMPLERS="independent sobol sobol-r1"
[ -n "$PEER_PY" ] && SAMPLERS="$SAMPLERS mitsuba-multijitter mitsuba-orthogonal"

render() { # scene out spp sampler seed
    case "$4" in
    mitsuba-*)
        "$PEER_PY" bench/peer/mitsuba_peer.py "$1" --mode render --spp "$3" --threads "$THREADS" \
            --seed "$5" --sampler "${4#mitsuba-}" --out "$2" >/dev/null 2>>"$WORK/render.log"
        return
        ;;
    sobol-r1)
        set -- "$1" "$2" "$3" sobol "$5" --replicates 1
        ;;
    esac
    "$VB" render "$1" -o "$2" --spp "$3" --granularity 32 --adaptive none --sampler "$4" \
        --seed "$5" --threads "$THREADS" --progress none "${@:6}" >/dev/null 2>>"$WORK/render.log"
}

# The squares of primes at and around N: "N" when N is one, else the one
# below and the one above.
prime_squares_around() {
    python3 - "$1" <<'EOF'
import sys
n = int(sys.argv[1])
def prime(p):
    return p >= 2 and all(p % d for d in range(2, int(p ** 0.5) + 1))
sq = [p * p for p in range(2, 200) if prime(p)]
if n in sq:
    print(n)
else:
    print(max(q for q in sq if q < n), min(q for q in sq if q > n))
EOF
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
            counts=$spp
            [ "$sampler" = mitsuba-orthogonal ] && counts=$(prime_squares_around "$spp")
            for count in $counts; do
                for seed in $(seq 1 "$SEEDS"); do
                    out="$WORK/$scene_name-$SIZE-$sampler-$count-s$seed.exr"
                    start=$(date +%s.%N)
                    render "$scene" "$out" "$count" "$sampler" "$seed"
                    secs=$(echo "$(date +%s.%N) - $start" | bc)
                    r=$(relmse "$out" "$ref")
                    # spp: the count the row stands for; count: the one rendered
                    echo "$scene_name $spp $sampler $seed $r $secs $count" >>"$rows"
                    echo "   $scene_name $count spp $sampler seed $seed: relMSE $r (${secs} s)" >&2
                done
            done
        done
    done
done

python3 - "$rows" "$REF_SPP" "$SIZE" "$SEEDS" "$RESULTS/sampler.json" <<'EOF'
import json, math, sys, subprocess
rows_path, ref_spp, size, seeds, out = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
runs = {}  # (scene, spp, sampler) -> {count rendered: [(relmse, seconds)]}
for line in open(rows_path):
    scene, spp, sampler, seed, r, secs, count = line.split()
    runs.setdefault((scene, int(spp), sampler), {}).setdefault(int(count), []).append(
        (float(r), float(secs)))
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


def mean(xs):
    return sum(xs) / len(xs)


for scene in scenes:
    spps = sorted({k[1] for k in runs if k[0] == scene})
    n0 = spps[0]
    m0 = mean([r for r, _ in runs[(scene, n0, "independent")][n0]])
    own = m0 * n0 / (ref_spp + n0)  # the reference's own relMSE
    entry = {"reference_own_relmse_est": own, "spp": {}}
    for spp in spps:
        e = {}
        for sampler in ("independent", "sobol", "sobol-r1", "mitsuba-multijitter",
                        "mitsuba-orthogonal"):
            by_count = runs.get((scene, spp, sampler))
            if not by_count:
                continue
            at = {}
            for count, rs in sorted(by_count.items()):
                raw = mean([r for r, _ in rs])
                at[count] = {"relmse_raw": raw, "relmse": max(raw - own, 1e-12),
                             "per_seed_raw": [r for r, _ in rs],
                             "seconds": mean([t for _, t in rs])}
            if spp in at:
                e[sampler] = at[spp]
            else:  # squares of primes around spp: log-log interpolation
                (lo, a), (hi, b) = sorted(at.items())
                f = math.log(spp / lo) / math.log(hi / lo)
                slope = math.log(b["relmse"] / a["relmse"]) / math.log(hi / lo)
                e[sampler] = {"relmse": math.exp(math.log(a["relmse"]) * (1 - f) +
                                                 math.log(b["relmse"]) * f),
                              "interpolated_from": {str(c): v for c, v in at.items()},
                              "slope": slope,
                              "seconds": a["seconds"] * (1 - f) + b["seconds"] * f}
        e["ratio_independent_over_sobol"] = e["independent"]["relmse"] / e["sobol"]["relmse"]
        if "sobol-r1" in e:
            e["ratio_sobol_over_sobol_r1"] = e["sobol"]["relmse"] / e["sobol-r1"]["relmse"]
        for peer in ("mitsuba-multijitter", "mitsuba-orthogonal"):
            if peer in e:
                e["ratio_%s_over_sobol" % peer.split("-")[1]] = \
                    e[peer]["relmse"] / e["sobol"]["relmse"]
        entry["spp"][str(spp)] = e

        def peer_cols(name):
            if name not in e:
                return ["-", "-", "-"]
            r1 = e.get("sobol-r1")
            return ["%.4g" % e[name]["relmse"], "%.2fx" % (e[name]["relmse"] / e["sobol"]["relmse"]),
                    "%.2fx" % (e[name]["relmse"] / r1["relmse"]) if r1 else "-"]
        ortho = e.get("mitsuba-orthogonal", {})
        counts = "/".join(ortho.get("interpolated_from", {}).keys()) or (str(spp) if ortho else "-")
        table.append([scene, str(spp), "%.4g" % e["independent"]["relmse"],
                      "%.4g" % e["sobol"]["relmse"], "%.2fx" % e["ratio_independent_over_sobol"],
                      "%.4g" % e["sobol-r1"]["relmse"] if "sobol-r1" in e else "-"] +
                     peer_cols("mitsuba-multijitter") + peer_cols("mitsuba-orthogonal") +
                     [counts, "%.1f" % e["independent"]["seconds"],
                      "%.1f" % e["sobol"]["seconds"], "%.2g" % own])
    res["scenes"][scene] = entry
json.dump(res, open(out, "w"), indent=1)
print("| scene | spp | relMSE independent | relMSE sobol (2 replicates) | indep/sobol "
      "| sobol, 1 replicate | Mitsuba multijitter | multijitter/sobol | multijitter/sobol 1 rep. "
      "| Mitsuba orthogonal | orthogonal/sobol | orthogonal/sobol 1 rep. "
      "| orthogonal rendered at | s indep | s sobol | ref own relMSE |")
print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|")
for t in table:
    print("| " + " | ".join(t) + " |")
EOF
echo "run-sampler.sh: wrote $RESULTS/sampler.json" >&2
