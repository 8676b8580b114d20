#!/usr/bin/env bash
# run.sh - the study of Mitsuba 3's documentation scenes (study.py): our
# importer and renderer against Mitsuba on the same files.
#
#   MITSUBA_DATA=/path/to/mitsuba-data bash bench/mitsuba-scenes/run.sh
#
# MITSUBA_DATA: a checkout of github.com/mitsuba-renderer/mitsuba-data
# (its docs/scenes and common/; default ../shared/mitsuba-data). Knobs:
# STUDY_SPP (64), STUDY_REF_SPP (16x), STUDY_WIDTH (96), STUDY_HEIGHT (72).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
cd "$ROOT"
export MITSUBA_DATA="${MITSUBA_DATA:-$ROOT/../shared/mitsuba-data}"
if [ ! -d "$MITSUBA_DATA/docs/scenes" ]; then
    # (make bench-error runs it: without the data the rest still runs)
    echo "run.sh: skipped: no mitsuba-data at $MITSUBA_DATA (set MITSUBA_DATA to a checkout" \
        "of github.com/mitsuba-renderer/mitsuba-data)" >&2
    exit 0
fi
[ -x bin/vbrender ] || make all
bash bench/peer/setup.sh >/dev/null
# shellcheck disable=SC1091
source bench/peer/env.sh
"$MITSUBA_PEER_PYTHON" bench/mitsuba-scenes/study.py
