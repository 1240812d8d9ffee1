#!/usr/bin/env python3
"""Scores `trinocular match` on the rendered scenes of ../shared/data with ../shared/eval.

    python3 tools/eval_shared.py [--shared ../shared] [--bin target/release/trinocular]
        [--options '{"tolerancePx": 2}'] [--captures 00,01] [--keep DIR] [--images]

For each capture: builds a MatchRequest from calib.json and either segments_lsd.json (LSD
segments, oriented by contrast) or, with --images, the three PNG images (our own extraction),
runs the CLI, writes the 3D segments in the scorer's format, scores
them, and prints per-capture and pooled metrics (pooled: error rate over all segments,
completeness over all eligible length). Needs numpy for the scorer: see ../shared/eval/README.md.
"""
import argparse, base64, json, os, subprocess, sys, tempfile


def request_for(cdir, options, images=False):
    calib = json.load(open(os.path.join(cdir, "calib.json")))
    cams = []
    for c in calib["cameras"]:
        cams.append({"name": c["name"], "width": c["width"], "height": c["height"],
                     "projection": [v for row in c["P"] for v in row]})
    req = {"calibration": {"cameras": cams}}
    if images:
        req["images"] = {"images": [
            {"encoded": base64.b64encode(open(os.path.join(cdir, f"img{i}.png"), "rb").read()).decode()}
            for i in (1, 2, 3)]}
    else:
        lsd = json.load(open(os.path.join(cdir, "segments_lsd.json")))
        lists = [{"oriented": True,
                  "segments": [{"u1": s[0], "v1": s[1], "u2": s[2], "v2": s[3]} for s in im["segments"]]}
                 for im in lsd["images"]]
        req["segments"] = {"lists": lists}
    if options:
        req["options"] = options
    return req


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--shared", default=os.path.join(os.path.dirname(__file__), "..", "..", "shared"))
    ap.add_argument("--bin", default="target/release/trinocular")
    ap.add_argument("--python", default=sys.executable, help="python with numpy, for the scorer")
    ap.add_argument("--options", default=None)
    ap.add_argument("--captures", default=None)
    ap.add_argument("--keep", default=None)
    ap.add_argument("--images", action="store_true", help="match the images, not the LSD segments")
    a = ap.parse_args()
    data = os.path.join(a.shared, "data", "office")
    scorer = os.path.join(a.shared, "eval", "score.py")
    options = json.loads(a.options) if a.options else None
    caps = sorted(d[len("capture_"):] for d in os.listdir(data) if d.startswith("capture_"))
    if a.captures:
        caps = a.captures.split(",")
    work = a.keep or tempfile.mkdtemp()
    os.makedirs(work, exist_ok=True)
    tot_n = tot_c = 0
    tot_len = cov_len = 0.0
    ms = []
    for cap in caps:
        cdir = os.path.join(data, "capture_" + cap)
        req_path = os.path.join(work, f"request_{cap}.json")
        json.dump(request_for(cdir, options, a.images), open(req_path, "w"))
        out = json.loads(subprocess.run([a.bin, "match", req_path], check=True,
                                        capture_output=True, text=True).stdout)
        json.dump(out, open(os.path.join(work, f"response_{cap}.json"), "w"))
        segs = [[s["start"]["x"], s["start"]["y"], s["start"]["z"], s["end"]["x"], s["end"]["y"], s["end"]["z"]]
                for s in out.get("segments3d", [])]
        res_path = os.path.join(work, f"result_{cap}.json")
        json.dump({"segments": segs, "frame": "rig"}, open(res_path, "w"))
        sc = json.loads(subprocess.run([a.python, scorer, data, res_path, "--capture", cap], check=True,
                                       capture_output=True, text=True).stdout)
        st = out.get("stats", {})
        ms.append(st.get("totalMs", 0.0))
        print(f"capture {cap}: n={sc['n_segments']} correct={sc['n_correct']} err={sc['error_rate']} "
              f"compl={sc['completeness']} compl_c10={sc['completeness_contrast10']} "
              f"acc_med_mm={sc.get('acc_median_mm')} in={st.get('segmentsIn')} ms={st.get('totalMs', 0):.2f}")
        tot_n += sc["n_segments"]
        tot_c += sc["n_correct"]
        tot_len += sc["eligible_length_m"]
        cov_len += sc["covered_length_m"]
    print(json.dumps({"captures": len(caps), "segments": tot_n, "correct": tot_c,
                      "error_rate": round(1 - tot_c / tot_n, 4) if tot_n else None,
                      "completeness": round(cov_len / tot_len, 4) if tot_len else None,
                      "median_total_ms": sorted(ms)[len(ms) // 2] if ms else None}))


if __name__ == "__main__":
    main()
