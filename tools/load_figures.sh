#!/usr/bin/env bash
# The service's load figures (issues 4 and 19), all in one run on this machine:
#   1. capacity, closed loop, for segment mode (600 segments/image) and image mode (512x512 PNG
#      triplet): the library in-process (the peer), gRPC, HTTP protobuf and HTTP JSON, run in
#      turn ROUNDS times (peer, gRPC, HTTP, JSON, peer, ...), so that each transport's ratio is
#      taken against the peer of its own round: a run on this machine moves by 5-10% from one
#      minute to the next, and one peer run against one transport run measures that drift as
#      much as the transport. Each row gives the median over the rounds and their range; each
#      ratio the median of the rounds' ratios and their range;
#   2. overload: open loop at 2x the measured gRPC / HTTP saturation rate (the rounds'
#      median), against the unloaded p99 (open loop at half the saturation rate).
# Server and load generator share the machine, so the transports also pay for their client.
#
#   tools/load_figures.sh [SECONDS_PER_RUN] [ROUNDS]   (defaults 10 and 3)
set -euo pipefail
cd "$(dirname "$0")/.."
secs="${1:-10}"
rounds="${2:-3}"
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
for mode in segments600 images512; do
  req="$dir/$mode.json"
  echo "## $mode: closed loop, $concurrency clients, server on $threads threads, $rounds rounds of ${secs} s"
  runs="$dir/$mode.runs"
  : >"$runs"
  for round in $(seq "$rounds"); do
    for t in inproc grpc http json; do
      case $t in
        inproc) out=$(load --target "inproc://$threads" --request "$req" --concurrency $concurrency) ;;
        grpc) out=$(load --target grpc://127.0.0.1:50071 --request "$req" --concurrency $concurrency) ;;
        http) out=$(load --target http://127.0.0.1:8071 --request "$req" --concurrency $concurrency) ;;
        json) out=$(load --target http://127.0.0.1:8071 --request "$req" --concurrency $concurrency --http-json) ;;
      esac
      printf '%s %s %s\n' "$round" "$t" "$out" >>"$runs"
    done
  done
  # One line per run: round, target, the load generator's JSON. Medians over the rounds.
  python3 - "$runs" <<'PY'
import json, statistics, sys
runs = {}
for line in open(sys.argv[1]):
    r, t, d = line.split(" ", 2)
    runs.setdefault(t, {})[int(r)] = json.loads(d)
names = {"inproc": "in-process library", "grpc": "gRPC", "http": "HTTP protobuf", "json": "HTTP JSON"}
med = lambda xs: statistics.median(xs)
print("| target | throughput, median (range) | p50 | p99 | outcomes | / in-process, median of rounds (range) |")
print("|---|---|---|---|---|---|")
for t in ("inproc", "grpc", "http", "json"):
    rs = runs[t]
    tp = [d["throughput_per_s"] for d in rs.values()]
    codes = {}
    for d in rs.values():
        for k, v in dict(d["by_code"]).items():
            codes[k] = codes.get(k, 0) + v
    ratio = ""
    if t != "inproc":
        q = [rs[r]["throughput_per_s"] / runs["inproc"][r]["throughput_per_s"] for r in rs]
        ratio = f"{med(q):.3f} ({min(q):.3f}-{max(q):.3f})"
    print(f"| {names[t]} | {med(tp):.0f}/s ({min(tp):.0f}-{max(tp):.0f}) | "
          f"{med([d['latency_ms']['p50'] for d in rs.values()]):.2f} ms | "
          f"{med([d['latency_ms']['p99'] for d in rs.values()]):.2f} ms | {codes} | {ratio or 1} |")
PY
  sat() { # the rounds' median throughput of a target
    python3 -c "import json,statistics,sys; print(statistics.median(json.loads(l.split(' ',2)[2])['throughput_per_s'] for l in open(sys.argv[1]) if l.split(' ')[1]==sys.argv[2]))" "$runs" "$1"
  }
  echo
  echo "## $mode: overload, open loop at 2x saturation vs unloaded (half saturation)"
  echo "| target | offered | answered | p50 | p99 | outcomes |"
  echo "|---|---|---|---|---|---|"
  for t in grpc http; do
    if [ $t = grpc ]; then target=grpc://127.0.0.1:50071; else target=http://127.0.0.1:8071; fi
    saturation=$(sat $t)
    for factor in 0.5 2; do
      rate=$(python3 -c "print(round($saturation * $factor, 1))")
      rss_before=$(ps -o rss= -p $server)
      out=$(load --target $target --request "$req" --rate "$rate")
      rss_after=$(ps -o rss= -p $server)
      field "$out" "f\"| $t | {$rate:.0f}/s | {d['throughput_per_s']:.0f}/s | {d['latency_ms']['p50']:.2f} ms | {d['latency_ms']['p99']:.2f} ms | {dict(d['by_code'])} (server RSS $rss_before -> $rss_after KiB) |\""
    done
  done
  echo
done
