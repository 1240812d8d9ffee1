#!/usr/bin/env python3
"""How well the reported 2D line noise describes the true error of extracted (or listed)
segments, on the rendered rooms: the check behind the extractor's noise model.

    python tools/line_noise_study.py --shared PATH [--rooms office,lab] [--input images|lsd]
        [--bin target/release/trinocular] [--options '{"lineNoisePx": 0.3}']

Run with a Python that has numpy. For each capture and camera, every segment that lies along
the projection of a visible ground-truth edge (both ends within 1.5 px of it, direction within
4 degrees) is compared with that projection: its offset error at the segment's midpoint and
its direction error, each divided by the segment's reported 1σ (image input: the extractor's
`offsetSigmaPx` / `angleSigmaDeg`; LSD lists: the matcher's list model, computed here the same
way). Prints, by segment length, the median squared normalised error (1 dof: 0.455 when
calibrated) and the share within 1.96σ and 2.58σ (95% and 99% when calibrated); then the same by the
distance of the nearest parallel neighbour segment and of the nearest other true edge; then,
by that neighbour's contrast (same or opposite orientation) and distance in 0.5-px bins, how
far the segment's midpoint lies off its true edge toward the neighbour (negative: pushed
away) and the robust spread about that median (1.4826 x MAD), the measurement behind the
list model's correction of an opposite-contrast neighbour's push (`segment::Repulsion`).
"""
import argparse
import json
import math
import os
import subprocess
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
from eval_rooms import request_for  # noqa: E402

