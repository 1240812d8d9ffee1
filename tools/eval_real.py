#!/usr/bin/env python3
"""Matches a real photograph set of the shared data and checks each 3D segment in the set's
fourth photo with the shared checker (`check_fourth_view.py`, imported through its command
line, not copied).

    python tools/eval_real.py --shared PATH [--set real/herzjesu_p25]
        [--options '{"minGradient": 10}'] [--bin target/release/trinocular]
        [--overlay OUT.png] [--keep DIR] [--json]

Run it with a Python that has numpy and OpenCV (the checker's requirements: see the shared
eval README), e.g.

    python3 -m venv /tmp/realv && /tmp/realv/bin/pip install numpy opencv-python-headless
    cargo build --release && /tmp/realv/bin/python tools/eval_real.py --shared ../shared

The request is the set's calibration.json, its three images and its options.json, with
--options merged over them (so '{"includeUncertain": true}' scores every match). Prints one
line: the checker's counts and confirmed share, the response's segment counts and timing,
and whether the rig was matched in per-pair frames; --overlay draws img4 with the
projections (green confirmed, red contradicted, yellow unclear).
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--shared", required=True, help="the shared directory (data/, eval/)")
    ap.add_argument("--set", default="real/herzjesu_p25", help="set under data/")
    ap.add_argument("--options", default="{}", help="MatchOptions JSON merged over options.json")
    ap.add_argument("--bin", default="target/release/trinocular")
    ap.add_argument("--overlay", help="write the checker's overlay here (PNG)")
    ap.add_argument("--keep", help="keep the request and response in this directory")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args()

    set_dir = os.path.join(args.shared, "data", args.set)
    checker = os.path.join(args.shared, "eval", "check_fourth_view.py")
    options = {}
    options_path = os.path.join(set_dir, "options.json")
    if os.path.exists(options_path):
        options = json.load(open(options_path))
    options.update(json.loads(args.options))

    work = args.keep or tempfile.mkdtemp(prefix="trinocular-real-")
    os.makedirs(work, exist_ok=True)
    options_file = os.path.join(work, "options.json")
    json.dump(options, open(options_file, "w"))
    response_file = os.path.join(work, "response.json")
    images = [os.path.join(set_dir, f"img{i}.png") for i in (1, 2, 3)]
    subprocess.run(
        [args.bin, "match", "--calibration", os.path.join(set_dir, "calibration.json"),
         "--images", *images, "--options", options_file, "-o", response_file],
        check=True)
    check = [sys.executable, checker, response_file, set_dir]
    if args.overlay:
        check += ["--overlay", args.overlay]
    verdict = json.loads(subprocess.run(check, check=True, capture_output=True, text=True)
                         .stdout.strip().splitlines()[-1])
    stats = json.load(open(response_file)).get("stats", {})
    result = {
        "set": args.set,
        "options": options,
        **verdict,
        "segments_in": stats.get("segmentsIn"),
        "uncertain": stats.get("uncertain", 0),
        "per_pair_rectification": stats.get("perPairRectification", False),
        "total_ms": round(stats.get("totalMs", 0.0), 1),
    }
    if args.json:
        print(json.dumps(result))
    else:
        print(f"{args.set} {json.dumps(options)}: {verdict['n']} segments, "
              f"{verdict['confirmed']} confirmed ({100 * verdict['confirmed_share']:.1f}%), "
              f"{verdict['contradicted']} contradicted, {verdict['unclear']} unclear; "
              f"{result['uncertain']} uncertain (left out unless includeUncertain); segments per image "
              f"{result['segments_in']}; per-pair frames {result['per_pair_rectification']}; "
              f"{result['total_ms']} ms")


if __name__ == "__main__":
    main()
