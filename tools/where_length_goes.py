#!/usr/bin/env python3
"""Where the answer loses the edges its input segments allow, point by point of each edge.

    /tmp/ev/bin/python tools/where_length_goes.py --shared ../shared [--rooms office,lab]
        [--input lsd|images] [--every-match] [--bin target/release/trinocular]

For each capture of the rendered rooms, runs `trinocular match` with `includeUncertain` (and,
from images, `returnExtracted`) and follows every point of every eligible ground-truth edge
(visible in all three cameras, >= 20 px in each; 400 points an edge). A point is *allowed*
when an input segment runs along the edge's projection there in every view (within 1.5 px
and 5 degrees, as tools/oracle_extracted.py counts it), and *covered* when a 3D segment of
the default answer (`--every-match`: of every match) that the shared scorer assigns to this
edge spans it. An allowed point not covered is put in the first class that holds:

  right triplet, ...          the answer has a triplet of three segments along the edge there:
    ends short of here          its 3D segment covers the edge, but not this point (the trim);
    uncertain                   its 3D segment is correct for the edge but the gate doubts it;
    scored to another edge      correct, but the scorer assigns it to another edge within
                                tolerance (a parallel edge a few centimetres away);
    off in direction / position / past the edge's end
                                the scorer's test it fails against this edge (geometry);
  segment taken by ...        a segment along the edge there is in another triplet: one correct
                              for this edge (a fragment's partner), one correct for another
                              edge, or a wrong one (certain or uncertain);
  not matched, ...            none of those segments is in any triplet: one is shorter than
                              20 px, or the edge runs within 15 degrees of the 1-2 epipolar
                              lines in view 1, or neither.

Counted per capture (the scorer pools captures, so the room's completeness is a little
higher than the per-capture "covered"). Prints per room each class's share of the eligible
length. Needs numpy and pillow besides the scorer.
"""
import argparse
import collections
import json
import os
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import eval_rooms as ER  # noqa: E402  (the request builder)

POINTS = 400
ALONG_PX, ALONG_DEG = 1.5, 5.0
SHORT_PX = 20.0
EPIPOLAR_DEG = 15.0


def camera_centre(P):
    _, _, vt = np.linalg.svd(P)
    return vt[-1] / vt[-1][3]


def along_sets(uv, d, segments):
    """Per point of `uv` (the edge's projection, unit direction `d`), the input segments
    (rows u1 v1 u2 v2) that run along it there (within ALONG_PX and ALONG_DEG; also what
    tools/oracle_extracted.py counts as extracted)."""
    sets = [set() for _ in uv]
    for k, (u1, v1, u2, v2) in enumerate(segments):
        s = np.array([u2 - u1, v2 - v1])
        sl = np.linalg.norm(s)
        if sl < 1e-9 or abs(s @ d / sl) < np.cos(np.radians(ALONG_DEG)):
            continue
        w = uv - np.array([u1, v1])
        along = w @ (s / sl)
        across = np.abs(w[:, 0] * s[1] / sl - w[:, 1] * s[0] / sl)
        for i in np.nonzero((along >= 0) & (along <= sl) & (across <= ALONG_PX))[0]:
            sets[i].add(k)
    return sets


