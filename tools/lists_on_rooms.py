#!/usr/bin/env python3
"""The synthetic rooms' list defects applied to the shared rooms' own edges: what a defect model
costs the matcher on the very geometry where OpenCV LSD's real lists were measured.

    python tools/lists_on_rooms.py --shared PATH --out DIR [--model exact|realistic|independent]
        [--seed N] [--no-misses] [--no-fragments] [--no-ends] [--no-clutter]

then score DIR like the shared tree (its `segments_lsd.json` are the lists made here):

    python tools/eval_rooms.py --shared DIR --input lsd
    python tools/defect_study.py --shared DIR --input lsd

Run with a Python that has numpy and Pillow. DIR mirrors PATH (symbolic links) but for each
capture's `segments_lsd.json`. Per capture and camera, every visible interval of a ground-truth
edge (`visibility.json`, projected with `calib_world.json`) of 8 px or more and 4 grey levels or
more is an exact segment, oriented by the rendered image (grey levels 1.5 px either side, median
of nine points along it); collinear duplicates (two boxes' edges on one line) are one segment.
Then, `--model`:

- `exact`: nothing more;
- `realistic`: `synth::Defects::realistic()` (crates/synth/src/defects.rs), its figures repeated
  here: of two segments of the same contrast alongside within 3 px only the longer is listed
  (LSD grows one region over both); a line's shift toward its brighter side shared by the edge's views (0.035 px) and each
  view's own (0.06 px) and its turn (0.085 px), these for 25 px and as 1/sqrt(length); the nearest
  other edge alongside within 5 px moves it as `NEIGHBOUR_SHIFT_OPPOSITE` / `NEIGHBOUR_SHIFT_SAME`
  say (times the share of the line it runs beside, the spread the edge's own, a further turn of
  0.4 of the shift per view, as 1/sqrt(length) beyond 60 px); 7% of the edges disturbed where nothing runs alongside within 3 px
  (in each such view with probability 0.47: shifted by the edge's own 0.4 px and the view's
  0.15 px, turned by 0.4 px, as 1/sqrt(length) beyond 60 px);
- `independent`: the generator's model before 2026-12-07 (each end on its own at 0.12 px; where
  another edge runs alongside within 3 px, 85% of the edges at 0.65 px; elsewhere one edge in ten
  disturbed, each view with probability 0.47, at 0.65 px; one edge in seven faint);

and for both, what `realistic()` adds (each can be left out): faint edges (one in eleven)
missed in each view with probability 0.85, the others with 0.015; 7% of the segments in 2-3 pieces with gaps of
2-10 px; ends 1 px short with 0.7 px along; 18% clutter (10-80 px, anywhere, any direction).

The candidates differ from the generator's in two ways, both in the rooms' favour: an edge's
contrast runs are not cut where its contrast changes sign (the rooms give no scene to trace), and
its orientation is read from the rendered image rather than the scene.
"""
import argparse
import json
import os
import sys

import numpy as np
from PIL import Image

sys.path.insert(0, os.path.dirname(__file__))
from defect_study import beside  # noqa: E402

MIN_PX = 8.0
MIN_CONTRAST = 4.0
REFERENCE_PX = 25.0
TAIL_TURN_REFERENCE_PX = 60.0  # synth::defects::TAIL_TURN_REFERENCE_PX
CROWDING_PX = 3.0
MERGE_PX = 3.0
NEIGHBOUR_REACH_PX = 5.0
MIN_NEIGHBOUR_PX = 20.0
PARALLEL_COS = np.cos(np.radians(4.0))
# (distance between the true lines px, median shift toward the neighbour px, robust spread px):
# crates/synth/src/defects.rs, measured by tools/defect_study.py on LSD's lists.
NEIGHBOUR_SHIFT_OPPOSITE = [(0.5, -0.78, 0.13), (1.25, -0.55, 0.20), (1.75, -0.49, 0.13),
                            (2.25, -0.29, 0.16), (2.75, -0.22, 0.07), (3.25, -0.16, 0.05),
                            (3.75, -0.07, 0.06), (4.5, -0.03, 0.07), (5.0, 0.0, 0.0)]
