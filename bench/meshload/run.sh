#!/bin/sh
# run.sh - mesh reader benchmark: our common/mesh.c against Assimp on a
# generated 1M-triangle mesh (binary PLY, ascii PLY, OBJ), then both readers
# on a few broken files. Scratch files go to bench/work/meshload (ignored by
# git; override with WORK=...). Installs libassimp-dev if it is missing.
set -eu
cd "$(dirname "$0")/../.."
WORK=${WORK:-bench/work/meshload}
SUDO=$([ "$(id -u)" = 0 ] || echo sudo)

if ! dpkg-query -W -f='${Status}\n' libassimp-dev 2>/dev/null | grep -q '^install ok installed'; then
    echo "run.sh: installing libassimp-dev"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends libassimp-dev
fi

mkdir -p "$WORK"
CFLAGS="-std=c11 -O2 -Wall -Wextra -Werror -ffp-contract=off -fno-math-errno -D_DEFAULT_SOURCE -Icommon"
# The reader as the renderer links it; if another part of the core library
# does not build right now, compile the reader alone.
if make build/libvbcore.a >"$WORK/make.log" 2>&1; then
    CORE=build/libvbcore.a
else
    echo "run.sh: make build/libvbcore.a failed (see $WORK/make.log); using the mesh reader alone"
    for f in mesh ply obj numparse; do cc $CFLAGS -c common/$f.c -o "$WORK/$f.o"; done
    rm -f "$WORK/mesh.a" && ar rcs "$WORK/mesh.a" "$WORK"/mesh.o "$WORK"/ply.o "$WORK"/obj.o "$WORK"/numparse.o
    CORE="$WORK/mesh.a"
fi
cc $CFLAGS bench/meshload/gen_mesh.c -lm -o "$WORK/gen_mesh"
cc $CFLAGS bench/meshload/compare.c "$CORE" -lassimp -lm -o "$WORK/compare"

[ -f "$WORK/torus_1m.obj" ] || "$WORK/gen_mesh" "$WORK"

echo "== load time, best of 3 (Assimp with aiProcess_Triangulate only)"
"$WORK/compare" "$WORK/torus_1m_le.ply" "$WORK/torus_1m_ascii.ply" "$WORK/torus_1m.obj"

echo "== broken files"
B="$WORK/broken"
mkdir -p "$B"
size=$(stat -c %s "$WORK/torus_1m_le.ply")
head -c $((size / 2)) "$WORK/torus_1m_le.ply" >"$B/truncated_half_le.ply"
head -c $((size - 7)) "$WORK/torus_1m_le.ply" >"$B/truncated_end_le.ply"
hdr='ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n'
printf "${hdr}0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n" >"$B/index_range.ply"
printf "${hdr}0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n" >"$B/nan_coord.ply"
printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n' >"$B/index_range.obj"
printf 'v 0 0 0\nv 1 nan 0\nv 0 1 0\nf 1 2 3\n' >"$B/nan_coord.obj"
printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -9\n' >"$B/index_negative.obj"
printf 'ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0123456789' >"$B/huge_count.ply"
"$WORK/compare" --broken "$B"/*
