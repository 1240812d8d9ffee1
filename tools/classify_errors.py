#!/usr/bin/env python3
"""Why 3D segments fail the strict scorer: direction only, position, or a wrong match.

    python3 tools/eval_shared.py --python /tmp/ev/bin/python --images --keep /tmp/evk
    /tmp/ev/bin/python tools/classify_errors.py /tmp/evk [--shared ../shared]

For each 3D segment of the kept responses (world frame via each capture's pose), against the
ground-truth edges with the scorer's tolerance max(2 cm, 1% of range):
  ok        both ends and the midpoint within tolerance of one edge, direction within 5 degrees;
  dir_only  within tolerance of an edge, but the direction is off by more than 5 degrees;
  pos_near  no edge within tolerance, but one within 3x the tolerance (imprecise depth);
  far       no edge within 3x the tolerance (a wrong match).
Prints the counts, and per class the median 3D length and predicted direction uncertainty.
"""
import argparse, glob, json, os, re, sys
import numpy as np


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("kept")
    ap.add_argument("--shared", default=os.path.join(os.path.dirname(__file__), "..", "..", "shared"))
    a = ap.parse_args()
    sys.path.insert(0, os.path.join(a.shared, "eval"))
    import score as S
    data = os.path.join(a.shared, "data", "office")
    E = np.asarray(S.load_json(os.path.join(data, "gt_edges.json"))["edges"], float)
    A, B = E[:, :3], E[:, 3:]
    eu = (B - A) / np.linalg.norm(B - A, axis=1)[:, None]
    counts = {k: [] for k in ("ok", "dir_only", "pos_near", "far")}
    for path in sorted(glob.glob(os.path.join(a.kept, "response_*.json"))):
        cap = re.search(r"response_(\d+)\.json", path).group(1)
        pose = S.load_json(os.path.join(data, f"capture_{cap}", "pose.json"))
        T = np.asarray(pose["rig_to_world"])
        c = np.asarray(pose["rig_centre_world"])
        for s in json.load(open(path)).get("segments3d", []):
            p1, p2 = (T[:3, :3] @ np.array([s[e][k] for k in "xyz"]) + T[:3, 3] for e in ("start", "end"))
            su = (p2 - p1) / np.linalg.norm(p2 - p1)
            angle = np.degrees(np.arccos(np.clip(np.abs(eu @ su), 0, 1)))
            rel = np.zeros(len(E))
            for P in (p1, p2, (p1 + p2) / 2):
                tol = max(0.02, 0.01 * np.linalg.norm(P - c))
                rel = np.maximum(rel, S.point_seg_dist(P[None], A, B)[0] / tol)
            if np.any((rel <= 1) & (angle <= 5)):
                k = "ok"
            elif np.any(rel <= 1):
                k = "dir_only"
            elif rel.min() <= 3:
                k = "pos_near"
            else:
                k = "far"
            counts[k].append((np.linalg.norm(p2 - p1), s.get("directionSigmaDeg", 0.0)))
    n = sum(len(v) for v in counts.values())
    for k, v in counts.items():
        if v:
            l, sg = np.median([x[0] for x in v]), np.median([x[1] for x in v])
            print(f"{k:9} {len(v):5} ({100 * len(v) / n:5.1f}%)  median length {l:.3f} m, direction sigma {sg:.2f} deg")


if __name__ == "__main__":
    main()
