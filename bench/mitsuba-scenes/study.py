#!/usr/bin/env python3
"""The study of Mitsuba 3's own documentation scenes (issue 22): each file
of mitsuba-data/docs/scenes through `vbrender render`, then, for those we
render, our image against Mitsuba's of the same file.

    bench/mitsuba-scenes/run.sh          (sets up the peer; MITSUBA_DATA)

For every scene: refused (and the message, which names file, line and
plugin) or rendered; for the rendered ones, at a reduced resolution
(WIDTHxHEIGHT, the films edited in a scratch copy of the scenes):
  - a reference: Mitsuba at REF_SPP (16x SPP), seed 11;
  - Mitsuba at SPP (independent sampler, as the scene files say), seed 12;
  - ours at SPP (independent sampler, uniform), seed 1;
  - bias: the image mean of each against the reference's;
  - relMSE of each against the reference, and ours over Mitsuba's;
  - speed: samples/s of each (Mitsuba's second, warm run), 2 threads;
then bench/results/mitsuba-scenes.json, a contact sheet
(bench/results/mitsuba-scenes.png: Mitsuba left, ours right) and the
table in bench/RESULTS.md between its mitsuba-scenes markers.
"""
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np
import mitsuba as mi

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), '..', '..'))
DATA = os.environ.get('MITSUBA_DATA')
SPP = int(os.environ.get('STUDY_SPP', '64'))
REF_SPP = int(os.environ.get('STUDY_REF_SPP', str(16 * SPP)))
W = int(os.environ.get('STUDY_WIDTH', '96'))
H = int(os.environ.get('STUDY_HEIGHT', '72'))
VB = os.path.join(ROOT, 'bin', 'vbrender')


def luminance(a):
    return 0.2126 * a[..., 0] + 0.7152 * a[..., 1] + 0.0722 * a[..., 2]


def relmse(a, ref):
    return float(np.mean((a - ref) ** 2 / (ref ** 2 + 1e-2)))


def load(path):
    return np.array(mi.Bitmap(path))[..., :3].astype(np.float64)


def mitsuba_render(scene_file, spp, seed, out):
    """Renders with the file's own sampler; returns (seconds, the sampler's name)."""
    try:
        sc = mi.load_file(scene_file, spp=spp)
    except RuntimeError as e:  # Mitsuba refuses a parameter the file does not use
        if 'unused parameters' not in str(e):
            raise
        sc = mi.load_file(scene_file)
    s = sc.sensors()[0].sampler()
    sampler = s.class_name() if callable(s.class_name) else str(s.class_name)
    mi.render(sc, spp=min(spp, 4), seed=seed)  # warm: the JIT compiles once
    start = time.time()
    img = mi.render(sc, spp=spp, seed=seed)
    np.array(img)  # the render is done when its result is read
    seconds = time.time() - start
    mi.Bitmap(img).convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32,
                           srgb_gamma=False).write(out)
    return seconds, sampler


