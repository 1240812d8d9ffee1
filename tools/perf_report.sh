#!/usr/bin/env bash
# Issue 19's figures, each beside its peer, measured in one run on this machine, then the
# profile of the slowest stage of a match:
#   1. extraction, one 512x512 and one 1024x1024 image, one thread: ours (criterion median)
#      against OpenCV's GaussianBlur + Canny and OpenCV's LSD (tools/peer_opencv.py, same
#      images), as ratios;
#   2. a whole 512x512 triplet end to end (extract x3, match, reconstruct) on one thread and
#      two, and where its time goes: extraction's stages and the match's, on each
#      (examples/profile_extract.rs);
#   3. match/600 and match/10000 on one thread (criterion medians), per segment;
#   4. the stages of match/600 (medians of `stats` over 2000 runs) and a perf profile of the
#      match: where the time goes by function, and a flame graph SVG when inferno is installed
#      (`cargo install inferno`), written to target/perf/match600.svg;
#   5. with --load: the transports' throughput against the in-process library
#      (tools/load_figures.sh 5).
#
#     tools/perf_report.sh [--load]      # needs python3 (a venv /tmp/cv with OpenCV is made once) and perf
set -euo pipefail
cd "$(dirname "$0")/.."
out=target/perf
mkdir -p "$out"
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
median_ms() { python3 -c "import json,sys; print('%.3f' % (json.load(open(sys.argv[1]))['median']['point_estimate'] / 1e6))" "$1"; }

echo "== building (release)"
cargo build --release --quiet --example bench_images --example profile_match --example profile_extract
./target/release/examples/bench_images "$dir" >/dev/null
cargo bench --quiet --bench extract -- 'extract/|images/512' >/dev/null 2>&1
cargo bench --quiet --bench matching -- 'match/' >/dev/null 2>&1

if [ ! -x /tmp/cv/bin/python ]; then
  python3 -m venv /tmp/cv && /tmp/cv/bin/pip install --quiet opencv-python-headless numpy
fi
/tmp/cv/bin/python tools/peer_opencv.py "$dir/room_512.png" "$dir/room_1024.png" --json >"$dir/opencv.json"

echo
echo "== 1. extraction, one thread (medians, ms)"
echo "| image | ours | OpenCV blur+Canny | ours / Canny (goal <= 1.5) | OpenCV LSD | ours / LSD (goal <= 0.1) |"
echo "|---|---|---|---|---|---|"
for size in 512 1024; do
  ours=$(median_ms "target/criterion/extract/$size/new/estimates.json")
  python3 - "$dir/opencv.json" "$size" "$ours" <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
size, ours = int(sys.argv[2]), float(sys.argv[3])
r = next(r for r in rows if r["width"] == size)
print(f"| {size}x{size} | {ours:.3f} | {r['blur_canny_ms']:.3f} | {ours / r['blur_canny_ms']:.2f} | {r['lsd_ms']:.3f} | {ours / r['lsd_ms']:.3f} |")
PY
done

echo
echo "== 2. a 512x512 triplet end to end (medians, ms)"
for threads in 1 2; do
  echo "- images/512/$threads-threads: $(median_ms "target/criterion/images/512_${threads}-threads/new/estimates.json") ms (goal on two threads: <= 4 ms)"
done
./target/release/examples/profile_extract 512 200 | sed 's/^/- /'

echo
echo "== 3. matching, one thread (medians)"
m600=$(median_ms target/criterion/match/600/new/estimates.json)
m10k=$(median_ms target/criterion/match/10000/new/estimates.json)
python3 -c "
a, b = $m600, $m10k
print(f'- match/600: {a:.3f} ms (goal <= 1 ms), {a / 600 * 1000:.2f} us per segment')
print(f'- match/10000: {b:.3f} ms, {b / 10000 * 1000:.2f} us per segment: {b / 10000 / (a / 600):.2f}x that of match/600 (goal <= 1.3x)')
"

echo
echo "== 4. match/600's stages and the profile of the slowest"
./target/release/examples/profile_match 600 2000
if command -v perf >/dev/null; then
  # DWARF call stacks: the release build keeps no frame pointers, but its unwind tables serve.
  perf record -q -F 999 --call-graph dwarf,16384 -o "$out/match600.data" \
    ./target/release/examples/profile_match 600 300 >/dev/null 2>&1 || true
  echo "where the time goes (inclusive, the core's functions over 3%):"
  perf report -i "$out/match600.data" --children --percent-limit 3 --stdio -g none --sort sym 2>/dev/null |
    grep -E '^ +[0-9].*trinocular_core' | grep -v '(inlined)' | head -15 || true
  if command -v inferno-collapse-perf >/dev/null && command -v inferno-flamegraph >/dev/null; then
    perf script -i "$out/match600.data" 2>/dev/null | inferno-collapse-perf |
      inferno-flamegraph --title "match/600, one thread" >"$out/match600.svg"
    echo "flame graph: $out/match600.svg"
  else
    echo "(no flame graph: cargo install inferno for inferno-collapse-perf and inferno-flamegraph)"
  fi
else
  echo "(no perf: apt-get install linux-perf)"
fi

if [ "${1:-}" = "--load" ]; then
  echo
  echo "== 5. the transports against the in-process library"
  tools/load_figures.sh 5
fi
