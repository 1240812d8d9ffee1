#!/usr/bin/env python3
"""Scores a session map (examples/session_map.rs) on a room of ../shared/data with ../shared/eval.

    /tmp/ev/bin/python tools/eval_map.py [--shared ../shared] [--room office|lab] [--images]
        [--options '{"maxDirectionSigmaDeg": 2}'] [--min-observations 2]
        [--fuse '--lateral-m 0.02 --angle-deg 3'] [--out DIR] [--no-run]

Runs `cargo run --release --example session_map` (unless --no-run: then scores OUT/map.json
as it is), the scorer on OUT/map.json with --details and --png OUT/score.png, and adds what the
scorer does not say — duplicates:
  - segs_per_edge: correct map segments / distinct ground-truth edges they match (edges that
    are collinear duplicates of one another in the GT count as one); the goal is <= 1.3;
  - segs_per_gt_edge: the same per edge as the ground truth lists them (a row of boards end
    to end is several edges on one line): over the listed edges that correct map segments
    overlap by more than 1 cm along them, the mean number of such segments — how many pieces
    the map makes of one edge, where segs_per_edge also counts one piece per board of a row;
  - overlap_ratio: over those edges, summed length of the correct segments projected on their
    edge / length of the union of these projections (1.0 = no two segments cover the same
    stretch of an edge).
Prints the scorer's JSON with these keys added. Run it with a python that has numpy (the
scorer's, see ../shared/eval/README.md); the scorer runs with the same python.
"""
import argparse, functools, json, os, shlex, subprocess, sys

import numpy as np


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    ap = argparse.ArgumentParser()
    ap.add_argument("--shared", default=os.path.join(here, "..", "..", "shared"))
    ap.add_argument("--room", default="office")
    ap.add_argument("--images", action="store_true")
    ap.add_argument("--options", default=None, help="MatchOptions, proto3 JSON")
    ap.add_argument("--min-observations", default=None)
    ap.add_argument("--fuse", default="", help="more session_map flags, e.g. '--angle-deg 2'")
    ap.add_argument("--out", default=os.path.join("target", "eval_map"))
    ap.add_argument("--no-run", action="store_true")
    a = ap.parse_args()
    data = os.path.join(a.shared, "data", a.room)
    if not a.no_run:
        cmd = ["cargo", "run", "--release", "--quiet", "--example", "session_map", "--",
               "--data", data, "--out", a.out]
        if a.images:
            cmd.append("--images")
        if a.options:
            cmd += ["--options", a.options]
        if a.min_observations:
            cmd += ["--min-observations", str(a.min_observations)]
        cmd += shlex.split(a.fuse)
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    map_path = os.path.join(a.out, "map.json")
    details = os.path.join(a.out, "details.json")
    out = subprocess.run([sys.executable, os.path.join(a.shared, "eval", "score.py"), data, map_path,
                          "--details", details, "--png", os.path.join(a.out, "score.png")],
                         check=True, capture_output=True, text=True).stdout
    summary = json.loads(out)
    match = json.load(open(details))["match"]
    S = np.asarray(json.load(open(map_path))["segments"], float).reshape(-1, 6)
    E = np.asarray(json.load(open(os.path.join(data, "gt_edges.json")))["edges"], float)
    A, B = E[:, :3], E[:, 3:]
    U = (B - A) / np.linalg.norm(B - A, axis=1, keepdims=True)

    L = np.linalg.norm(B - A, axis=1)

    @functools.lru_cache(maxsize=None)
    def on_its_line(j):
        # The scorer's duplicate edges: parallel and on the same line.
        par = np.abs(np.abs(U @ U[j]) - 1) < 1e-9
        w = A - A[j]
        off = np.linalg.norm(w - (w @ U[j])[:, None] * U[j], axis=1)
        return np.nonzero(par & (off < 1e-6))[0]

    def representative(j):
        return int(on_its_line(j).min())

    pieces = {}
    for k, j in enumerate(match):
        if j >= 0:
            for i in on_its_line(j):
                lo, hi = sorted(((S[k, :3] - A[i]) @ U[i], (S[k, 3:] - A[i]) @ U[i]))
                if min(hi, L[i]) - max(lo, 0.0) > 0.01:
                    pieces[int(i)] = pieces.get(int(i), 0) + 1

    groups = {}
    for k, j in enumerate(match):
        if j >= 0:
            groups.setdefault(representative(j), []).append(k)
    n_correct = sum(len(v) for v in groups.values())
    summed = union = 0.0
    for j, ks in groups.items():
        t = sorted(sorted(((S[k, :3] - A[j]) @ U[j], (S[k, 3:] - A[j]) @ U[j])) for k in ks)
        summed += sum(hi - lo for lo, hi in t)
        cur_lo, cur_hi = t[0]
        for lo, hi in t[1:]:
            if lo > cur_hi:
                union += cur_hi - cur_lo
                cur_lo, cur_hi = lo, hi
            else:
                cur_hi = max(cur_hi, hi)
        union += cur_hi - cur_lo
    summary["covered_edges"] = len(groups)
    summary["segs_per_edge"] = round(n_correct / len(groups), 3) if groups else None
    summary["segs_per_gt_edge"] = round(float(np.mean(list(pieces.values()))), 3) if pieces else None
    summary["overlap_ratio"] = round(summed / union, 3) if union > 0 else None
    summary["pose_error"] = json.load(open(map_path)).get("pose_error")
    print(json.dumps(summary))


if __name__ == "__main__":
    sys.exit(main())
