#!/usr/bin/env bash
# The service's load figures (issue 4's goals), all in one run on this machine:
#   1. capacity, closed loop, for segment mode (600 segments/image) and image mode (512x512 PNG
#      triplet): the library in-process (the peer), gRPC, HTTP protobuf and HTTP JSON;
#   2. overload: open loop at 2x the measured gRPC / HTTP saturation rate, against the unloaded
#      p99 (open loop at half the saturation rate).
# Server and load generator share the machine, so the transports also pay for their client.
#
#   tools/load_figures.sh [SECONDS_PER_RUN]   (default 10)
set -euo pipefail
cd "$(dirname "$0")/.."
secs="${1:-10}"
threads=2
concurrency=4
dir="$(mktemp -d)"
trap 'kill $server 2>/dev/null || true; rm -rf "$dir"' EXIT
cargo build --release --quiet --bin trinocular -p trinocular -p trinocular-loadgen --examples
cargo run --release --quiet --example load_requests -- "$dir" >/dev/null
./target/release/trinocular serve --threads "$threads" --grpc-addr 127.0.0.1:50071 \
  --http-addr 127.0.0.1:8071 >"$dir/server.log" 2>&1 &
server=$!
for _ in $(seq 100); do curl -sf localhost:8071/readyz >/dev/null && break; sleep 0.1; done
load() { ./target/release/trinocular-loadgen --json --duration-s "$secs" "$@"; }
field() { python3 -c "import json,sys; d=json.loads(sys.argv[1]); print($2)" "$1"; }
row() { # name json
  field "$2" "f\"| $1 | {d['throughput_per_s']:.0f}/s | {d['latency_ms']['p50']:.2f} ms | {d['latency_ms']['p99']:.2f} ms | {dict(d['by_code'])} |\""
}
for mode in segments600 images512; do
  req="$dir/$mode.json"
  echo "## $mode: closed loop, $concurrency clients, server on $threads threads"
  echo "| target | throughput | p50 | p99 | outcomes |"
  echo "|---|---|---|---|---|"
  inproc=$(load --target "inproc://$threads" --request "$req" --concurrency $concurrency)
  grpc=$(load --target grpc://127.0.0.1:50071 --request "$req" --concurrency $concurrency)
  http=$(load --target http://127.0.0.1:8071 --request "$req" --concurrency $concurrency)
  json=$(load --target http://127.0.0.1:8071 --request "$req" --concurrency $concurrency --http-json)
  row "in-process library" "$inproc"; row "gRPC" "$grpc"; row "HTTP protobuf" "$http"; row "HTTP JSON" "$json"
  base=$(field "$inproc" "d['throughput_per_s']")
  for t in grpc http json; do
    echo "- $t / in-process: $(field "${!t}" "round(d['throughput_per_s'] / $base, 3)")"
  done
  echo
  echo "## $mode: overload, open loop at 2x saturation vs unloaded (half saturation)"
  echo "| target | offered | answered | p50 | p99 | outcomes |"
  echo "|---|---|---|---|---|---|"
  for t in grpc http; do
    if [ $t = grpc ]; then target=grpc://127.0.0.1:50071; else target=http://127.0.0.1:8071; fi
    sat=$(field "${!t}" "d['throughput_per_s']")
    for factor in 0.5 2; do
      rate=$(python3 -c "print(round($sat * $factor, 1))")
      rss_before=$(ps -o rss= -p $server)
      out=$(load --target $target --request "$req" --rate "$rate")
      rss_after=$(ps -o rss= -p $server)
      field "$out" "f\"| $t | {$rate:.0f}/s | {d['throughput_per_s']:.0f}/s | {d['latency_ms']['p50']:.2f} ms | {d['latency_ms']['p99']:.2f} ms | {dict(d['by_code'])} (server RSS $rss_before -> $rss_after KiB) |\""
    done
  done
  echo
done