BINS = [(0, 20), (20, 40), (40, 80), (80, 1e9)]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--shared", required=True)
    ap.add_argument("--rooms", default="office,lab")
    ap.add_argument("--input", default="images", choices=["images", "lsd"])
    ap.add_argument("--bin", default="target/release/trinocular")
    ap.add_argument("--options", default=None)
    a = ap.parse_args()
    options = json.loads(a.options) if a.options else {}
    line_noise = options.get("lineNoisePx", 0.3)
    options["returnExtracted"] = True
    work = tempfile.mkdtemp()
    rows = []  # (length, z_offset, z_angle)
    for room in a.rooms.split(","):
        data = os.path.join(a.shared, "data", room)
        E = np.asarray(json.load(open(os.path.join(data, "gt_edges.json")))["edges"], float)
        for cap in sorted(d[8:] for d in os.listdir(data) if d.startswith("capture_")):
            cdir = os.path.join(data, "capture_" + cap)
            req = request_for(cdir, options, a.input == "images")
            path = os.path.join(work, "req.json")
            json.dump(req, open(path, "w"))
            out = json.loads(subprocess.run([a.bin, "match", path], check=True, capture_output=True, text=True).stdout)
            if a.input == "images":
                lists = [l.get("segments", []) for l in out["extracted"]]
            else:
                lists = [l["segments"] for l in req["segments"]["lists"]]
            calib = json.load(open(os.path.join(cdir, "calib_world.json")))
            vis = json.load(open(os.path.join(cdir, "visibility.json")))
            for cam in range(3):
                P = np.asarray(calib["cameras"][cam]["P"], float)
                lines = []
                for r in vis["edges"]:
                    for lo, hi in r["vis"][cam]:
                        A, B = E[r["i"], :3], E[r["i"], 3:]
                        pa = P @ np.append(A + lo * (B - A), 1)
                        pb = P @ np.append(A + hi * (B - A), 1)
                        if pa[2] <= 0 or pb[2] <= 0:
                            continue
                        pa, pb = pa[:2] / pa[2], pb[:2] / pb[2]
                        if np.linalg.norm(pb - pa) >= 5:
                            lines.append((pa, pb, r["i"]))
                if not lines:
                    continue
                LA = np.array([l[0] for l in lines])
                LB = np.array([l[1] for l in lines])
                LD = LB - LA
                LL = np.linalg.norm(LD, axis=1)
                LU = LD / LL[:, None]
                LN = np.stack([-LU[:, 1], LU[:, 0]], 1)
                edge_ids = np.array([l[2] for l in lines])
                segs_np = np.array([[t.get("u1", 0.0), t.get("v1", 0.0), t.get("u2", 0.0), t.get("v2", 0.0)] for t in lists[cam]])
                for s in lists[cam]:
                    p = np.array([s.get("u1", 0.0), s.get("v1", 0.0)])
                    q = np.array([s.get("u2", 0.0), s.get("v2", 0.0)])
                    L = np.linalg.norm(q - p)
                    if L < 8:
                        continue
                    u = (q - p) / L
                    dp = np.abs(np.einsum("ij,ij->i", p - LA, LN))
                    dq = np.abs(np.einsum("ij,ij->i", q - LA, LN))
                    ang = np.degrees(np.arccos(np.clip(np.abs(LU @ u), 0, 1)))
                    # Within the edge's visible part, along it.
                    tp = np.einsum("ij,ij->i", p - LA, LU) / LL
                    tq = np.einsum("ij,ij->i", q - LA, LU) / LL
                    ok = (dp < 1.5) & (dq < 1.5) & (ang < 4) & (np.minimum(tp, tq) > -0.05) & (np.maximum(tp, tq) < 1.05)
                    if not ok.any():
                        continue
                    k = np.argmin(np.where(ok, dp + dq, np.inf))
                    m = 0.5 * (p + q)
                    # Signed along the segment's left normal (the bright side, v down).
                    left = np.array([u[1], -u[0]])
                    e_signed = (m - (LA[k] + ((m - LA[k]) @ LU[k]) * LU[k])) @ left
                    e_off = abs(e_signed)
                    e_ang = math.radians(ang[k])
                    if a.input == "images":
                        so, sa = s["offsetSigmaPx"], math.radians(s["angleSigmaDeg"])
                    else:
                        n = max(L / 2.0, 2.0)
                        so, sa = line_noise / math.sqrt(n), line_noise * math.sqrt(12 / n) / L
                    # Nearest other parallel segment alongside (its midpoint projects onto this one).
                    oth = segs_np
                    om = 0.5 * (oth[:, :2] + oth[:, 2:])
                    od = oth[:, 2:] - oth[:, :2]
                    ol = np.linalg.norm(od, axis=1) + 1e-9
                    par = np.abs((od / ol[:, None]) @ u) > np.cos(np.radians(10))
                    along = (om - p) @ u
                    across = np.abs((om - m) @ np.array([u[1], -u[0]]))
                    near = par & (along > 0) & (along < L) & (across > 0.3)
                    crowd = across[near].min() if near.any() else 99.0
                    # That neighbour's contrast (+1 same orientation, -1 opposite) and the error
                    # toward it (positive: pulled toward, negative: pushed away).
                    if near.any():
                        j = np.where(near)[0][np.argmin(across[near])]
                        same = float(np.sign((od[j] / ol[j]) @ u))
                        toward = e_signed * np.sign((om[j] - m) @ np.array([u[1], -u[0]]))
                    else:
                        same, toward = 0.0, 0.0
                    # Nearest other true edge alongside: parallel within 6 degrees, its projection
                    # passing the midpoint; two edges that close blur into one in the image.
                    dm = np.abs(np.einsum("ij,ij->i", m - LA, LN))
                    tm = np.einsum("ij,ij->i", m - LA, LU) / LL
                    other = (ang < 6) & (tm > -0.1) & (tm < 1.1) & (edge_ids != edge_ids[k])
                    other_px = dm[other].min() if other.any() else 99.0
                    rows.append((L, e_off / so, e_ang / sa, s.get("gradient", 0.0), e_signed, so, math.degrees(e_ang), abs(u[1]), (m - (LA[k] + ((m - LA[k]) @ LU[k]) * LU[k]))[0], cam, crowd, other_px, same, toward))
    R = np.array(rows)
    print(f"{len(R)} segments on a true edge ({a.input}, rooms {a.rooms})")
    for lo, hi in BINS + [(0, 1e9)]:
        sel = (R[:, 0] >= lo) & (R[:, 0] < hi)
        if not sel.any():
            continue
        zo, za = R[sel, 1], R[sel, 2]
        print(f"length {lo:>3}-{hi if hi < 1e8 else 'up':>3} px: n={sel.sum():5}  "
              f"offset: median z²={np.median(zo**2):.3f} in1.96={np.mean(zo < 1.96):.3f} in2.58={np.mean(zo < 2.58):.3f}  "
              f"angle: median z²={np.median(za**2):.3f} in1.96={np.mean(za < 1.96):.3f} in2.58={np.mean(za < 2.58):.3f}  "
              f"offset px: bias {np.median(R[sel, 4]):+.3f} MAD {np.median(np.abs(R[sel, 4] - np.median(R[sel, 4]))):.3f} "
              f"p90 {np.percentile(np.abs(R[sel, 4]), 90):.3f}, reported {np.median(R[sel, 5]):.3f}; angle p90 {np.percentile(R[sel, 6], 90):.3f} deg")


    for lo, hi in [(0, 2), (2, 3), (3, 4), (4, 5), (5, 6), (6, 8), (8, 15), (15, 100)]:
        sel = (R[:, 10] >= lo) & (R[:, 10] < hi) & (R[:, 0] > 40)
        if sel.any():
            zo = R[sel, 1]
            print(f"nearest parallel neighbour {lo}-{hi} px: n={sel.sum():5} |offset| median {np.median(np.abs(R[sel, 4])):.3f} "
                  f"p90 {np.percentile(np.abs(R[sel, 4]), 90):.3f} reported {np.median(R[sel, 5]):.3f} "
                  f"in1.96={np.mean(zo < 1.96):.3f} in2.58={np.mean(zo < 2.58):.3f} vertical share {np.mean(R[sel, 7] > 0.9):.2f}")
    for lo, hi in [(0, 1), (1, 2), (2, 3), (3, 5), (5, 10), (10, 100)]:
        sel = (R[:, 11] >= lo) & (R[:, 11] < hi)
        if sel.any():
            print(f"another true edge {lo}-{hi} px alongside: n={sel.sum():5} |offset| median "
                  f"{np.median(np.abs(R[sel, 4])):.3f} p90 {np.percentile(np.abs(R[sel, 4]), 90):.3f} "
                  f"offset in1.96={np.mean(R[sel, 1] < 1.96):.3f} angle in1.96={np.mean(R[sel, 2] < 1.96):.3f}")
    for contrast, name in ((-1.0, "opposite"), (1.0, "same")):
        for lo in np.arange(1.0, 6.0, 0.5):
            sel = (R[:, 10] >= lo) & (R[:, 10] < lo + 0.5) & (R[:, 0] > 20) & (R[:, 12] == contrast)
            if sel.sum() > 3:
                t = R[sel, 13]
                med = np.median(t)
                print(f"{name} contrast neighbour {lo:.1f}-{lo + 0.5:.1f} px: n={sel.sum():4} toward it median {med:+.3f} "
                      f"spread about it {1.4826 * np.median(np.abs(t - med)):.3f} pushed away {np.mean(t < 0):.2f}")
    if os.environ.get("BY_ORIENTATION"):
        vert = R[:, 7] > 0.9
        for cam in range(3):
            sel = vert & (R[:, 9] == cam) & (R[:, 0] > 40)
            print(f"camera {cam} vertical: n={sel.sum()} du median {np.median(R[sel, 8]):+.3f} MAD {np.median(np.abs(R[sel, 8] - np.median(R[sel, 8]))):.3f} p90|du| {np.percentile(np.abs(R[sel, 8]), 90):.3f}")
            sel = (R[:, 7] < 0.3) & (R[:, 9] == cam) & (R[:, 0] > 40)
            print(f"camera {cam} horizontal: n={sel.sum()} |e| median {np.median(np.abs(R[sel, 4])):.3f} p90 {np.percentile(np.abs(R[sel, 4]), 90):.3f}")


if __name__ == "__main__":
    main()
