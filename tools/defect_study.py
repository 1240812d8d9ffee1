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
  (`clutter_fraction`);
- the structure of the offsets (signed toward each segment's brighter side, so lists must be
  oriented): how alike one edge's line is shifted in two views (the correlation of the shifts
  of the longest segment per view, for lines with no other true edge alongside within 3 px and
  for those with one; `shift_shared_px` against `shift_view_px`), by the shorter one's length;
  and, by the distance between the true lines of the nearest other edge alongside within 5 px
  (20 px or longer, overlapping at least 70% of the segment) and by that edge's contrast (the
  same or opposite, from the rendered image), the median shift of the segment's midpoint
  toward it and the robust spread about it (`NEIGHBOUR_SHIFT_OPPOSITE`, `NEIGHBOUR_SHIFT_SAME`).
  Needs Pillow for the images.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np
from PIL import Image

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


NEIGHBOUR_REACH_PX = 5.0
MIN_OVERLAP_SHARE = 0.7


def brighter_normal(image, a, b):
    """The unit normal of the image line a -> b toward its brighter side (grey levels 1.5 px
    either side, median of nine points along it)."""
    d = b - a
    n = np.array([d[1], -d[0]]) / np.linalg.norm(d)
    h, w = image.shape

    def grey(p):
        return image[min(max(int(round(p[1])), 0), h - 1), min(max(int(round(p[0])), 0), w - 1)]
    c = np.median([grey(a + s * d + 1.5 * n) - grey(a + s * d - 1.5 * n) for s in np.linspace(0.1, 0.9, 9)])
    return n if c >= 0 else -n


def nearest_alongside(p, q, a, t, n, pieces, edge):
    """The nearest other edge's piece alongside the segment p-q (assigned to the piece through a
    with direction t, normal n): parallel within ANGLE_DEG, at least MIN_PIECE_PX long,
    overlapping at least MIN_OVERLAP_SHARE of the segment, its line within NEIGHBOUR_REACH_PX
    of the true line at the middle of the overlap. Returns (signed distance along n, (c, e))."""
    sp, sq = sorted((t @ (p - a), t @ (q - a)))
    best = None
    for c, e, other in pieces:
        if other == edge or np.linalg.norm(e - c) < MIN_PIECE_PX:
            continue
        u = (e - c) / np.linalg.norm(e - c)
        if abs(u @ t) < np.cos(np.radians(ANGLE_DEG)):
            continue
        s0, s1 = t @ (c - a), t @ (e - a)
        lo, hi = max(min(s0, s1), sp), min(max(s0, s1), sq)
        if hi - lo < MIN_OVERLAP_SHARE * (sq - sp):
            continue
        at = c + (e - c) * ((0.5 * (lo + hi) - s0) / (s1 - s0))
        dist = n @ (at - a)
        if 0.05 <= abs(dist) <= NEIGHBOUR_REACH_PX and (best is None or abs(dist) < abs(best[0])):
            best = (dist, (c, e))
    return best


