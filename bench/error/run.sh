#!/usr/bin/env bash
# make bench-error: error against wall time and samples for uniform and the
# adaptive modes, the thesis's section 5.3.2 with error measured, the
# --target-error check and the Mitsuba 3 peer (see bench/error/README.md).
#
# Needs bin/vbrender (make all). Settings come from the environment
# (VB_STUDY_QUICK=1 for a ~3-minute smoke run; the rest in bench/error/study.py).
# `run.sh --repeat` runs bench/error/repeat.py instead: uniform, relmse and
# relerr again at three more seeds (about 21 minutes); `--calibrate` and
# `--coverage` the calibration and target-error studies of issue 24;
# `--peer-best` equal time against Mitsuba 3 at its best sampler on each
# scene (bench/error/peer_best.py).
# Writes bench/results/error.json, bench/results/error/*.png and the bench/RESULTS.md
# section between <!-- bench:error:begin --> and <!-- bench:error:end -->.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
cd "$ROOT"

if [ ! -x bin/vbrender ] || [ ! -x build/bench/bench_batches ]; then
    echo "bench/error/run.sh: bin/vbrender or build/bench/bench_batches is missing;" \
        "run 'make all build/bench/bench_batches' first (make bench-error does)" >&2
    exit 1
fi

bash bench/peer/setup.sh
# shellcheck disable=SC1091
source bench/peer/env.sh
if ! "$MITSUBA_PEER_PYTHON" -c 'import matplotlib' 2>/dev/null; then
    "$ROOT/bench/venv/bin/pip" install -q --disable-pip-version-check matplotlib
fi

# --repeat: bench/error/repeat.py (adaptive against uniform over several seeds)
if [ "${1:-}" = "--repeat" ]; then
    shift
    exec "$MITSUBA_PEER_PYTHON" bench/error/repeat.py "$@"
fi
# --calibrate: bench/error/calibrate.py (does the variance channel predict the
# error? about 15 minutes); --coverage: bench/error/coverage.py (does the
# target error hold on every pixel? about an hour)
if [ "${1:-}" = "--calibrate" ]; then
    shift
    exec "$MITSUBA_PEER_PYTHON" bench/error/calibrate.py "$@"
fi
if [ "${1:-}" = "--peer-best" ]; then
    shift
    exec "$MITSUBA_PEER_PYTHON" bench/error/peer_best.py "$@"
fi
if [ "${1:-}" = "--coverage" ]; then
    shift
    exec "$MITSUBA_PEER_PYTHON" bench/error/coverage.py "$@"
fi
exec "$MITSUBA_PEER_PYTHON" bench/error/study.py "$@"
