"""Would a line fitted to the grey levels beside each extracted segment be more precise than
the extractor's line through its edge points? A study on the rendered rooms, not a product
stage (docs/ACCURACY.md, "Tried and dropped: the line fitted to the grey levels").

    [BAND=2] [SHADING=0|1] [ROOMS=office,lab] [CAPS=00,01,...,11] python tools/band_fit_study.py

Run from the repository root with a Python that has numpy, scipy and pillow, after `cargo build
--release`; `../shared` must hold the rooms. For every extracted segment (12 px and longer)
that lies on the projection of a true edge (both ends within 1.5 px, 4 degrees), the pixels
within BAND px of its line (1 px short of its ends) are fitted by least squares with a blurred
step edge, a + c * Phi((s - o - theta * t) / b), across-line offset o and tilt theta, both
sides' levels (SHADING=1: each varying linearly along the line); the fitted line's offset at the
midpoint and its direction are compared with the truth, beside the extractor's. Prints, by
length, the median and 90th percentile of both errors, the fit's own (Gauss-Newton) angle
sigma, and the share of the fitted lines' errors within 1.96 / 2.58 of the extractor's
reported sigma scaled by k: how far the reported noise could shrink if the fitted line
replaced the extractor's.
"""
import json, math, os, subprocess, sys, tempfile
import numpy as np
from PIL import Image
from scipy.optimize import least_squares
from scipy.special import erf
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from eval_rooms import request_for

SH = os.environ.get("SHARED", "../shared")
R = float(os.environ.get("BAND", "2"))
SHADING = os.environ.get("SHADING", "0") == "1"
rooms = os.environ.get("ROOMS", "office,lab").split(",")
caps = os.environ.get("CAPS", ",".join(f"{k:02}" for k in range(12))).split(",")
rows = []
for room in rooms:
    data = os.path.join(SH, "data", room)
    E = np.asarray(json.load(open(os.path.join(data, "gt_edges.json")))["edges"], float)
    for cap in caps:
        cdir = os.path.join(data, "capture_" + cap)
        req = request_for(cdir, {"returnExtracted": True}, True)
        path = os.path.join(tempfile.mkdtemp(), "req.json"); json.dump(req, open(path, "w"))
        out = json.loads(subprocess.run(["target/release/trinocular", "match", path], check=True, capture_output=True, text=True).stdout)
        lists = [l.get("segments", []) for l in out["extracted"]]
        calib = json.load(open(os.path.join(cdir, "calib_world.json")))
        vis = json.load(open(os.path.join(cdir, "visibility.json")))
        for cam in range(3):
            img = np.asarray(Image.open(os.path.join(cdir, f"img{cam+1}.png")).convert("L"), float)
            H, W = img.shape
            P = np.asarray(calib["cameras"][cam]["P"], float)
            lines = []
            for r in vis["edges"]:
                for lo, hi in r["vis"][cam]:
                    A, B = E[r["i"], :3], E[r["i"], 3:]
                    pa = P @ np.append(A + lo * (B - A), 1); pb = P @ np.append(A + hi * (B - A), 1)
                    if pa[2] <= 0 or pb[2] <= 0: continue
                    pa, pb = pa[:2] / pa[2], pb[:2] / pb[2]
                    if np.linalg.norm(pb - pa) >= 5: lines.append((pa, pb))
            LA = np.array([l[0] for l in lines]); LB = np.array([l[1] for l in lines])
            LD = LB - LA; LL = np.linalg.norm(LD, axis=1); LU = LD / LL[:, None]; LN = np.stack([-LU[:, 1], LU[:, 0]], 1)
            ys, xs = np.mgrid[0:H, 0:W]
            for s in lists[cam]:
                p = np.array([s["u1"], s["v1"]]); q = np.array([s["u2"], s["v2"]])
                L = np.linalg.norm(q - p)
                if L < 12: continue
                u = (q - p) / L
                dp = np.abs(np.einsum("ij,ij->i", p - LA, LN)); dq = np.abs(np.einsum("ij,ij->i", q - LA, LN))
                ang = np.degrees(np.arccos(np.clip(np.abs(LU @ u), 0, 1)))
                tp = np.einsum("ij,ij->i", p - LA, LU) / LL; tq = np.einsum("ij,ij->i", q - LA, LU) / LL
                ok = (dp < 1.5) & (dq < 1.5) & (ang < 4) & (np.minimum(tp, tq) > -0.05) & (np.maximum(tp, tq) < 1.05)
                if not ok.any(): continue
                k = np.argmin(np.where(ok, dp + dq, np.inf))
                m = 0.5 * (p + q)
                n = np.array([u[1], -u[0]])
                def err(mid, dirv):
                    e = (mid - (LA[k] + ((mid - LA[k]) @ LU[k]) * LU[k])) @ n
                    return e, math.degrees(math.acos(min(1, abs(LU[k] @ dirv))))
                e0, a0 = err(m, u)
                # band pixels
                x0, x1 = int(max(0, min(p[0], q[0]) - R - 1)), int(min(W - 1, max(p[0], q[0]) + R + 1))
                y0, y1 = int(max(0, min(p[1], q[1]) - R - 1)), int(min(H - 1, max(p[1], q[1]) + R + 1))
                X = xs[y0:y1 + 1, x0:x1 + 1].ravel().astype(float); Y = ys[y0:y1 + 1, x0:x1 + 1].ravel().astype(float)
                I = img[y0:y1 + 1, x0:x1 + 1].ravel()
                t = (X - m[0]) * u[0] + (Y - m[1]) * u[1]
                sn = (X - m[0]) * n[0] + (Y - m[1]) * n[1]
                sel = (np.abs(sn) <= R) & (np.abs(t) <= L / 2 - 1)
                t, sn, I = t[sel], sn[sel], I[sel]
                if len(I) < 20: continue
                lo_side = I[sn < -1].mean() if (sn < -1).any() else I.min()
                hi_side = I[sn > 1].mean() if (sn > 1).any() else I.max()
                def model(x):
                    o, th, a, c, b, a1, c1 = x if SHADING else (*x, 0.0, 0.0)
                    tt = t / max(L, 1)
                    return a + a1 * tt + (c + c1 * tt) * 0.5 * (1 + erf((sn - o - th * t) / (abs(b) * math.sqrt(2)) ))
                x0v = [0.0, 0.0, lo_side, hi_side - lo_side, 0.7] + ([0.0, 0.0] if SHADING else [])
                try:
                    res = least_squares(lambda x: model(x) - I, x0v)
                except Exception:
                    continue
                o, th = res.x[0], res.x[1]
                if abs(o) > 1.5 or abs(th) > 0.1: continue
                mid1 = m + o * n
                dir1 = u + th * n; dir1 /= np.linalg.norm(dir1)
                e1, a1 = err(mid1, dir1)
                resid = np.sqrt(np.mean(res.fun ** 2))
                J = res.jac
                try:
                    C = np.linalg.inv(J.T @ J) * resid**2
                except Exception:
                    continue
                crb = math.degrees(math.sqrt(abs(C[1,1])))
                rows.append((L, e0, a0, e1, a1, s["offsetSigmaPx"], s["angleSigmaDeg"], abs(res.x[4]), resid, abs(res.x[3]), crb))
