#!/usr/bin/env python3
"""Scores `trinocular match` on the rendered rooms of the shared data with the shared scorer,
room by room, and says why the wrong segments are wrong.

    python tools/eval_rooms.py --shared PATH [--rooms office,lab] [--input images|lsd|both]
        [--options '{"includeUncertain": true}'] [--bin target/release/trinocular] [--keep DIR]
        [--calibration] [--json]

Run it with a Python that has numpy (the scorer's own requirement: see the scorer's README).
For each room and capture it builds a MatchRequest from calib.json and either the three PNG
images (our extraction) or segments_lsd.json (OpenCV LSD lists), runs the CLI, and scores the
3D segments with the scorer's own `score()` (imported, not copied). Per room and input it
prints the pooled figures (error over all segments, completeness over all eligible length),
the error classes of the issue tracker, the error by 3D length, and (`--calibration`) how
well the reported covariances describe the true errors of the segments that lie on their
true edge: the share of squared Mahalanobis errors of direction and position (2 degrees of
freedom each) within the chi-square 95% and 99% quantiles, overall and by the reported
direction sigma (where the accuracy gate decides, 2-5 degrees, a covariance drawn too wide
would refuse segments it need not). The saved chi2_ROOM_INPUT.npy has one row per segment:
direction and position chi2, reported direction sigma (degrees), uncertain (0/1).

Which segments are "on their true edge" is decided in the images, not by the 3D error that
is being tested: a 3D segment is on ground-truth edge j when each of its three image
segments lies along j's projection in that view (both ends within 1.5 px of it, within 4
degrees, inside its visible part). Its errors are then measured against j however large
they are. (Choosing the population by the scorer's verdict instead, i.e. among segments
within 5 degrees and the position tolerance, cuts off exactly the tail the test is about:
it reported 96.7% of the office's directions within q95 where the whole population gives
95.1%.)

Error classes, against the nearest ground-truth edge with the scorer's tolerance
max(2 cm, 1% of the distance to the rig):
  ok        correct (both ends and the midpoint within tolerance of one edge, direction within 5 deg);
  dir_only  within tolerance of an edge, but more than 5 degrees off its direction;
  pos_near  no edge within tolerance, but one within 3x the tolerance;
  far       no edge within 3x the tolerance.
"""
import argparse
import base64
import json
import os
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor

import numpy as np

CHI2_2DOF_95 = 5.991464547107979
CHI2_2DOF_99 = 9.210340371976184
LENGTH_BINS = [(0.0, 0.10), (0.10, 0.30), (0.30, 1e9)]
DIRECTION_SIGMA_BINS = [(0.0, 1.0), (1.0, 2.0), (2.0, 3.0), (3.0, 5.0), (5.0, 1e9)]


def request_for(cdir, options, images):
    calib = json.load(open(os.path.join(cdir, "calib.json")))
    cams = [{"name": c["name"], "width": c["width"], "height": c["height"],
             "projection": [v for row in c["P"] for v in row]} for c in calib["cameras"]]
    req = {"calibration": {"cameras": cams}}
    if images:
        req["images"] = {"images": [
            {"encoded": base64.b64encode(open(os.path.join(cdir, f"img{i}.png"), "rb").read()).decode()}
            for i in (1, 2, 3)]}
    else:
        lsd = json.load(open(os.path.join(cdir, "segments_lsd.json")))
        req["segments"] = {"lists": [
            {"oriented": True,
             "segments": [{"u1": s[0], "v1": s[1], "u2": s[2], "v2": s[3]} for s in im["segments"]]}
            for im in lsd["images"]]}
    if options:
        req["options"] = options
    return req


def run_capture(binary, cdir, options, images, work, tag):
    req_path = os.path.join(work, f"request_{tag}.json")
    with open(req_path, "w") as f:
        json.dump(request_for(cdir, options, images), f)
    out = subprocess.run([binary, "match", req_path], check=True, capture_output=True, text=True).stdout
    with open(os.path.join(work, f"response_{tag}.json"), "w") as f:
        f.write(out)
    return json.loads(out)


