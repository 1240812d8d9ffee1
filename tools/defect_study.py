#!/usr/bin/env python3
"""What a real line extractor's lists look like against the exact ground truth of the rendered
rooms: the measurement behind `synth::Defects::realistic()`.

    python tools/defect_study.py --shared PATH [--rooms office,lab] [--input lsd|images]
        [--bin target/release/trinocular]

Run with a Python that has numpy. For every capture and camera, the visible pieces of the
ground-truth edges (`visibility.json`, projected with `calib_world.json`) that project to at
least 20 px are the segments an ideal extractor would report. Each listed segment (OpenCV LSD's
`segments_lsd.json`, or our extractor's, through the CLI) is assigned to the piece it lies
along (both ends within 1.5 px of the piece's line, direction within 4 degrees, overlapping it
along the line; the nearest if several). Prints, pooled over both rooms:

- the offset of each end across its piece's line (robust sigma 1.4826 x MAD, percentiles of
  |offset|), and per segment its line's shift and turn (the mean and half difference of its
  ends' offsets): the synthetic lists' `endpoint_noise_px` and tail;
- whether the tail belongs to edges or to views: the share of (edge, view) with an end more
  than 0.4 px off, and the same share in another view of an edge given one, where no other
  true edge runs alongside within 3 px (`disturbed_share`, `disturbed_view_prob`) and where
  one does (`crowded_share`, `crowded_view_prob`); and per segment, the tail's share with and
  without another true edge (or another listed segment) alongside;
- where a segment ends within 6 px of its piece's end, how far past (positive) or short of
  it: `end_noise_px` (robust sigma) and `end_shortfall_px` (the median);
- per piece, how many segments lie along it: the share in two or more (`fragment_prob`) and
  with none; per edge that all three views show, in how many views it was found (misses that
  go together: `faint_share`, `faint_miss_prob`, `miss_prob`);
- the segments of at least 8 px along no visible piece, as a share of those along one
  (`clutter_fraction`).
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
from eval_rooms import request_for  # noqa: E402

NEAR_PX = 1.5
ANGLE_DEG = 4.0
END_NEAR_PX = 6.0
MIN_PIECE_PX = 20.0
MIN_SEGMENT_PX = 8.0
# Grey levels across the edge: the synthetic lists report no edge under this
# (`synth::visibility::MIN_CONTRAST`), so a miss is counted only among the edges above it.
MIN_CONTRAST = 4.0
# An end farther than this across its true line is in the offsets' tail.
TAIL_PX = 0.4
# A parallel line this close beside a segment may pull its fit (the matcher's crowding reach).
NEIGHBOUR_PX = 3.0


def project(P, X):
    h = P @ np.append(X, 1.0)
    return h[:2] / h[2] if h[2] > 0 else None


def pieces_of(vis, E, P, cam):
    out = []
    for e in vis["edges"]:
        A, B = E[e["i"], :3], E[e["i"], 3:]
        contrast = (e.get("contrast") or [None] * 3)[cam]
        if contrast is None or contrast < MIN_CONTRAST:
            continue
        for s0, s1 in e["vis"][cam]:
            a, b = project(P, A + s0 * (B - A)), project(P, A + s1 * (B - A))
            if a is None or b is None or np.linalg.norm(b - a) < MIN_PIECE_PX:
                continue
            out.append((a, b, e["i"]))
    return out


def beside(s, others, reach):
    """Whether one of `others` (rows u1 v1 u2 v2) runs alongside segment `s`: parallel within
    ANGLE_DEG, overlapping it along its line, and over the overlap within `reach` px of s's
    line and not on it (> 0.05 px)."""
    p, q = s[:2], s[2:]
    L = np.linalg.norm(q - p)
    t = (q - p) / L
    n = np.array([-t[1], t[0]])
    cos_tol = np.cos(np.radians(ANGLE_DEG))
    for o in others:
        a, b = o[:2], o[2:]
        lo = np.linalg.norm(b - a)
        if lo < 1e-9 or np.allclose(o, s) or abs(t @ (b - a)) / lo < cos_tol:
            continue
        ta, tb = t @ (a - p), t @ (b - p)
        s0, s1 = max(min(ta, tb), 0.0), min(max(ta, tb), L)
        if s0 >= s1:
            continue
        across = [abs(n @ (a + (b - a) * ((x - ta) / (tb - ta)) - p)) for x in (s0, s1)]
        if 0.05 <= max(across) <= reach:
            return True
    return False


def lists_for(cdir, source, binary, work):
    if source == "lsd":
        lsd = json.load(open(os.path.join(cdir, "segments_lsd.json")))
        return [np.asarray(im["segments"], float).reshape(-1, 4) for im in lsd["images"]]
    req = request_for(cdir, {"returnExtracted": True}, True)
    path = os.path.join(work, "req.json")
    json.dump(req, open(path, "w"))
    out = json.loads(subprocess.run([binary, "match", path], check=True,
                                    capture_output=True, text=True).stdout)
    return [np.asarray([[s.get("u1", 0), s.get("v1", 0), s.get("u2", 0), s.get("v2", 0)]
                        for s in l.get("segments", [])], float).reshape(-1, 4)
            for l in out["extracted"]]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--shared", required=True)
    ap.add_argument("--rooms", default="office,lab")
    ap.add_argument("--input", default="lsd", choices=["lsd", "images"])
    ap.add_argument("--bin", default="target/release/trinocular")
    a = ap.parse_args()
    work = tempfile.mkdtemp()
    across, along = [], []
    shift_turn = []  # per segment: the mean of its two ends' offsets and half their difference
    per_piece = []
    tails = []  # per edge found in all three views: the largest |end offset| in each
    tail_crowded = []  # and whether a true edge runs beside it there
    views_covering = []  # per eligible edge of a capture: in how many views a segment lies along it
    n_assigned = n_clutter = 0
    # per assigned segment: (end off by more than TAIL_PX, a listed parallel neighbour beside
    # it, a true edge piece beside its own)
    crowded = []
    cos_tol = np.cos(np.radians(ANGLE_DEG))
    for room in a.rooms.split(","):
        data = os.path.join(a.shared, "data", room)
        E = np.asarray(json.load(open(os.path.join(data, "gt_edges.json")))["edges"], float)
        for cap in sorted(d for d in os.listdir(data) if d.startswith("capture_")):
            cdir = os.path.join(data, cap)
            calib = json.load(open(os.path.join(cdir, "calib_world.json")))
            vis = json.load(open(os.path.join(cdir, "visibility.json")))
            lists = lists_for(cdir, a.input, a.bin, work)
            covered = [set(), set(), set()]
            worst = [dict(), dict(), dict()]
            crowd = [dict(), dict(), dict()]
            for cam, segs in enumerate(lists):
                P = np.asarray(calib["cameras"][cam]["P"], float)
                pieces = pieces_of(vis, E, P, cam)
                counts = np.zeros(len(pieces), int)
                for s in segs:
                    p, q = s[:2], s[2:]
                    length = np.linalg.norm(q - p)
                    if length < MIN_SEGMENT_PX:
                        continue
                    d = (q - p) / length
                    best = None
                    for k, (a_, b_, _) in enumerate(pieces):
                        t = b_ - a_
                        L = np.linalg.norm(t)
                        t = t / L
                        if abs(d @ t) < cos_tol:
                            continue
                        n = np.array([-t[1], t[0]])
                        dp, dq = n @ (p - a_), n @ (q - a_)
                        if max(abs(dp), abs(dq)) > NEAR_PX:
                            continue
                        tp, tq = t @ (p - a_), t @ (q - a_)
                        if min(tp, tq) >= L or max(tp, tq) <= 0:
                            continue
                        score = abs(dp) + abs(dq)
                        if best is None or score < best[0]:
                            best = (score, k, dp, dq, tp, tq, L)
                    if best is None:
                        n_clutter += 1
                        continue
                    n_assigned += 1
                    _, k, dp, dq, tp, tq, L = best
                    crowded.append((max(abs(dp), abs(dq)) > TAIL_PX,
                                    beside(s, segs, NEIGHBOUR_PX),
                                    beside(s, [np.concatenate([a_, b_]) for a_, b_, e_ in pieces
                                               if e_ != pieces[k][2]], NEIGHBOUR_PX)))
                    counts[k] += 1
                    across += [dp, dq]
                    shift_turn.append((0.5 * (dp + dq), 0.5 * (dq - dp), length))
                    edge = pieces[k][2]
                    worst[cam][edge] = max(worst[cam].get(edge, 0.0), abs(dp), abs(dq))
                    crowd[cam][edge] = crowd[cam].get(edge, False) or crowded[-1][2]
                    lo, hi = min(tp, tq), max(tp, tq)
                    if abs(lo) <= END_NEAR_PX:
                        along.append(-lo)  # past the piece's start: positive
                    if abs(hi - L) <= END_NEAR_PX:
                        along.append(hi - L)
                per_piece += list(counts)
                covered[cam] = {pieces[k][2] for k in np.nonzero(counts)[0]}
            for e in vis["edges"]:
                if min(e.get("all3_px") or [0]) >= MIN_PIECE_PX and \
                        min(c if c is not None else 0 for c in (e.get("contrast") or [0])) >= MIN_CONTRAST:
                    views_covering.append(sum(e["i"] in covered[c] for c in range(3)))
                    if all(e["i"] in worst[c] for c in range(3)):
                        tails.append([worst[c][e["i"]] for c in range(3)])
                        tail_crowded.append([crowd[c][e["i"]] for c in range(3)])
    across, along, per_piece = np.asarray(across), np.asarray(along), np.asarray(per_piece)

    def robust(x):
        return 1.4826 * np.median(np.abs(x - np.median(x)))

    print(f"input {a.input}, rooms {a.rooms}: {n_assigned} segments along {len(per_piece)} "
          f"visible pieces of >= {MIN_PIECE_PX:.0f} px and "
          f">= {MIN_CONTRAST:.0f} grey levels")
    print(f"across the line, per end: robust sigma {robust(across):.3f} px, "
          f"|offset| 90th percentile {np.percentile(np.abs(across), 90):.3f} px, "
          f"median {np.median(across):+.3f} px; |offset| percentiles 50/75/90/95/99: "
          + " / ".join(f"{v:.3f}" for v in np.percentile(np.abs(across), [50, 75, 90, 95, 99])))
    st = np.asarray(shift_turn)
    print(f"per segment, the line's shift (mean of its ends' offsets): robust sigma "
          f"{robust(st[:, 0]):.3f} px; its turn (half their difference): {robust(st[:, 1]):.3f} px "
          f"(independent ends give both {robust(across) / np.sqrt(2):.3f})")
    for lo, hi in ((8, 20), (20, 40), (40, 80), (80, 160), (160, 1e9)):
        b = st[(st[:, 2] >= lo) & (st[:, 2] < hi)]
        if len(b) >= 20:
            print(f"  {lo:.0f}-{hi:.0f} px ({len(b)}): shift robust sigma {robust(b[:, 0]):.3f} px, "
                  f"90th pct |shift| {np.percentile(np.abs(b[:, 0]), 90):.3f}; turn {robust(b[:, 1]):.3f} px, "
                  f"90th pct |turn| {np.percentile(np.abs(b[:, 1]), 90):.3f}")
    print(f"along the line, ends within {END_NEAR_PX:.0f} px of the piece's end ({len(along)}): "
          f"robust sigma {robust(along):.3f} px, median {np.median(along):+.3f} px (positive: past it)")
    print(f"pieces with none: {np.mean(per_piece == 0):.3f}; "
          f"of those with some, in two or more: {np.mean(per_piece[per_piece > 0] >= 2):.3f}")
    vc = np.asarray(views_covering)
    print(f"edges visible in all three views ({len(vc)}), found in 0 / 1 / 2 / 3 views: "
          + " / ".join(f"{np.mean(vc == k):.3f}" for k in range(4)))
    tl = np.asarray(tails) > TAIL_PX
    base = tl.mean()
    given = np.mean([tl[i, b] for i in range(len(tl)) for a_ in range(3) for b in range(3)
                     if a_ != b and tl[i, a_]])
    print(f"an end off by more than {TAIL_PX} px, per edge and view: {base:.3f}; in another view "
          f"of the same edge, given one: {given:.3f} ({len(tl)} edges found in all three)")
    tc = np.asarray(tail_crowded, bool)
    free = [(i, a_, b) for i in range(len(tl)) for a_ in range(3) for b in range(3)
            if a_ != b and not tc[i, a_] and not tc[i, b]]
    both = [(i, a_, b) for i in range(len(tl)) for a_ in range(3) for b in range(3)
            if a_ != b and tc[i, a_] and tc[i, b]]
    print(f"  the same where no true edge runs beside either view: per view "
          f"{tl[~tc].mean():.3f}, given one {np.mean([tl[i, b] for i, a_, b in free if tl[i, a_]]):.3f}; "
          f"beside one: per view {tl[tc].mean():.3f}, given one where both are "
          f"{np.mean([tl[i, b] for i, a_, b in both if tl[i, a_]]):.3f} "
          f"({np.mean(tc):.3f} of the views)")
    cr = np.asarray(crowded, bool)
    for name, col in (("a listed parallel segment", 1), ("another true edge", 2)):
        w = cr[:, col]
        print(f"an end off by more than {TAIL_PX} px, per segment: with {name} within "
              f"{NEIGHBOUR_PX:.0f} px ({np.mean(w):.3f} of them) {np.mean(cr[w, 0]):.3f}, "
              f"without {np.mean(cr[~w, 0]):.3f}")
    print(f"segments along no visible piece (clutter): {n_clutter / max(n_assigned, 1):.3f} "
          f"of those along one")


if __name__ == "__main__":
    main()
