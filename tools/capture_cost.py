#!/usr/bin/env python3
"""AddCapture against a plain Match of the same images, through the service (issue 16's goal:
AddCapture with registration at most 2x a Match of the same input).

    python tools/capture_cost.py --shared ../shared [--room office] [--bin target/release/trinocular]
                                 [--store embedded|memory] [--yaw-noise-deg 1 --xy-noise-m 0.02] [--reps 2]
                                 [--default-covariance] [--lists]

Starts `trinocular serve` on ephemeral-ish local ports (embedded store in a temporary
directory by default: every AddCapture is a durable commit, as in production), creates a
session with the room's calibration and, capture by capture, times a Match of the capture's
three images (or its LSD lists, --lists) and then an AddCapture of the same input (its pose given with N(0, yaw) of
heading and N(0, xy) across the floor, the prior saying so, or the service's default prior
with --default-covariance), both over gRPC. Prints per
capture AddCapture / Match and the totals. Run with a python that has the client installed
(clients/python/run_tests.sh makes one).
"""
import argparse, json, subprocess, sys, tempfile, time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "clients" / "python" / "examples"))
from map_room import shared_to_calibration  # noqa: E402  (the shared rooms' calibration format)
from trinocular import Client  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shared", type=Path, required=True)
    ap.add_argument("--room", default="office")
    ap.add_argument("--bin", default="target/release/trinocular")
    ap.add_argument("--store", default="embedded")
    ap.add_argument("--yaw-noise-deg", type=float, default=1.0)
    ap.add_argument("--xy-noise-m", type=float, default=0.02)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--lists", action="store_true",
                    help="send each capture's OpenCV LSD lists (segments_lsd.json), not its images")
    ap.add_argument("--default-covariance", action="store_true",
                    help="send no rig_to_world_covariance (the service's default odometry: 3 deg, 5 cm)")
    a = ap.parse_args()
    room = a.shared / "data" / a.room
    caps = sorted(d for d in room.iterdir() if d.is_dir() and (d / "pose.json").is_file())
    calibration = shared_to_calibration(caps[0] / "calib.json")
    yaw_sigma, xy_sigma = np.radians(a.yaw_noise_deg), a.xy_noise_m
    covariance = np.diag([1e-6, 1e-6, max(yaw_sigma, 1e-4) ** 2,
                          max(xy_sigma, 1e-3) ** 2, max(xy_sigma, 1e-3) ** 2, 1e-4])
    with tempfile.TemporaryDirectory() as data:
        server = subprocess.Popen([a.bin, "serve", "--grpc-addr", "127.0.0.1:50079",
                                   "--http-addr", "127.0.0.1:8079", "--store", a.store,
                                   "--data-dir", data, "--threads", "2"],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            client = Client("127.0.0.1:50079", timeout=60)
            for _ in range(100):
                try:
                    client.list_sessions()
                    break
                except Exception:
                    time.sleep(0.1)
            rng = np.random.default_rng(a.seed)
            for rep in range(a.reps):
                session = client.create_session(calibration, name="capture cost")
                matched, added = [], []
                for i, d in enumerate(caps):
                    if a.lists:
                        lsd = json.loads((d / "segments_lsd.json").read_text())["images"]
                        lists = [np.array(im["segments"], float).reshape(-1, 4) for im in lsd]
                        given = {"segments": lists, "oriented": True}
                    else:
                        given = {"images": [(d / f"img{k}.png").read_bytes() for k in (1, 2, 3)]}
                    pose = np.array(json.loads((d / "pose.json").read_text())["rig_to_world"], float)
                    if i > 0:
                        yaw = rng.normal(0.0, yaw_sigma)
                        c, s = np.cos(yaw), np.sin(yaw)
                        pose[:3, :3] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ pose[:3, :3]
                        pose[:2, 3] += rng.normal(0.0, xy_sigma, 2)
                    t = time.perf_counter()
                    if a.lists:
                        client.match_segments(calibration, lists, oriented=True)
                    else:
                        client.match_images(calibration, *given["images"])
                    matched.append(time.perf_counter() - t)
                    t = time.perf_counter()
                    client.add_capture(session.id, pose, **given,
                                       rig_to_world_covariance=None if a.default_covariance else covariance)
                    added.append(time.perf_counter() - t)
                client.delete_session(session.id)
                ratios = np.array(added) / np.array(matched)
                print(f"{a.room}, run {rep + 1}: AddCapture / Match per capture "
                      + " ".join(f"{r:.2f}" for r in ratios))
                print(f"{a.room}, run {rep + 1}: Match {1e3 * sum(matched):.0f} ms, AddCapture "
                      f"{1e3 * sum(added):.0f} ms over {len(caps)} captures: {sum(added) / sum(matched):.2f}x "
                      f"(per capture median {np.median(ratios):.2f}x, worst {ratios.max():.2f}x)")
        finally:
            server.terminate()
            server.wait()


if __name__ == "__main__":
    main()