def xyz(p):
    return np.array([p.get("x", 0.0), p.get("y", 0.0), p.get("z", 0.0)])


def perp_basis(u):
    a = np.array([1.0, 0, 0]) if abs(u[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(u, e1)])


ALONG_PX = 1.5
ALONG_DEG = 4.0


def edges_along(cdir, E, lists):
    """Per camera, per 2D segment of `lists` (dicts with u1 v1 u2 v2): the set of ground-truth
    edges whose visible projection it lies along (both ends within ALONG_PX, direction within
    ALONG_DEG, inside the visible interval with 5% slack)."""
    calib = json.load(open(os.path.join(cdir, "calib_world.json")))
    vis = json.load(open(os.path.join(cdir, "visibility.json")))
    out = []
    for cam in range(3):
        P = np.asarray(calib["cameras"][cam]["P"], float)
        la, lb, ids = [], [], []
        for r in vis["edges"]:
            A, B = E[r["i"], :3], E[r["i"], 3:]
            for lo, hi in r["vis"][cam]:
                pa = P @ np.append(A + lo * (B - A), 1)
                pb = P @ np.append(A + hi * (B - A), 1)
                if pa[2] <= 0 or pb[2] <= 0:
                    continue
                pa, pb = pa[:2] / pa[2], pb[:2] / pb[2]
                if np.linalg.norm(pb - pa) >= 1:
                    la.append(pa), lb.append(pb), ids.append(r["i"])
        sets = []
        if not la:
            out.append([set() for _ in lists[cam]])
            continue
        LA, LB, ids = np.array(la), np.array(lb), np.array(ids)
        LL = np.linalg.norm(LB - LA, axis=1)
        LU = (LB - LA) / LL[:, None]
        LN = np.stack([-LU[:, 1], LU[:, 0]], 1)
        for s in lists[cam]:
            p = np.array([s.get("u1", 0.0), s.get("v1", 0.0)])
            q = np.array([s.get("u2", 0.0), s.get("v2", 0.0)])
            L = np.linalg.norm(q - p)
            if L <= 0:
                sets.append(set())
                continue
            u = (q - p) / L
            dp = np.abs(np.einsum("ij,ij->i", p - LA, LN))
            dq = np.abs(np.einsum("ij,ij->i", q - LA, LN))
            ang = np.degrees(np.arccos(np.clip(np.abs(LU @ u), 0, 1)))
            tp = np.einsum("ij,ij->i", p - LA, LU) / LL
            tq = np.einsum("ij,ij->i", q - LA, LU) / LL
            ok = (dp < ALONG_PX) & (dq < ALONG_PX) & (ang < ALONG_DEG) & \
                 (np.minimum(tp, tq) > -0.05) & (np.maximum(tp, tq) < 1.05)
            sets.append(set(ids[ok].tolist()))
        out.append(sets)
    return out


def true_edge(triplet, along, seg_w, E):
    """The ground-truth edge a triplet's three image segments all lie along (the nearest to
    the 3D segment's midpoint if several), or None."""
    common = along[0][triplet["s1"]] & along[1][triplet["s2"]] & along[2][triplet["s3"]]
    if not common:
        return None
    m = 0.5 * (seg_w[:3] + seg_w[3:])

    def dist(j):
        a, b = E[j, :3], E[j, 3:]
        u = (b - a) / np.linalg.norm(b - a)
        w = m - a
        return np.linalg.norm(w - (w @ u) * u)
    return min(common, key=dist)


