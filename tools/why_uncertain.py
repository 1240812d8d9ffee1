#!/usr/bin/env python3
"""Why the segments the accuracy gate leaves out are left out, and what each kind would add.

    /tmp/ev/bin/python tools/why_uncertain.py --shared ../shared [--rooms office,lab]
        [--input lsd|images] [--bin target/release/trinocular] [--keep DIR]

Runs the rooms' captures with `includeUncertain` (through tools/eval_rooms.py's request
builder), then sorts each uncertain 3D segment by what its reported covariance fails: the
direction test alone, the position tests alone (midpoint and both ends across the line), both,
or neither (the uniqueness test's doubt, or a trim that left too little). The tests are
recomputed here from the answer's covariance as the gate states them (docs/ACCURACY.md, "The
promise of the default answer": direction within 5 degrees, position within max(2 cm, 1% of
the range from the rig's centroid), each at 95% for a 2D Gaussian across the line), so a
segment on the gate's edge may land in a neighbouring kind. Prints per room the counts,
correct / wrong by the scorer's error classes, and the completeness of the default answer
with each kind added — all of it, and (an oracle) only its correct segments. Needs numpy and
scipy besides the scorer.
"""
import argparse
import collections
import json
import os
import sys
import tempfile

import numpy as np
from scipy.special import erf
from scipy.stats import chi2

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import eval_rooms as ER  # noqa: E402  (the request builder and the error classes)

ROUND_95 = float(np.sqrt(chi2.ppf(0.95, 2)))
KINDS = ["direction", "position", "both", "neither"]


def within_radius(variances, radius, confidence=0.95):
    """P(a 2D Gaussian of these principal variances lies within `radius`) >= confidence."""
    major, minor = variances
    if ROUND_95 * np.sqrt(major) <= radius:
        return True
    sx, sy = np.sqrt(max(major, 1e-30)), np.sqrt(max(minor, 1e-30))
    x = np.linspace(-radius, radius, 401)
    inside = erf(np.sqrt(np.maximum(radius * radius - x * x, 0.0)) / (sy * np.sqrt(2)))
    density = np.exp(-0.5 * (x / sx) ** 2) / (sx * np.sqrt(2 * np.pi))
    return np.trapezoid(density * inside, x) >= confidence


def across(u):
    a = np.array([1.0, 0, 0]) if abs(u[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(u, e1)], 1)


def principal(c, basis):
    w = np.linalg.eigvalsh(basis.T @ c @ basis)
    return w[1], w[0]


def kind_of(start, end, cov, centre):
    """Which of the gate's tests the segment's covariance fails."""
    length = np.linalg.norm(end - start)
    u = (end - start) / length
    basis = across(u)
    to_direction = (np.eye(3) - np.outer(u, u)) @ np.hstack([-np.eye(3), np.eye(3)]) / length
    direction_ok = within_radius(principal(to_direction @ cov @ to_direction.T, basis), np.radians(5.0))

    def tolerance(p):
        return max(0.02, 0.01 * np.linalg.norm(p - centre))

    to_mid = np.hstack([np.eye(3), np.eye(3)]) * 0.5
    mid = 0.5 * (start + end)
    position_ok = (within_radius(principal(to_mid @ cov @ to_mid.T, basis), tolerance(mid))
                   and within_radius(principal(cov[:3, :3], basis), tolerance(start))
                   and within_radius(principal(cov[3:, 3:], basis), tolerance(end)))
    return {(False, True): "direction", (True, False): "position", (False, False): "both",
            (True, True): "neither"}[(direction_ok, position_ok)]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shared", required=True)
    ap.add_argument("--rooms", default="office,lab")
    ap.add_argument("--input", default="lsd", choices=["images", "lsd"])
    ap.add_argument("--bin", default="target/release/trinocular")
    ap.add_argument("--keep", default=None)
    a = ap.parse_args()
    sys.path.insert(0, os.path.join(a.shared, "eval"))
    import score as S  # the shared scorer, imported as is

    work = a.keep or tempfile.mkdtemp()
    os.makedirs(work, exist_ok=True)
    images = a.input == "images"
    for room in a.rooms.split(","):
        data = os.path.join(a.shared, "data", room)
        E = np.asarray(S.load_json(os.path.join(data, "gt_edges.json"))["edges"], float)
        rows = []
        for cap in sorted(d[len("capture_"):] for d in os.listdir(data) if d.startswith("capture_")):
            cdir = os.path.join(data, "capture_" + cap)
            out = ER.run_capture(a.bin, cdir, {"includeUncertain": True}, images, work, f"{room}_{a.input}_{cap}")
            calib = json.load(open(os.path.join(cdir, "calib.json")))
            centres = []
            for c in calib["cameras"]:
                P = np.asarray(c["P"], float)
                centres.append(-np.linalg.solve(P[:, :3], P[:, 3]))
            centre = np.mean(centres, axis=0)
            pose = S.load_json(os.path.join(cdir, "pose.json"))
            T = np.asarray(pose["rig_to_world"], float)
            c_world = np.asarray(pose["rig_centre_world"], float)
            for s in out.get("segments3d", []):
                start, end = ER.xyz(s["start"]), ER.xyz(s["end"])
                world = np.concatenate([T[:3, :3] @ start + T[:3, 3], T[:3, :3] @ end + T[:3, 3]])
                uncertain = s.get("uncertain", False)
                kind = kind_of(start, end, np.asarray(s["covariance"], float).reshape(6, 6), centre) \
                    if uncertain else "certain"
                rows.append({"capture": cap, "kind": kind, "world": world, "length": np.linalg.norm(end - start),
                             "class": ER.classify(world[None], E, c_world, S)[0]})

        def scored(keep):
            total = covered = 0.0
            n = correct = 0
            for cap in sorted({r["capture"] for r in rows}):
                segs = [r["world"].tolist() for r in rows if r["capture"] == cap and keep(r)]
                sc, _ = S.score(data, {"segments": segs, "frame": "world"}, capture=cap)
                total += sc["eligible_length_m"]
                covered += sc["covered_length_m"]
                n += sc["n_segments"]
                correct += sc["n_correct"]
            return f"{n} segments, {1 - correct / max(n, 1):.2%} wrong, {covered / total:.2%} complete"

        counts = collections.Counter((r["kind"], r["class"] == "ok") for r in rows)
        lengths = collections.Counter()
        for r in rows:
            lengths[(r["kind"], r["class"] == "ok")] += r["length"]
        print(f"{room}, {a.input}: the default answer {scored(lambda r: r['kind'] == 'certain')}")
        for kind in KINDS:
            print(f"  uncertain for {kind:9}: {counts[(kind, True)]} correct ({lengths[(kind, True)]:.1f} m), "
                  f"{counts[(kind, False)]} wrong ({lengths[(kind, False)]:.1f} m); added: "
                  f"{scored(lambda r, k=kind: r['kind'] in ('certain', k))}; its correct ones only: "
                  f"{scored(lambda r, k=kind: r['kind'] == 'certain' or (r['kind'] == k and r['class'] == 'ok'))}")


if __name__ == "__main__":
    sys.exit(main())