NEIGHBOUR_SHIFT_SAME = [(0.5, -0.16, 0.20), (1.25, -0.21, 0.15), (1.75, -0.24, 0.26),
                        (2.25, 0.48, 0.24), (2.75, 0.49, 0.34), (3.25, 0.41, 0.30),
                        (3.75, 0.31, 0.46), (4.5, 0.04, 0.12), (5.0, 0.0, 0.0)]


def mirror(src, dst, skip=()):
    os.makedirs(dst, exist_ok=True)
    for f in os.listdir(src):
        if f not in skip and not os.path.lexists(os.path.join(dst, f)):
            os.symlink(os.path.join(src, f), os.path.join(dst, f))


def exact_segments(cdir, E, cam):
    """Exact oriented segments of one view: (brighter-left start, end, edge index)."""
    calib = json.load(open(os.path.join(cdir, "calib_world.json")))
    vis = json.load(open(os.path.join(cdir, "visibility.json")))
    P = np.asarray(calib["cameras"][cam]["P"], float)
    image = np.asarray(Image.open(os.path.join(cdir, f"img{cam + 1}.png")).convert("L"), float)
    h, w = image.shape

    def grey(p):
        return image[min(max(int(round(p[1])), 0), h - 1), min(max(int(round(p[0])), 0), w - 1)]
    segs = []
    for r in vis["edges"]:
        A, B = E[r["i"], :3], E[r["i"], 3:]
        for lo, hi in r["vis"][cam]:
            pa, pb = P @ np.append(A + lo * (B - A), 1), P @ np.append(A + hi * (B - A), 1)
            if pa[2] <= 0 or pb[2] <= 0:
                continue
            pa, pb = pa[:2] / pa[2], pb[:2] / pb[2]
            d = pb - pa
            length = np.linalg.norm(d)
            if length < MIN_PX:
                continue
            n = np.array([d[1], -d[0]]) / length
            c = np.median([grey(pa + s * d + 1.5 * n) - grey(pa + s * d - 1.5 * n)
                           for s in np.linspace(0.1, 0.9, 9)])
            if abs(c) < MIN_CONTRAST:
                continue
            segs.append((pa, pb, r["i"]) if c > 0 else (pb, pa, r["i"]))
    # Collinear duplicates: the first of each group, extended over the others.
    kept, used = [], [False] * len(segs)
    for i, (a, b, e) in enumerate(segs):
        if used[i]:
            continue
        u = (b - a) / np.linalg.norm(b - a)
        n = np.array([u[1], -u[0]])
        t0, t1 = 0.0, np.linalg.norm(b - a)
        for j in range(i + 1, len(segs)):
            c, d, _ = segs[j]
            if used[j] or abs((c - a) @ n) > 0.3 or abs((d - a) @ n) > 0.3 or (d - c) @ u <= 0:
                continue
            s0, s1 = (c - a) @ u, (d - a) @ u
            if s0 <= t1 and s1 >= t0:
                t0, t1, used[j] = min(t0, s0), max(t1, s1), True
        kept.append((a + t0 * u, a + t1 * u, e))
    return kept, (w, h)


def merge_same_contrast(segs):
    """`Defects::realistic().merge_same_contrast_px`: of two segments of the same contrast
    alongside within MERGE_PX (parallel within 4 degrees, half or more of the shorter beside
    the longer), only the longer is listed. Returns the indices listed."""
    order = sorted(range(len(segs)), key=lambda k: -np.linalg.norm(segs[k][1] - segs[k][0]))
    kept = []
    for k in order:
        p, q, _ = segs[k]
        ls = np.linalg.norm(q - p)
        v = (q - p) / ls
        merged = False
        for j in kept:
            a, b, _ = segs[j]
            length = np.linalg.norm(b - a)
            u = (b - a) / length
            if u @ v < PARALLEL_COS:  # oriented: the same contrast runs the same way
                continue
            n = np.array([-u[1], u[0]])
            if abs(n @ (p - a)) > MERGE_PX or abs(n @ (q - a)) > MERGE_PX:
                continue
            s0, s1 = u @ (p - a), u @ (q - a)
            if min(max(s0, s1), length) - max(min(s0, s1), 0.0) >= 0.5 * ls:
                merged = True
                break
        if not merged:
            kept.append(k)
    return sorted(kept)