def classify(S, E, c, S_mod):
    """Error class per segment (world frame)."""
    A, B = E[:, :3], E[:, 3:]
    eu = (B - A) / np.linalg.norm(B - A, axis=1)[:, None]
    classes = []
    for s in S:
        p1, p2 = s[:3], s[3:]
        su = (p2 - p1) / max(np.linalg.norm(p2 - p1), 1e-12)
        angle = np.degrees(np.arccos(np.clip(np.abs(eu @ su), 0, 1)))
        rel = np.zeros(len(E))
        for P in (p1, p2, (p1 + p2) / 2):
            tol = max(0.02, 0.01 * np.linalg.norm(P - c))
            rel = np.maximum(rel, S_mod.point_seg_dist(P[None], A, B)[0] / tol)
        if np.any((rel <= 1) & (angle <= 5)):
            k = "ok"
        elif np.any(rel <= 1):
            k = "dir_only"
        elif rel.min() <= 3:
            k = "pos_near"
        else:
            k = "far"
        classes.append(k)
    return classes


def nearest(s, E, c, S_mod):
    """The start, midpoint and end's distances from the true edge nearest the segment (least
    summed), each over the scorer's tolerance there, and the angle: says whether a wrong
    segment is off across its edge or runs on past an end of it."""
    A, B = E[:, :3], E[:, 3:]
    pts = (s[:3], 0.5 * (s[:3] + s[3:]), s[3:])
    d = np.stack([S_mod.point_seg_dist(P[None], A, B)[0] for P in pts])
    j = int(np.argmin(d.sum(axis=0)))
    rel = [d[k, j] / max(0.02, 0.01 * np.linalg.norm(P - c)) for k, P in enumerate(pts)]
    su = (s[3:] - s[:3]) / max(np.linalg.norm(s[3:] - s[:3]), 1e-12)
    eu = (B[j] - A[j]) / np.linalg.norm(B[j] - A[j])
    angle = np.degrees(np.arccos(np.clip(abs(eu @ su), 0, 1)))
    return "/".join(f"{r:.1f}" for r in rel) + f" tol, {angle:.1f}°"