def geometry_failure(S, seg, A, B, centre):
    """Which of the scorer's tests (its module `S`: tolerances and distances) the 3D segment
    `seg` (6 numbers) fails against edge AB."""
    p1, p2 = seg[:3], seg[3:]
    eu = (B - A) / np.linalg.norm(B - A)
    su = (p2 - p1) / max(np.linalg.norm(p2 - p1), 1e-12)
    if abs(eu @ su) < np.cos(np.radians(S.ANGLE_DEG)):
        return "off in direction"
    past = False
    for p in (p1, p2, (p1 + p2) / 2):
        tol = max(S.TOL_ABS, S.TOL_REL * np.linalg.norm(p - centre))
        if S.point_line_dist(p[None], A[None], B[None])[0] > tol:
            return "off in position"
        past |= S.point_seg_dist(p[None], A[None], B[None])[0, 0] > tol
    return "past the edge's end" if past else "scored to another edge"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shared", default=os.path.join(os.path.dirname(__file__), "..", "..", "shared"))
    ap.add_argument("--rooms", default="office,lab")
    ap.add_argument("--input", default="lsd", choices=["lsd", "images"])
    ap.add_argument("--every-match", action="store_true",
                    help="count an uncertain segment as covering, as includeUncertain answers")
    ap.add_argument("--bin", default="target/release/trinocular")
    a = ap.parse_args()
    sys.path.insert(0, os.path.join(a.shared, "eval"))
    import score as S  # the shared scorer's own assignment of segments to edges

    work = tempfile.mkdtemp()
    images = a.input == "images"
    options = {"includeUncertain": True}
    if images:
        options["returnExtracted"] = True
    for room in a.rooms.split(","):
        data = os.path.join(a.shared, "data", room)
        E = np.asarray(json.load(open(os.path.join(data, "gt_edges.json")))["edges"], float)
        length = collections.Counter()
        for cap in sorted(d[len("capture_"):] for d in os.listdir(data) if d.startswith("capture_")):
            cdir = os.path.join(data, f"capture_{cap}")
            out = ER.run_capture(a.bin, cdir, options, images, work, f"{room}_{cap}")
            if images:
                lists = [np.array([[s.get(k, 0.0) for k in ("u1", "v1", "u2", "v2")]
                                   for s in l.get("segments", [])], float).reshape(-1, 4)
                         for l in out["extracted"]]
            else:
                lsd = json.load(open(os.path.join(cdir, "segments_lsd.json")))
                lists = [np.array([s[:4] for s in im["segments"]], float).reshape(-1, 4) for im in lsd["images"]]
            pose = json.load(open(os.path.join(cdir, "pose.json")))
            calw = json.load(open(os.path.join(cdir, "calib_world.json")))
            vis = json.load(open(os.path.join(cdir, "visibility.json")))
            T = np.asarray(pose["rig_to_world"], float)
            centre = np.asarray(pose["rig_centre_world"], float)
            segs = out.get("segments3d", [])
            X = np.array([[s["start"].get(k, 0.0) for k in "xyz"] + [s["end"].get(k, 0.0) for k in "xyz"]
                          for s in segs], float).reshape(-1, 6)
            Xw = np.hstack([X[:, :3] @ T[:3, :3].T + T[:3, 3], X[:, 3:] @ T[:3, :3].T + T[:3, 3]])
            assigned = S.match_segments(Xw, E, centre) if len(Xw) else np.zeros(0, int)
            uncertain = [bool(s.get("uncertain", False)) for s in segs]
            triplets = [(t.get("s1", 0), t.get("s2", 0), t.get("s3", 0)) for t in out.get("triplets", [])]
            segment_of = {}
            for si, s in enumerate(segs):
                for t in s.get("triplets") or [s.get("triplet", 0)]:
                    segment_of[t] = si
            users = [collections.defaultdict(list) for _ in range(3)]
            for ti, t in enumerate(triplets):
                for v in range(3):
                    users[v][t[v]].append(ti)
            P = [np.asarray(c["P"], float) for c in calw["cameras"]]
            epipole = P[0] @ camera_centre(P[1])
            epipole = epipole[:2] / epipole[2] if abs(epipole[2]) > 1e-12 else None
            counts = (lambda si: not uncertain[si]) if not a.every_match else (lambda si: True)
            for r in vis["edges"]:
                if not r["all3"] or min(r["all3_px"]) < 20:
                    continue
                j = r["i"]
                A, B = E[j, :3], E[j, 3:]
                ts = np.linspace(0, 1, POINTS)
                step = np.linalg.norm(B - A) / POINTS
                inside = np.zeros(POINTS, bool)
                for lo, hi in r["all3"]:
                    inside |= (ts >= lo) & (ts <= hi)
                Xp = A[None] + (B - A)[None] * ts[:, None]
                along, uvs = [], []
                for v in range(3):
                    h = (P[v] @ np.hstack([Xp, np.ones((POINTS, 1))]).T).T
                    uv = h[:, :2] / h[:, 2:3]
                    d = uv[-1] - uv[0]
                    along.append(along_sets(uv, d / (np.linalg.norm(d) + 1e-12), lists[v]))
                    uvs.append(uv)
                covered = np.zeros(POINTS, bool)
                for si in np.nonzero(assigned == j)[0]:
                    if counts(si):
                        dd = B - A
                        s1, s2 = (Xw[si, :3] - A) @ dd / (dd @ dd), (Xw[si, 3:] - A) @ dd / (dd @ dd)
                        covered |= (ts >= min(s1, s2)) & (ts <= max(s1, s2))
                for i in np.nonzero(inside)[0]:
                    length["eligible"] += step
                    here = [along[v][i] for v in range(3)]
                    if not all(here):
                        continue
                    length["allowed"] += step
                    if covered[i]:
                        length["covered"] += step
                        continue
                    right = [ti for ti, t in enumerate(triplets) if all(t[v] in here[v] for v in range(3))]
                    with3d = [segment_of[ti] for ti in right if ti in segment_of]
                    if with3d:
                        mine = [si for si in with3d if assigned[si] == j]
                        if any(counts(si) for si in mine):
                            length["right triplet, its 3D segment ends short of here"] += step
                        elif mine:
                            length["right triplet, uncertain"] += step
                        else:
                            length["right triplet, " + geometry_failure(S, Xw[with3d[0]], A, B, centre)] += step
                        continue
                    if right:
                        length["right triplet, no 3D segment"] += step
                        continue
                    taken = set()
                    for v in range(3):
                        for k in here[v]:
                            for ti in users[v].get(k, []):
                                si = segment_of.get(ti)
                                if si is None:
                                    taken.add("no 3D segment")
                                elif assigned[si] == j:
                                    taken.add("correct for this edge")
                                elif assigned[si] >= 0:
                                    taken.add("correct for another edge")
                                else:
                                    taken.add("wrong, " + ("uncertain" if uncertain[si] else "certain"))
                    if taken:
                        for kind in ("wrong, certain", "wrong, uncertain", "correct for another edge",
                                     "correct for this edge", "no 3D segment"):
                            if kind in taken:
                                length["segment taken by a triplet " + kind] += step
                                break
                        continue
                    shortest = min(max(np.linalg.norm(lists[v][k][2:] - lists[v][k][:2]) for k in here[v])
                                   for v in range(3))
                    angle = 90.0
                    if epipole is not None:
                        d = uvs[0][-1] - uvs[0][0]
                        e = uvs[0][i] - epipole
                        angle = np.degrees(np.arccos(min(1.0, abs(e @ d) / (np.linalg.norm(e) * np.linalg.norm(d) + 1e-12))))
                    if shortest < SHORT_PX:
                        length["not matched, shorter than 20 px in a view"] += step
                    elif angle < EPIPOLAR_DEG:
                        length["not matched, along the 1-2 epipolar lines"] += step
                    else:
                        length["not matched, other"] += step
        eligible = length.pop("eligible")
        print(f"{room} ({a.input}{', every match' if a.every_match else ''}), share of the eligible length, per capture:")
        for key in ["allowed", "covered"] + sorted(k for k in length if k not in ("allowed", "covered")):
            print(f"  {key:58s} {100 * length[key] / eligible:6.2f}%")


if __name__ == "__main__":
    main()