def shift_structure(oriented):
    """Prints how alike the views of one edge shift its line: per capture, edge and camera the
    longest segment, paired across cameras."""
    by = {}
    for key, edge, cam, shift, length, crowded in oriented:
        k = (key, edge)
        if cam not in by.setdefault(k, {}) or by[k][cam][1] < length:
            by[k][cam] = (shift, length, crowded)

    def robust(x):
        return 1.4826 * np.median(np.abs(x - np.median(x)))
    for crowded, name in ((False, "alone"), (True, "beside another true edge within 3 px")):
        rows = []
        for views in by.values():
            cams = sorted(views)
            for i in range(len(cams)):
                for j in range(i + 1, len(cams)):
                    x, y = views[cams[i]], views[cams[j]]
                    if x[2] == crowded and y[2] == crowded:
                        rows.append((x[0], y[0], min(x[1], y[1])))
        r = np.asarray(rows)
        if len(r) < 20:
            continue
        x, y = np.clip(r[:, 0], -1, 1), np.clip(r[:, 1], -1, 1)
        print(f"a line's shift toward its brighter side in two views of its edge, {name}: "
              f"{len(r)} pairs, correlation {np.corrcoef(x, y)[0, 1]:.2f}; |shift| percentiles "
              "50/75/90/95/99: " + " / ".join(f"{v:.3f}" for v in np.percentile(np.abs(r[:, :2]), [50, 75, 90, 95, 99])))
        if crowded:
            continue
        for lo, hi in ((8, 30), (30, 60), (60, 120), (120, 1e9)):
            b = r[(r[:, 2] >= lo) & (r[:, 2] < hi)]
            if len(b) < 20:
                continue
            both = robust(np.concatenate([b[:, 0], b[:, 1]]))
            apart = robust(b[:, 0] - b[:, 1]) / np.sqrt(2)
            print(f"  the shorter {lo:.0f}-{hi:.0f} px ({len(b)} pairs): robust sigma {both:.3f} px, "
                  f"of it each view's own {apart:.3f}, shared {np.sqrt(max(both ** 2 - apart ** 2, 0)):.3f}; "
                  f"correlation {np.corrcoef(np.clip(b[:, 0], -1, 1), np.clip(b[:, 1], -1, 1))[0, 1]:.2f}")


def neighbour_table(neighbours):
    r = np.asarray(neighbours, float)
    bins = ((0.0, 1.0), (1.0, 1.5), (1.5, 2.0), (2.0, 2.5), (2.5, 3.0), (3.0, 3.5), (3.5, 4.0), (4.0, 5.0))
    for same, name in ((0, "opposite"), (1, "same")):
        for lo, hi in bins:
            sel = (r[:, 0] == same) & (r[:, 1] >= lo) & (r[:, 1] < hi)
            if sel.sum() < 5:
                continue
            t = r[sel, 2]
            med = np.median(t)
            print(f"beside an edge of {name} contrast {lo:.1f}-{hi:.1f} px away ({sel.sum()}): the midpoint "
                  f"{med:+.2f} px toward it, robust spread {1.4826 * np.median(np.abs(t - med)):.2f}, "
                  f"over 0.4 px off {np.mean(np.abs(t) > 0.4):.2f}")


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
    # per segment: capture key, edge, camera, shift toward its brighter side, length, crowded
    oriented = []
    # per segment with another edge alongside within NEIGHBOUR_REACH_PX: same contrast,
    # distance between the true lines, midpoint's offset toward it
    neighbours = []
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
                image = np.asarray(Image.open(os.path.join(cdir, f"img{cam + 1}.png")).convert("L"), float)
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
                    a_, b_, edge_k = pieces[k]
                    t = (b_ - a_) / np.linalg.norm(b_ - a_)
                    n = np.array([-t[1], t[0]])
                    # The list is oriented: the brighter side is on the left of p -> q.
                    toward_bright = np.sign(n @ np.array([d[1], -d[0]]))
                    oriented.append(((room, cap), edge_k, cam, 0.5 * (dp + dq) * toward_bright,
                                     length, crowded[-1][2]))
                    near = nearest_alongside(p, q, a_, t, n, pieces, edge_k)
                    if near is not None:
                        dist, (c_, e_) = near
                        same = brighter_normal(image, c_, e_) @ brighter_normal(image, a_, b_) > 0
                        mid = n @ (0.5 * (p + q) - a_)
                        neighbours.append((same, abs(dist), mid * np.sign(dist)))
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
                  f"90th / 97th / 99th pct |turn| "
                  + " / ".join(f"{v:.3f}" for v in np.percentile(np.abs(b[:, 1]), [90, 97, 99])))
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
    shift_structure(oriented)
    neighbour_table(neighbours)


if __name__ == "__main__":
    main()