def mahalanobis(seg_rig, cov6, edge_rig):
    """Squared normalised errors of direction and midpoint position (2 dof each), or None."""
    p1, p2 = seg_rig[:3], seg_rig[3:]
    d = p2 - p1
    L = np.linalg.norm(d)
    if L <= 0:
        return None
    u = d / L
    m = 0.5 * (p1 + p2)
    a, b = edge_rig[:3], edge_rig[3:]
    eu = (b - a) / np.linalg.norm(b - a)
    if eu @ u < 0:
        eu = -eu
    basis = perp_basis(u)
    # Direction: u = (p2 - p1)/L, so its error across the line is the endpoints' difference / L.
    J_dir = np.hstack([-basis, basis]) / L
    J_pos = np.hstack([basis, basis]) * 0.5
    C = np.asarray(cov6, float).reshape(6, 6)
    Cd = J_dir @ C @ J_dir.T
    Cp = J_pos @ C @ J_pos.T
    e_dir = basis @ (eu - u)
    w = m - a
    foot = a + (w @ eu) * eu
    e_pos = basis @ (foot - m)
    try:
        return float(e_dir @ np.linalg.solve(Cd, e_dir)), float(e_pos @ np.linalg.solve(Cp, e_pos))
    except np.linalg.LinAlgError:
        return None


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shared", required=True, help="the shared folder (holds data/ and eval/)")
    ap.add_argument("--rooms", default="office,lab")
    ap.add_argument("--input", default="both", choices=["images", "lsd", "both"])
    ap.add_argument("--bin", default="target/release/trinocular")
    ap.add_argument("--options", default=None)
    ap.add_argument("--captures", default=None, help="e.g. 00,05 (default: all)")
    ap.add_argument("--keep", default=None)
    ap.add_argument("--wrong", action="store_true", help="list every wrong segment")
    ap.add_argument("--calibration", action="store_true")
    ap.add_argument("--json", action="store_true", help="one JSON line per room and input")
    a = ap.parse_args()
    sys.path.insert(0, os.path.join(a.shared, "eval"))
    import score as S_mod  # the shared scorer, imported as is

    options = json.loads(a.options) if a.options else None
    if a.calibration:
        # The image segments, to decide which edge each 3D segment is on (adds to the answer
        # only; the 3D output is the same).
        options = dict(options or {}, returnExtracted=True)
    inputs = ["images", "lsd"] if a.input == "both" else [a.input]
    work = a.keep or tempfile.mkdtemp()
    os.makedirs(work, exist_ok=True)
    for room in a.rooms.split(","):
        data = os.path.join(a.shared, "data", room)
        E = np.asarray(S_mod.load_json(os.path.join(data, "gt_edges.json"))["edges"], float)
        caps = sorted(d[len("capture_"):] for d in os.listdir(data) if d.startswith("capture_"))
        if a.captures:
            caps = a.captures.split(",")
        for inp in inputs:
            images = inp == "images"
            tags = [f"{room}_{inp}_{cap}" for cap in caps]
            with ThreadPoolExecutor(2) as pool:
                outs = list(pool.map(lambda ct: run_capture(a.bin, os.path.join(data, "capture_" + ct[0]),
                                                            options, images, work, ct[1]), zip(caps, tags)))
            n = nc = 0
            tot_len = cov_len = 0.0
            classes_all, lengths, chi = [], [], []
            ms = []
            for cap, out in zip(caps, outs):
                segs3 = out.get("segments3d", [])
                seg_rig = np.array([np.concatenate([xyz(s["start"]), xyz(s["end"])]) for s in segs3]).reshape(-1, 6)
                sc, extra = S_mod.score(data, {"segments": seg_rig.tolist(), "frame": "rig"}, capture=cap)
                n += sc["n_segments"]
                nc += sc["n_correct"]
                tot_len += sc["eligible_length_m"]
                cov_len += sc["covered_length_m"]
                ms.append(out.get("stats", {}).get("totalMs", 0.0))
                pose = S_mod.load_json(os.path.join(data, f"capture_{cap}", "pose.json"))
                T = np.asarray(pose["rig_to_world"], float)
                c = np.asarray(pose["rig_centre_world"], float)
                seg_w = np.hstack([seg_rig[:, :3] @ T[:3, :3].T + T[:3, 3], seg_rig[:, 3:] @ T[:3, :3].T + T[:3, 3]])
                cls = classify(seg_w, E, c, S_mod)
                classes_all += cls
                if a.wrong:
                    for i, (s, sr, k) in enumerate(zip(segs3, seg_rig, cls)):
                        if k == "ok":
                            continue
                        t = out["triplets"][s.get("triplet", 0)]
                        print(f"  wrong {room} {inp} {cap} #{i} {k:8} len={np.linalg.norm(sr[3:] - sr[:3]):.2f}m "
                              f"range={np.linalg.norm(0.5 * (sr[:3] + sr[3:])):.2f}m dirσ={s.get('directionSigmaDeg', 0):.2f}° "
                              f"posσ={100 * s.get('positionSigmaM', 0):.2f}cm triplet=({t.get('s1', 0)},{t.get('s2', 0)},{t.get('s3', 0)}) "
                              f"pieces={len(s.get('triplets', []))} resid={s.get('residualPx', 0):.3f}px "
                              f"nearest edge: start/mid/end {nearest(seg_w[i], E, c, S_mod)}")
                lengths += list(np.linalg.norm(seg_rig[:, 3:] - seg_rig[:, :3], axis=1))
                if a.calibration:
                    Tinv = np.linalg.inv(T)
                    cdir = os.path.join(data, "capture_" + cap)
                    if images:
                        lists2d = [l.get("segments", []) for l in out.get("extracted", [])]
                    else:
                        req = json.load(open(os.path.join(work, f"request_{room}_{inp}_{cap}.json")))
                        lists2d = [l["segments"] for l in req["segments"]["lists"]]
                    along = edges_along(cdir, E, lists2d)
                    for s, sr, sw in zip(segs3, seg_rig, seg_w):
                        cov = s.get("covariance")
                        # Segments on their true edge: decided in the images (see above).
                        j = true_edge(out["triplets"][s.get("triplet", 0)], along, sw, E) if cov else None
                        if j is None:
                            continue
                        e = E[j]
                        e_rig = np.concatenate([Tinv[:3, :3] @ e[:3] + Tinv[:3, 3], Tinv[:3, :3] @ e[3:] + Tinv[:3, 3]])
                        m = mahalanobis(sr, cov, e_rig)
                        if m is not None:
                            chi.append((*m, s.get("directionSigmaDeg", 0.0), float(s.get("uncertain", False))))
            classes_all = np.array(classes_all)
            lengths = np.array(lengths)
            res = {"room": room, "input": inp, "captures": len(caps), "segments": n,
                   "error_rate": round(1 - nc / n, 4) if n else None,
                   "completeness": round(cov_len / tot_len, 4) if tot_len else None,
                   "median_total_ms": round(float(np.median(ms)), 2) if ms else None}
            for k in ("dir_only", "pos_near", "far"):
                res[k] = round(float(np.mean(classes_all == k)), 4) if n else None
            for lo, hi in LENGTH_BINS:
                sel = (lengths >= lo) & (lengths < hi)
                key = f"wrong_{int(lo * 100)}_{int(hi * 100) if hi < 1e8 else 'up'}cm"
                res[key] = (round(float(np.mean(classes_all[sel] != "ok")), 3), int(sel.sum())) if sel.any() else None
            if a.calibration and chi:
                ch = np.array(chi)
                res["calib_n"] = len(ch)
                res["dir_in95"] = round(float(np.mean(ch[:, 0] <= CHI2_2DOF_95)), 4)
                res["dir_in99"] = round(float(np.mean(ch[:, 0] <= CHI2_2DOF_99)), 4)
                res["pos_in95"] = round(float(np.mean(ch[:, 1] <= CHI2_2DOF_95)), 4)
                res["pos_in99"] = round(float(np.mean(ch[:, 1] <= CHI2_2DOF_99)), 4)
                res["dir_median_chi2"] = round(float(np.median(ch[:, 0])), 3)
                res["pos_median_chi2"] = round(float(np.median(ch[:, 1])), 3)
                # By the reported direction sigma: where the gate decides (2-4 degrees), is the
                # covariance too wide or too narrow?
                for lo, hi in DIRECTION_SIGMA_BINS:
                    sel = (ch[:, 2] >= lo) & (ch[:, 2] < hi)
                    if sel.any():
                        res[f"dir_sigma_{lo:g}_{hi:g}"] = (int(sel.sum()),
                                                           round(float(np.mean(ch[sel, 0] <= CHI2_2DOF_95)), 3),
                                                           round(float(np.mean(ch[sel, 1] <= CHI2_2DOF_95)), 3))
                np.save(os.path.join(work, f"chi2_{room}_{inp}.npy"), ch)
            if a.json:
                print(json.dumps(res), flush=True)
            else:
                print(f"{room:7} {inp:6} n={n:5} err={res['error_rate']:.4f} compl={res['completeness']:.4f} "
                      f"dir_only={res['dir_only']:.4f} pos_near={res['pos_near']:.4f} far={res['far']:.4f} "
                      + " ".join(f"{k}={res[k]}" for k in res if k.startswith("wrong_"))
                      + (f" calib(n={res['calib_n']}): dir95={res['dir_in95']} dir99={res['dir_in99']} "
                         f"pos95={res['pos_in95']} pos99={res['pos_in99']} med={res['dir_median_chi2']}/{res['pos_median_chi2']}"
                         if "calib_n" in res else "")
                      + "".join(f" {k}=(n, dir95, pos95){res[k]}" for k in res if k.startswith("dir_sigma_")), flush=True)


if __name__ == "__main__":
    main()