def neighbour_shift(segs, k):
    """The nearest other edge's segment alongside segment k within NEIGHBOUR_REACH_PX: the
    measured shift toward it and spread (pixels along k's brighter normal), times the share of
    k it runs beside."""
    a, b, e = segs[k]
    length = np.linalg.norm(b - a)
    u = (b - a) / length
    n = np.array([u[1], -u[0]])
    best = None
    for c, d, f in segs:
        lo_ = np.linalg.norm(d - c)
        if f == e or lo_ < MIN_NEIGHBOUR_PX:
            continue
        facing = np.array([(d - c)[1], -(d - c)[0]]) / lo_ @ n
        if abs(facing) < PARALLEL_COS:
            continue
        s0, s1 = u @ (c - a), u @ (d - a)
        lo, hi = max(min(s0, s1), 0.0), min(max(s0, s1), length)
        if hi <= lo:
            continue
        at = c + (d - c) * ((0.5 * (lo + hi) - s0) / (s1 - s0))
        across = n @ (at - a)
        if 0.05 <= abs(across) < NEIGHBOUR_REACH_PX and (best is None or abs(across) < abs(best[0])):
            best = (across, facing > 0, (hi - lo) / length)
    if best is None:
        return 0.0, 0.0
    across, same, share = best
    table = np.asarray(NEIGHBOUR_SHIFT_SAME if same else NEIGHBOUR_SHIFT_OPPOSITE)
    toward = np.interp(abs(across), table[:, 0], table[:, 1])
    spread = np.interp(abs(across), table[:, 0], table[:, 2])
    return np.sign(across) * toward * share, spread * share


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--shared", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--model", default="realistic", choices=["exact", "realistic", "independent"])
    ap.add_argument("--seed", type=int, default=1)
    for defect in ("misses", "fragments", "ends", "clutter"):
        ap.add_argument(f"--no-{defect}", action="store_true")
    a = ap.parse_args()
    rng = np.random.default_rng(a.seed)
    defects = a.model != "exact"
    mirror(a.shared, a.out, skip=("data",))
    for room in ("office", "lab"):
        rdir, odir = os.path.join(a.shared, "data", room), os.path.join(a.out, "data", room)
        mirror(rdir, odir, skip=[f for f in os.listdir(rdir) if f.startswith("capture_")])
        E = np.asarray(json.load(open(os.path.join(rdir, "gt_edges.json")))["edges"], float)
        for cap in sorted(f for f in os.listdir(rdir) if f.startswith("capture_")):
            cdir, out = os.path.join(rdir, cap), os.path.join(odir, cap)
            mirror(cdir, out, skip=("segments_lsd.json",))
            traits = {}
            images = []
            for cam in range(3):
                segs, (w, h) = exact_segments(cdir, E, cam)
                # Neighbours move a line whether or not they are listed apart.
                shifts = {k: neighbour_shift(segs, k) for k in range(len(segs))} if a.model == "realistic" else {}
                crowding = {k: beside(np.concatenate([segs[k][0], segs[k][1]]),
                                      [np.concatenate([s[0], s[1]]) for s in segs if s[2] != segs[k][2]
                                       and np.linalg.norm(s[1] - s[0]) >= MIN_NEIGHBOUR_PX], CROWDING_PX)
                            for k in range(len(segs))} if defects else {}
                order = list(range(len(segs)))
                if a.model == "realistic":
                    order = merge_same_contrast(segs)
                listed = []
                for k in order:
                    p0, q0, e = segs[k]
                    t = traits.setdefault(e, dict(
                        faint=rng.random() < (0.09 if a.model == "realistic" else 0.14),
                        disturbed=rng.random() < (0.07 if a.model == "realistic" else 0.1),
                        pulled=rng.random() < 0.85, shift=rng.normal(), neighbour=rng.normal(),
                        disturbance=rng.normal()))
                    if not defects:
                        listed.append([*p0, *q0])
                        continue
                    if not a.no_misses and rng.random() < (0.85 if t["faint"] else 0.015):
                        continue
                    crowded = crowding[k]
                    length = np.linalg.norm(q0 - p0)
                    pieces = [(p0, q0)]
                    if not a.no_fragments and rng.random() < 0.07:
                        m = 2 + rng.integers(2)
                        gaps = rng.uniform(2, 10, m - 1)
                        rest = length - gaps.sum()
                        if rest >= m * MIN_PX:
                            wts = rng.uniform(0.5, 1.5, m)
                            sizes = rest * wts / wts.sum()
                            if (sizes < MIN_PX).any():
                                sizes = np.full(m, rest / m)
                            u = (q0 - p0) / length
                            at, pieces = 0.0, []
                            for j in range(m):
                                pieces.append((p0 + at * u, p0 + (at + sizes[j]) * u))
                                at += sizes[j] + (gaps[j] if j < m - 1 else 0.0)
                    toward, spread = shifts.get(k, (0.0, 0.0))
                    for p, q in pieces:
                        piece = np.linalg.norm(q - p)
                        u = (q - p) / piece
                        bright = np.array([u[1], -u[0]])
                        if a.model == "realistic":
                            scale = np.sqrt(REFERENCE_PX / piece)
                            tail = min(1.0, np.sqrt(TAIL_TURN_REFERENCE_PX / piece))
                            if not crowded and t["disturbed"] and rng.random() < 0.47:
                                shift = 0.4 * t["disturbance"] + rng.normal(0, 0.15)
                                turn = rng.normal(0, 0.4 * tail)
                            else:
                                pushed = toward + spread * t["neighbour"]
                                shift = 0.035 * scale * t["shift"] + rng.normal(0, 0.06 * scale) + pushed
                                turn = rng.normal(0, 0.085 * scale) + rng.normal(0, 0.4 * abs(pushed) * tail)
                            off_p, off_q = shift - turn, shift + turn
                        else:
                            pulled = t["pulled"] if crowded else (t["disturbed"] and rng.random() < 0.47)
                            sigma = 0.65 if pulled else 0.12
                            off_p, off_q = rng.normal(0, sigma), rng.normal(0, sigma)
                        short, noise = (0.0, 0.0) if a.no_ends else (1.0, 0.7)
                        p2 = p + u * (short + rng.normal(0, noise) if noise else short) + bright * off_p
                        q2 = q - u * (short + rng.normal(0, noise) if noise else short) + bright * off_q
                        p2 = np.clip(p2, -0.5, [w - 0.5, h - 0.5])
                        q2 = np.clip(q2, -0.5, [w - 0.5, h - 0.5])
                        if np.linalg.norm(q2 - p2) >= MIN_PX:
                            listed.append([*p2, *q2])
                if defects and not a.no_clutter:
                    for _ in range(int(round(0.18 * len(listed)))):
                        length, angle = rng.uniform(10, 80), rng.uniform(0, 2 * np.pi)
                        s = np.array([rng.uniform(-0.5, w - 0.5), rng.uniform(-0.5, h - 0.5)])
                        e = np.clip(s + length * np.array([np.cos(angle), np.sin(angle)]), -0.5, [w - 0.5, h - 0.5])
                        listed.append([*s, *e])
                images.append({"name": f"img{cam + 1}.png",
                               "segments": [[round(float(x), 4) for x in s] for s in listed]})
            json.dump({"detector": f"tools/lists_on_rooms.py --model {a.model} --seed {a.seed}",
                       "images": images}, open(os.path.join(out, "segments_lsd.json"), "w"))
    print(f"written {a.out}")


if __name__ == "__main__":
    main()
