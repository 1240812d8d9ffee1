#!/usr/bin/env python3
"""What our extraction makes possible on ../shared/data: completeness if every extracted segment
were matched and reconstructed perfectly.

    /tmp/ev/bin/python tools/oracle_extracted.py [--shared ../shared] [--bin target/release/trinocular]

For each capture, runs `trinocular match` on the images with returnExtracted, then counts a
point of an eligible ground-truth edge (visible in all three cameras, >= 20 px in each) as
reachable when, in each of the three images, an extracted segment runs along its projection
(within 1.5 px and 5 degrees). Prints the reachable share of the eligible length, comparable
with the scorer's completeness.
"""
import argparse, base64, json, os, subprocess, tempfile
import numpy as np

ap = argparse.ArgumentParser()
ap.add_argument("--shared", default=os.path.join(os.path.dirname(__file__), "..", "..", "shared"))
ap.add_argument("--bin", default="target/release/trinocular")
args = ap.parse_args()
data = os.path.join(args.shared, "data", "office")
req_path = os.path.join(tempfile.mkdtemp(), "request.json")
E = np.asarray(json.load(open(os.path.join(data, 'gt_edges.json')))['edges'], float)
tot = cov = 0.0
for cap in sorted(d[len('capture_'):] for d in os.listdir(data) if d.startswith('capture_')):
    cdir = f'{data}/capture_{cap}'
    vis = json.load(open(cdir + '/visibility.json'))
    calw = json.load(open(cdir + '/calib_world.json'))
    calib = json.load(open(cdir + '/calib.json'))
    cams = [{"width": c["width"], "height": c["height"], "projection": [v for r in c["P"] for v in r]} for c in calib["cameras"]]
    req = {"calibration": {"cameras": cams}, "options": {"returnExtracted": True},
           "images": {"images": [{"encoded": base64.b64encode(open(f'{cdir}/img{i}.png', 'rb').read()).decode()} for i in (1, 2, 3)]}}
    open(req_path, 'w').write(json.dumps(req))
    out = json.loads(subprocess.run([args.bin, "match", req_path], capture_output=True, text=True, check=True).stdout)
    lists = [[(s['u1'], s['v1'], s['u2'], s['v2']) for s in l.get('segments', [])] for l in out['extracted']]
    P = [np.asarray(c['P']) for c in calw['cameras']]
    for r in vis['edges']:
        if not r['all3'] or min(r['all3_px']) < 20: continue
        A, B = E[r['i'], :3], E[r['i'], 3:]
        L = np.linalg.norm(B - A)
        ts = np.linspace(0, 1, 400)
        inside = np.zeros_like(ts, bool)
        for a, b in r['all3']: inside |= (ts >= a) & (ts <= b)
        ok = inside.copy()
        for v in range(3):
            X = A[None] + (B - A)[None] * ts[:, None]
            h = (P[v] @ np.hstack([X, np.ones((len(ts), 1))]).T).T
            uv = h[:, :2] / h[:, 2:3]
            d = uv[-1] - uv[0]; d = d / (np.linalg.norm(d) + 1e-12)
            covered = np.zeros_like(ts, bool)
            for (u1, v1, u2, v2) in lists[v]:
                s = np.array([u2 - u1, v2 - v1]); sl = np.linalg.norm(s)
                if sl < 1e-9 or abs(np.dot(s / sl, d)) < np.cos(np.radians(5)): continue
                w = uv - np.array([u1, v1])
                along = w @ (s / sl); perp = np.abs(w[:, 0] * s[1] / sl - w[:, 1] * s[0] / sl)
                covered |= (along >= 0) & (along <= sl) & (perp <= 1.5)
            ok &= covered
        tot += inside.sum() / len(ts) * L
        cov += ok.sum() / len(ts) * L
print('oracle completeness from extracted segments: %.3f' % (cov / tot))
