#!/usr/bin/env python3
"""What our extraction makes possible on ../shared/data: completeness if every extracted segment
were matched and reconstructed perfectly, and where the rest of the edges are lost.

    /tmp/ev/bin/python tools/oracle_extracted.py [--shared ../shared] [--rooms office,lab]
        [--bin target/release/trinocular] [--input images|lsd]

For each capture, runs `trinocular match` on the images with returnExtracted (or, with
`--input lsd`, reads the capture's OpenCV LSD lists, segments_lsd.json), then counts a
point of an eligible ground-truth edge (visible in all three cameras, >= 20 px in each) as
extracted in a view when an extracted segment runs along its projection there (within 1.5 px
and 5 degrees), and reachable when it is extracted in all three. Prints per room the reachable
share of the eligible length (comparable with the scorer's completeness), the shares
extracted in 0, 1, 2 and 3 views, which view is the missing one where two have it, and the
step of grey level across the edge there (the two pixels 2 px either side of its projection,
sampled every 8th point): whether the missing view's image shows the edge at all; and, at
those points, what the missing view extracted nearest them (a segment reaching within 2 px of
the point along itself): nothing within 5 px; a parallel one (within 5 degrees) 1.5-5 px
away (another edge beside it, or two merged); one 5-20 degrees off, or crossing, within
1.5 px; one that ends up to 2 px short; one 1.5-5 px away and not parallel. Needs numpy and
pillow.
"""
import argparse, base64, json, os, subprocess, sys, tempfile

import numpy as np
from PIL import Image

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from where_length_goes import along_sets  # noqa: E402  (what runs along an edge, shared)

ap = argparse.ArgumentParser()
ap.add_argument("--shared", default=os.path.join(os.path.dirname(__file__), "..", "..", "shared"))
ap.add_argument("--rooms", default="office,lab")
ap.add_argument("--bin", default="target/release/trinocular")
ap.add_argument("--input", default="images", choices=["images", "lsd"],
                help="whose segments: our extraction's, or the rooms' OpenCV LSD lists")
args = ap.parse_args()
req_path = os.path.join(tempfile.mkdtemp(), "request.json")
for room in args.rooms.split(","):
    data = os.path.join(args.shared, "data", room)
    E = np.asarray(json.load(open(os.path.join(data, "gt_edges.json")))["edges"], float)
    total = 0.0
    by_views = np.zeros(4)
    missing = np.zeros(3)
    steps = []
    nearest = []  # (distance across, angle) of the nearest extracted segment
    for cap in sorted(d[len("capture_"):] for d in os.listdir(data) if d.startswith("capture_")):
        cdir = f"{data}/capture_{cap}"
        vis = json.load(open(cdir + "/visibility.json"))
        calw = json.load(open(cdir + "/calib_world.json"))
        calib = json.load(open(cdir + "/calib.json"))
        cams = [{"width": c["width"], "height": c["height"], "projection": [v for r in c["P"] for v in r]}
                for c in calib["cameras"]]
        req = {"calibration": {"cameras": cams}, "options": {"returnExtracted": True},
               "images": {"images": [{"encoded": base64.b64encode(open(f"{cdir}/img{i}.png", "rb").read()).decode()}
                                     for i in (1, 2, 3)]}}
        if args.input == "lsd":
            lsd = json.load(open(cdir + "/segments_lsd.json"))
            lists = [[tuple(s[:4]) for s in im["segments"]] for im in lsd["images"]]
        else:
            open(req_path, "w").write(json.dumps(req))
            out = json.loads(subprocess.run([args.bin, "match", req_path], capture_output=True, text=True,
                                            check=True).stdout)
            lists = [[(s["u1"], s["v1"], s["u2"], s["v2"]) for s in l.get("segments", [])] for l in out["extracted"]]
        P = [np.asarray(c["P"]) for c in calw["cameras"]]
        images = [np.asarray(Image.open(f"{cdir}/img{i}.png").convert("L"), float) for i in (1, 2, 3)]
        for r in vis["edges"]:
            if not r["all3"] or min(r["all3_px"]) < 20:
                continue
            A, B = E[r["i"], :3], E[r["i"], 3:]
            L = np.linalg.norm(B - A)
            ts = np.linspace(0, 1, 400)
            inside = np.zeros_like(ts, bool)
            for a, b in r["all3"]:
                inside |= (ts >= a) & (ts <= b)
            views = np.zeros(len(ts), int)
            per_view = []
            for v in range(3):
                X = A[None] + (B - A)[None] * ts[:, None]
                h = (P[v] @ np.hstack([X, np.ones((len(ts), 1))]).T).T
                uv = h[:, :2] / h[:, 2:3]
                d = uv[-1] - uv[0]
                d = d / (np.linalg.norm(d) + 1e-12)
                covered = np.array([bool(s) for s in along_sets(uv, d, lists[v])])
                views += covered
                per_view.append((covered, uv, d))
            total += inside.sum() / len(ts) * L
            for k in range(4):
                by_views[k] += (inside & (views == k)).sum() / len(ts) * L
            two = inside & (views == 2)
            for v, (covered, uv, d) in enumerate(per_view):
                here = two & ~covered
                missing[v] += here.sum() / len(ts) * L
                n = np.array([-d[1], d[0]])
                im = images[v]
                for q in uv[here][::8]:
                    a = np.round(q + 2 * n).astype(int)
                    b = np.round(q - 2 * n).astype(int)
                    if all(0 <= p[1] < im.shape[0] and 0 <= p[0] < im.shape[1] for p in (a, b)):
                        steps.append(abs(im[a[1], a[0]] - im[b[1], b[0]]))
                    best = (99.0, 99.0)
                    for (u1, v1, u2, v2) in lists[v]:
                        s = np.array([u2 - u1, v2 - v1])
                        sl = np.linalg.norm(s)
                        if sl < 1e-9:
                            continue
                        w = q - np.array([u1, v1])
                        along = w @ (s / sl)
                        if along < -2 or along > sl + 2:
                            continue
                        across = abs(w[0] * s[1] / sl - w[1] * s[0] / sl)
                        if across < best[0]:
                            best = (across, np.degrees(np.arccos(min(1.0, abs(np.dot(s / sl, d))))))
                    nearest.append(best)
    steps = np.array(steps)
    D = np.array(nearest)
    far, ang = D[:, 0], D[:, 1]
    classes = {
        "nothing within 5 px": far >= 5,
        "parallel, 1.5-5 px away": (far >= 1.5) & (far < 5) & (ang < 5),
        "not parallel, 1.5-5 px away": (far >= 1.5) & (far < 5) & (ang >= 5),
        "within 1.5 px, 5-20 deg off": (far < 1.5) & (ang >= 5) & (ang < 20),
        "within 1.5 px, crossing": (far < 1.5) & (ang >= 20),
        "within 1.5 px and parallel, ending short": (far < 1.5) & (ang < 5),
    }
    print(f"{room}: oracle completeness from extracted segments {by_views[3] / total:.3f}; "
          f"extracted in 0/1/2/3 views {np.round(by_views / total, 3).tolist()}; "
          f"in two, the missing one view 1/2/3 {np.round(missing / total, 3).tolist()}; "
          f"step across the edge there, grey levels, quantiles 10/25/50/75/90 "
          f"{np.percentile(steps, [10, 25, 50, 75, 90]).round(1).tolist()}, over 10: {np.mean(steps > 10):.2f}; "
          "nearest extracted there: " + ", ".join(f"{k} {np.mean(v):.2f}" for k, v in classes.items()))