def main():
    if not DATA or not os.path.isdir(os.path.join(DATA, 'docs', 'scenes')):
        sys.exit('study.py: set MITSUBA_DATA to a checkout of mitsuba-renderer/mitsuba-data')
    mi.set_variant(os.environ.get('MITSUBA_PEER_VARIANT', 'llvm_ad_rgb'))
    scratch = tempfile.mkdtemp(prefix='vb-mitsuba-study.')
    shutil.copytree(os.path.join(DATA, 'docs'), os.path.join(scratch, 'docs'))
    shutil.copytree(os.path.join(DATA, 'common'), os.path.join(scratch, 'common'))
    scenes_dir = os.path.join(scratch, 'docs', 'scenes')
    for dirpath, _, files in os.walk(scenes_dir):
        for f in files:
            if f.endswith('.xml'):
                p = os.path.join(dirpath, f)
                s = open(p).read()
                s = re.sub(r'name="width" value="\d+"', 'name="width" value="%d"' % W, s)
                s = re.sub(r'name="height" value="\d+"', 'name="height" value="%d"' % H, s)
                open(p, 'w').write(s)
    rows, sheet = [], []
    for f in sorted(os.listdir(scenes_dir)):
        if not f.endswith('.xml'):
            continue
        x = os.path.join(scenes_dir, f)
        name = f[:-4]
        ours = os.path.join(scratch, name + '-ours.exr')
        r = subprocess.run([VB, 'render', x, '-D', 'spp=%d' % SPP, '--spp', str(SPP), '--adaptive', 'none',
                            '--sampler', 'independent', '--threads', '2', '-o', ours,
                            '--progress', 'none'], capture_output=True, text=True)
        if r.returncode != 0:
            msg = (r.stderr.strip().splitlines() or ['?'])[-1].replace(scratch + '/', '')
            rows.append({'scene': f, 'rendered': False, 'refusal': msg})
            print('%-40s refused: %s' % (f, msg[:110]), flush=True)
            continue
        m = re.search(r'([\d.]+)([kM]?) samples/s', r.stdout + r.stderr)
        ours_sps = float(m.group(1)) * {'': 1, 'k': 1e3, 'M': 1e6}[m.group(2)] if m else None
        ref = os.path.join(scratch, name + '-ref.exr')
        theirs = os.path.join(scratch, name + '-mitsuba.exr')
        try:
            mitsuba_render(x, REF_SPP, 11, ref)
            t, sampler = mitsuba_render(x, SPP, 12, theirs)
        except Exception as e:  # a scene Mitsuba itself cannot render as given
            rows.append({'scene': f, 'rendered': True, 'mitsuba_error': str(e)[:200]})
            print('%-40s Mitsuba failed: %s' % (f, str(e)[:100]), flush=True)
            continue
        # ours again with our default sampler (Owen-scrambled Sobol)
        ours_sobol = os.path.join(scratch, name + '-ours-sobol.exr')
        subprocess.run([VB, 'render', x, '-D', 'spp=%d' % SPP, '--spp', str(SPP), '--adaptive',
                        'none', '--threads', '2', '-o', ours_sobol, '--progress', 'none'],
                       capture_output=True, check=True)
        R, O, M = load(ref), load(ours), load(theirs)
        OS = load(ours_sobol)
        row = {'scene': f, 'rendered': True,
               'bias_ours': float(luminance(O).mean() / luminance(R).mean() - 1),
               'bias_mitsuba': float(luminance(M).mean() / luminance(R).mean() - 1),
               'relmse_ours': relmse(O, R), 'relmse_mitsuba': relmse(M, R),
               'relmse_ours_sobol': relmse(OS, R), 'mitsuba_sampler': sampler,
               'samples_per_s_ours': ours_sps,
               'samples_per_s_mitsuba': W * H * SPP / t if t > 0 else None}
        row['relmse_ratio'] = row['relmse_ours'] / row['relmse_mitsuba']
        row['relmse_ratio_sobol'] = row['relmse_ours_sobol'] / row['relmse_mitsuba']
        rows.append(row)
        sheet.append((f, M, O))
        print('%-40s bias %+.2f %% (Mitsuba %+.2f %%)  relMSE ours/Mitsuba %.2f  samples/s %.2gM / %.2gM'
              % (f, 100 * row['bias_ours'], 100 * row['bias_mitsuba'], row['relmse_ratio'],
                 (ours_sps or 0) / 1e6, (row['samples_per_s_mitsuba'] or 0) / 1e6), flush=True)
    shutil.rmtree(scratch, ignore_errors=True)
    out = {'width': W, 'height': H, 'spp': SPP, 'ref_spp': REF_SPP, 'threads': 2,
           'mitsuba': mi.__version__, 'data': os.path.basename(os.path.abspath(DATA)),
           'scenes': rows}
    res = os.path.join(ROOT, 'bench', 'results')
    os.makedirs(res, exist_ok=True)
    json.dump(out, open(os.path.join(res, 'mitsuba-scenes.json'), 'w'), indent=1)
    if sheet:
        tiles = [np.concatenate([m, o], axis=1) for _, m, o in sheet]
        cols = 3
        while len(tiles) % cols:
            tiles.append(np.zeros_like(tiles[0]))
        grid = np.concatenate([np.concatenate(tiles[i:i + cols], axis=1)
                               for i in range(0, len(tiles), cols)], axis=0)
        mi.Bitmap(grid.astype(np.float32)).convert(mi.Bitmap.PixelFormat.RGB,
                                                   mi.Struct.Type.UInt8, srgb_gamma=True) \
            .write(os.path.join(res, 'mitsuba-scenes.png'))
    rendered = [r for r in rows if r.get('rendered') and 'relmse_ratio' in r]
    if not rendered:
        sys.exit('study.py: nothing rendered and compared; bench/RESULTS.md left as it was')
    lines = ['<!-- mitsuba-scenes:begin (bench/mitsuba-scenes/run.sh) -->',
             '',
             'Mitsuba 3 (%s) documentation scenes (`mitsuba-data/docs/scenes`, %d files) through '
             '`vbrender render`: %d rendered, %d refused with file, line and plugin. Rendered at %dx%d, '
             '%d spp each, ours uniform with the independent sampler and with our default (Sobol), '
             'Mitsuba with the sampler the file names; references: Mitsuba at %d spp; 2 threads. '
             'Under the gaussian filter Mitsuba splats, we sample (docs/SCENES.md): about 3x the relMSE '
             'from that alone. Samples/s include `vbrender render`\'s start at this size: not a speed '
             'comparison (that is `make bench`). '
             'Contact sheet: `bench/results/mitsuba-scenes.png` (Mitsuba left, ours right).'
             % (mi.__version__, len(rows), len(rendered), len(rows) - len(rendered), W, H, SPP,
                REF_SPP),
             '',
             '| scene | Mitsuba sampler | bias ours | bias Mitsuba | relMSE ours / Mitsuba: independent | Sobol | samples/s ours | samples/s Mitsuba |',
             '|---|---|--:|--:|--:|--:|--:|--:|']
    for r in rendered:
        lines.append('| %s | %s | %+.2f %% | %+.2f %% | %.2f | %.2f | %.2fM | %.2fM |' % (
            r['scene'], r['mitsuba_sampler'], 100 * r['bias_ours'], 100 * r['bias_mitsuba'],
            r['relmse_ratio'], r['relmse_ratio_sobol'],
            (r['samples_per_s_ours'] or 0) / 1e6, (r['samples_per_s_mitsuba'] or 0) / 1e6))
    lines += ['', '<!-- mitsuba-scenes:end -->']
    block = '\n'.join(lines)
    path = os.path.join(ROOT, 'bench', 'RESULTS.md')
    text = open(path).read()
    if '<!-- mitsuba-scenes:begin' in text:
        text = re.sub(r'<!-- mitsuba-scenes:begin.*?<!-- mitsuba-scenes:end -->', block, text,
                      flags=re.S)
    else:
        text = text.rstrip('\n') + '\n\n## Mitsuba 3 scene files\n\n' + block + '\n'
    open(path, 'w').write(text)
    print(block)


if __name__ == '__main__':
    main()
