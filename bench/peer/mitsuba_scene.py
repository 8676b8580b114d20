#!/usr/bin/env python3
"""Renders a Mitsuba 3 scene file with Mitsuba itself (the peer), for the
references tests compare our image of the same file against.

    source bench/peer/env.sh
    "$MITSUBA_PEER_PYTHON" bench/peer/mitsuba_scene.py SCENE.xml SPP OUT.exr [-D name=value ...]

tests/data/mitsuba/cornell-box-32.exr was made with
    ... mitsuba_scene.py scenes/mitsuba/cornell-box.xml 65536 \\
        tests/data/mitsuba/cornell-box-32.exr -D res=32
(Mitsuba 3.9.1, llvm_ad_rgb, seed 11; 16 s on 2 cores.)"""
import os
import sys
import time

import mitsuba as mi


def main():
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    scene, spp, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    params = {}
    args = sys.argv[4:]
    while args:
        if args[0] != "-D" or len(args) < 2 or "=" not in args[1]:
            sys.exit("expected -D name=value, got %s" % " ".join(args))
        name, value = args[1].split("=", 1)
        params[name] = value
        args = args[2:]
    mi.set_variant(os.environ.get("MITSUBA_PEER_VARIANT", "llvm_ad_rgb"))
    sc = mi.load_file(scene, spp=spp, **params)
    start = time.time()
    img = mi.render(sc, spp=spp, seed=11)
    bmp = mi.Bitmap(img).convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32,
                                 srgb_gamma=False)
    bmp.write(out)
    print("%s: %d spp in %.1f s" % (out, spp, time.time() - start))


if __name__ == "__main__":
    main()