R_ = np.array(rows)
print(len(R_), "segments")
for lo, hi in [(12, 20), (20, 40), (40, 80), (80, 1e9), (0, 1e9)]:
    s = (R_[:, 0] >= lo) & (R_[:, 0] < hi)
    if not s.any(): continue
    X = R_[s]
    print(f"L {lo}-{hi}: n={s.sum()} offset |e| med/p90 extractor {np.median(abs(X[:,1])):.3f}/{np.percentile(abs(X[:,1]),90):.3f} band {np.median(abs(X[:,3])):.3f}/{np.percentile(abs(X[:,3]),90):.3f} | angle med/p90 deg extractor {np.median(X[:,2]):.3f}/{np.percentile(X[:,2],90):.3f} band {np.median(X[:,4]):.3f}/{np.percentile(X[:,4],90):.3f} | reported angle sigma med {np.median(X[:,6]):.3f} blur {np.median(X[:,7]):.2f} crb angle med {np.median(X[:,10]):.3f} z_band in1.96 {np.mean(X[:,4] < 1.96*X[:,10]):.2f} z_ext in1.96 {np.mean(X[:,2] < 1.96*X[:,6]):.2f} resid {np.median(X[:,8]):.2f} contrast {np.median(X[:,9]):.1f}")
for lo, hi in [(12, 20), (20, 40), (40, 80), (80, 1e9)]:
    X = R_[(R_[:, 0] >= lo) & (R_[:, 0] < hi)]
    if len(X):
        print(f"L {lo}-{hi}: within 1.96 / 2.58 of k x the reported sigma: extractor (k 1) {np.mean(X[:, 2] < 1.96 * X[:, 6]):.3f} / {np.mean(X[:, 2] < 2.58 * X[:, 6]):.3f}; fitted "
              + ", ".join(f"k {k}: {np.mean(X[:, 4] < 1.96 * k * X[:, 6]):.3f} / {np.mean(X[:, 4] < 2.58 * k * X[:, 6]):.3f}" for k in (1.0, 0.8, 0.6)))
