#!/usr/bin/env python3
"""Time OpenCV's line segment detector and Canny as peers for our extractor.

Setup (once):
    python3 -m venv /tmp/cv && /tmp/cv/bin/pip install opencv-python-headless numpy

Run (from the repo root):
    /tmp/cv/bin/python tools/peer_opencv.py IMG [IMG ...] [--repeat N] [--json]
        [--size 1024] [--low 20] [--high 50]

OpenCV is forced to ONE thread (cv2.setNumThreads(1)) so the numbers compare
with a single-threaded extractor.

Per image (loaded as 8-bit grey, optionally resized to SIZE x SIZE with
INTER_LINEAR), after 3 warm-up runs, the MEDIAN over N repeats (default 30,
time.perf_counter) of:
  lsd         cv2.createLineSegmentDetector().detect(img)   (LSD; OpenCV 4.5.1+
              restored it after its removal in 3.4.6-4.5.0). If it is absent
              the fallback is cv2.ximgproc.createFastLineDetector() from
              opencv-contrib-python-headless (install that *instead of*
              opencv-python-headless); the output then says "FLD", not LSD.
  blur+canny  cv2.GaussianBlur(img, (0,0), 1.0) then cv2.Canny(blurred, low, high),
              timed together (thresholds on the blurred 8-bit image).
  canny       cv2.Canny(blurred, low, high) alone.
The detector object is built once, outside the timed region.

--json prints one JSON object per image:
  {"image","width","height","lsd_ms","lsd_segments","blur_canny_ms","canny_ms",
   "opencv_version","threads":1}
(plus "line_detector": "LSD" or "FLD").
"""

import argparse
import json
import statistics
import sys
import time

try:
    import cv2
    import numpy as np
except ImportError:
    sys.exit(
        "cv2/numpy not found: python3 -m venv /tmp/cv && "
        "/tmp/cv/bin/pip install opencv-python-headless numpy, "
        "then run with /tmp/cv/bin/python"
    )

WARMUP = 3


def median_ms(fn, repeat):
    for _ in range(WARMUP):
        fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


def make_line_detector(log):
    """Return (name, detect(img) -> number of segments)."""
    if hasattr(cv2, "createLineSegmentDetector"):
        try:
            lsd = cv2.createLineSegmentDetector()
            # OpenCV 3.4.6-4.5.0 kept the symbol but threw on use: probe it.
            lsd.detect(np.zeros((16, 16), np.uint8))

            def run(img):
                lines = lsd.detect(img)[0]
                return 0 if lines is None else len(lines)

            return "LSD", run
        except cv2.error as e:
            log(f"LSD is NOT available in OpenCV {cv2.__version__}: {e}")
    else:
        log(f"LSD is NOT available in OpenCV {cv2.__version__} "
            "(no cv2.createLineSegmentDetector)")
    if hasattr(cv2, "ximgproc") and hasattr(cv2.ximgproc, "createFastLineDetector"):
        fld = cv2.ximgproc.createFastLineDetector()
        log("falling back to cv2.ximgproc.createFastLineDetector (FLD), "
            "which is NOT LSD")

        def run(img):
            lines = fld.detect(img)
            return 0 if lines is None else len(lines)

        return "FLD", run
    log("no fallback either: install opencv-contrib-python-headless for "
        "cv2.ximgproc.createFastLineDetector; line detector timings skipped")
    return None, None


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("images", nargs="+", metavar="IMG")
    ap.add_argument("--repeat", type=int, default=30, help="timed runs (default 30)")
    ap.add_argument("--json", action="store_true", help="one JSON object per image")
    ap.add_argument("--size", type=int, default=None,
                    help="resize each image to SIZE x SIZE (INTER_LINEAR) first")
    ap.add_argument("--low", type=float, default=20, help="Canny low threshold (20)")
    ap.add_argument("--high", type=float, default=50, help="Canny high threshold (50)")
    args = ap.parse_args()
    if args.repeat < 1:
        ap.error("--repeat must be >= 1")

    def log(msg):
        # Notes go to stderr under --json so stdout stays JSON lines.
        print(msg, file=sys.stderr if args.json else sys.stdout)

    cv2.setNumThreads(1)
    log(f"OpenCV {cv2.__version__}, cv2.setNumThreads(1) -> "
        f"getNumThreads()={cv2.getNumThreads()}; {WARMUP} warm-ups, "
        f"median of {args.repeat} runs; Canny low={args.low:g} high={args.high:g}")
    det_name, det = make_line_detector(log)

    rows = []
    for path in args.images:
        img = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        if img is None:
            sys.exit(f"cannot read image: {path}")
        if args.size:
            img = cv2.resize(img, (args.size, args.size), interpolation=cv2.INTER_LINEAR)
        h, w = img.shape[:2]

        def blur():
            return cv2.GaussianBlur(img, (0, 0), 1.0)

        blurred = blur()
        row = {
            "image": path,
            "width": w,
            "height": h,
            "lsd_ms": None,
            "lsd_segments": None,
            "blur_canny_ms": median_ms(
                lambda: cv2.Canny(blur(), args.low, args.high), args.repeat),
            "canny_ms": median_ms(
                lambda: cv2.Canny(blurred, args.low, args.high), args.repeat),
            "opencv_version": cv2.__version__,
            "threads": 1,
            "line_detector": det_name,
        }
        if det is not None:
            row["lsd_ms"] = median_ms(lambda: det(img), args.repeat)
            row["lsd_segments"] = det(img)
        rows.append(row)
        if args.json:
            print(json.dumps(row), flush=True)

    if not args.json:
        name = det_name or "LSD"
        iw = max(len("image"), *(len(r["image"]) for r in rows))
        head = (f"{'image':<{iw}} {'size':>9} {name + ' ms':>9} {'segs':>5} "
                f"{'blur+canny ms':>14} {'canny ms':>9}")
        print(head)
        print("-" * len(head))

        def fmt(v):
            return "n/a" if v is None else f"{v:.3f}"

        for r in rows:
            size = f"{r['width']}x{r['height']}"
            print(f"{r['image']:<{iw}} {size:>9} {fmt(r['lsd_ms']):>9} "
                  f"{str(r['lsd_segments']):>5} {fmt(r['blur_canny_ms']):>14} "
                  f"{fmt(r['canny_ms']):>9}")

if __name__ == "__main__":
    main()
