#!/usr/bin/env python3
"""Matches the three images of `trinocular demo --out demo`.

    trinocular demo --out demo && trinocular serve --store memory &
    python examples/match_demo.py [--server localhost:50051] [--demo demo]
"""

import argparse
from pathlib import Path

import numpy as np

from trinocular import Client, TrinocularError


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--server", default="localhost:50051", help="gRPC address")
    ap.add_argument("--demo", default="demo", type=Path, help="output folder of `trinocular demo`")
    args = ap.parse_args()

    images = [args.demo / f"img{i}.png" for i in (1, 2, 3)]
    with Client(args.server, timeout=30) as client:
        try:
            r = client.match_images(args.demo / "calibration.json", *images,
                                    options={"returnExtracted": True})
        except TrinocularError as e:
            print(f"error: {e} (field: {e.field})")
            return 1
    print(f"extracted {[len(e) for e in r.extracted]} segments, "
          f"{len(r.triplets)} triplets, {len(r.segments_3d)} 3D segments "
          f"in {r.stats.get('totalMs', 0):.1f} ms")
    if len(r.segments_3d):
        lengths = np.linalg.norm(r.segments_3d[:, 1] - r.segments_3d[:, 0], axis=1)
        print(f"total 3D length {lengths.sum():.2f} m, median residual {np.median(r.residual_px):.3f} px")
        for (a, b), res in list(zip(r.segments_3d, r.residual_px))[:5]:
            print(f"  ({a[0]:+.3f} {a[1]:+.3f} {a[2]:+.3f}) -> ({b[0]:+.3f} {b[1]:+.3f} {b[2]:+.3f})  {res:.2f} px")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
