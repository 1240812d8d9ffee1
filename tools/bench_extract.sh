#!/usr/bin/env bash
# Extraction speed against its peers, side by side, on the same images, one thread each:
# our extractor and the pure-Rust lsdetect (criterion, benches/extract.rs), OpenCV's LSD and
# GaussianBlur + Canny (tools/peer_opencv.py). Prints criterion medians and OpenCV medians.
#
#     tools/bench_extract.sh            # needs python3; creates /tmp/cv with OpenCV once
set -euo pipefail
cd "$(dirname "$0")/.."
dir=$(mktemp -d)
cargo run --release --quiet --example bench_images -- "$dir" >/dev/null
cargo bench --bench extract -- 'extract/|peer_lsdetect/|images/' >/dev/null 2>&1
echo "criterion medians (ms), one thread unless stated:"
for f in target/criterion/extract/*/new/estimates.json target/criterion/peer_lsdetect/*/new/estimates.json \
         target/criterion/images/*/new/estimates.json; do
  python3 -c "import json,sys; d=json.load(open(sys.argv[1])); p=sys.argv[1].split('/'); print('  %-28s %8.3f' % (p[2]+'/'+p[3], d['median']['point_estimate']/1e6))" "$f"
done
if [ ! -x /tmp/cv/bin/python ]; then
  python3 -m venv /tmp/cv && /tmp/cv/bin/pip install --quiet opencv-python-headless numpy
fi
echo "OpenCV medians (ms), one thread:"
/tmp/cv/bin/python tools/peer_opencv.py "$dir/room_512.png" "$dir/room_1024.png"
rm -rf "$dir"
