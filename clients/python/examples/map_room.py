#!/usr/bin/env python3
"""Fuses a folder of captures into a map of the room.

FOLDER holds one capture per subfolder (or img1..3.png + pose.json directly in FOLDER for a
single capture): img1.png img2.png img3.png and pose.json {"rig_to_world": 4x4}. The rig's
calibration is FOLDER/calibration.json (a proto3-JSON Calibration), or, with
--calib-format shared, each capture's calib.json with cameras[i].P as 3x4 rows (the format
of ../shared/data/office; the first capture's is used).

    python examples/map_room.py /work/shared/data/office --calib-format shared \
        --server localhost:50051 --http localhost:8080 --out map.png
"""

import argparse
import json
import re
import sys
import urllib.request
from pathlib import Path

from trinocular import Client, TrinocularError


def shared_to_calibration(path: Path) -> dict:
    """cameras[i].P (3x4 rows) + width/height → a Calibration in proto3 JSON."""
    data = json.loads(path.read_text())
    cams = []
    for i, c in enumerate(data["cameras"]):
        P = [float(x) for row in c["P"] for x in row]
        cam = {"name": c.get("name", f"cam{i + 1}"), "width": c["width"], "height": c["height"],
               "projection": P}
        cams.append(cam)
    return {"cameras": cams}


def captures(folder: Path):
    dirs = sorted(d for d in folder.iterdir() if d.is_dir() and (d / "pose.json").is_file())
    if not dirs and (folder / "pose.json").is_file():
        dirs = [folder]
    return dirs


def save_top_view(client, http: str, session_id: str, out: Path) -> str:
    url = f"http://{http}/v1/sessions/{session_id}/map?format=png"
    try:
        with urllib.request.urlopen(url, timeout=60) as r:
            out.write_bytes(r.read())
        return f"top view from {url}"
    except OSError as e:
        http_error = e
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return f"no top view: HTTP failed ({http_error}) and matplotlib is not installed"
    m = client.get_map(session_id)
    fig, ax = plt.subplots(figsize=(8, 8))
    for a, b in m.segments:
        ax.plot([a[0], b[0]], [a[1], b[1]], "k-", lw=0.6)
    ax.plot(m.poses[:, 0, 3], m.poses[:, 1, 3], "r^")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    fig.savefig(out, dpi=120)
    return f"top view drawn with matplotlib (HTTP failed: {http_error})"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", type=Path)
    ap.add_argument("--server", default="localhost:50051", help="gRPC address")
    ap.add_argument("--http", default="localhost:8080", help="HTTP address (for the PNG top view)")
    ap.add_argument("--calib-format", choices=["proto", "shared"], default=None,
                    help="default: proto if FOLDER/calibration.json exists, else shared")
    ap.add_argument("--min-observations", type=int, default=None)
    ap.add_argument("--out", type=Path, default=Path("map.png"))
    ap.add_argument("--keep", action="store_true", help="do not delete the session at the end")
    args = ap.parse_args()

    caps = captures(args.folder)
    if not caps:
        print(f"no captures (pose.json) under {args.folder}", file=sys.stderr)
        return 2
    fmt = args.calib_format or ("proto" if (args.folder / "calibration.json").is_file() else "shared")
    if fmt == "proto":
        calibration = args.folder / "calibration.json"
    else:
        calibration = shared_to_calibration(caps[0] / "calib.json")

    with Client(args.server, timeout=120) as client:
        try:
            s = client.create_session(calibration, name=args.folder.name,
                                      min_observations=args.min_observations)
            print(f"session {s.id}")
            for d in caps:
                pose = json.loads((d / "pose.json").read_text())["rig_to_world"]
                # Named by its folder, so that a capture whose answer is lost is sent again
                # safely: stored once (CaptureResult.duplicate says it was already there).
                name = re.sub(r"[^!-~]", "_", d.name)[:128]
                r = client.add_capture(s.id, pose, images=[d / f"img{i}.png" for i in (1, 2, 3)],
                                       capture_id=name, retries=3)
                again = " (already stored)" if r.duplicate else ""
                print(f"  {d.name}: capture {r.capture_index}{again}, "
                      f"{len(r.match.segments_3d)} 3D segments")
            m = client.get_map(s.id)
            print(m.summary())
            print(save_top_view(client, args.http, s.id, args.out), "->", args.out)
            if not args.keep:
                client.delete_session(s.id)
        except TrinocularError as e:
            print(f"error: {e} (field: {e.field})", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
