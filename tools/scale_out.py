#!/usr/bin/env python3
"""Scale-out on one machine: nginx balancing gRPC and HTTP across three `trinocular serve`
processes that share the local Redis.

    python tools/scale_out.py [--bin target/release/trinocular] [--loadgen target/release/trinocular-loadgen]

Run with a python that has the client installed (clients/python/run_tests.sh makes one).
Checks, failing with exit 1 at the first that does not hold:
  1. the load generator through nginx, gRPC and HTTP: every request answered OK;
  2. one session built through the balancer (its captures spread over the replicas) has the
     same map as the same captures sent to one server;
  3. a replica killed (SIGKILL) while captures stream in through the balancer, each capture
     named (capture_id) and sent again under its name after a transport error until it is
     acknowledged: the clients saw only transport errors (UNAVAILABLE, or INTERNAL for a
     stream the proxy reset when its replica died between a response's headers and its
     trailers), every capture is stored exactly once (the session holds as many captures as
     were acknowledged, each at its own index), and captures went on being acknowledged
     after the kill.
On a 2-core machine this shows that scale-out is correct, not that it adds throughput.
"""
import argparse, os, shutil, signal, socket, subprocess, tempfile, threading, time

import numpy as np

from trinocular import Client, TrinocularError


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_http(port, timeout=20.0):
    import urllib.request
    end = time.time() + timeout
    while time.time() < end:
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/readyz", timeout=1) as r:
                if r.status == 200:
                    return
        except OSError:
            time.sleep(0.05)
    raise SystemExit(f"nothing ready on port {port}")


LOG = []


def check(ok, what):
    print(("ok   " if ok else "FAIL ") + what, flush=True)
    if not ok:
        for path in LOG:
            if os.path.exists(path):
                print(f"--- {path} (last lines)\n" + "".join(open(path).readlines()[-8:]))
        raise SystemExit(1)


def yaw_pose(k):
    a = np.radians(30.0 * k)
    m = np.eye(4)
    m[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    m[:3, 3] = [0.05 * k, 0.0, 0.0]
    return m


def geometry(m):
    rows = [tuple(np.round(s.ravel(), 9)) + (int(o),) for s, o in zip(m.segments, m.observations)]
    return sorted(rows)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", default="target/release/trinocular")
    ap.add_argument("--loadgen", default="target/release/trinocular-loadgen")
    ap.add_argument("--redis", default="redis://127.0.0.1:6379/0")
    a = ap.parse_args()
    if not shutil.which("nginx"):
        raise SystemExit("nginx is needed (Debian: apt-get install nginx-light)")
    work = tempfile.mkdtemp(prefix="trinocular-scale-")
    procs = []
    try:
        subprocess.run([a.bin, "demo", "--out", os.path.join(work, "demo")], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        images = [os.path.join(work, "demo", f"img{i}.png") for i in (1, 2, 3)]
        calibration = os.path.join(work, "demo", "calibration.json")

        replicas = []
        for _ in range(3):
            g, h = free_port(), free_port()
            p = subprocess.Popen([a.bin, "serve", "--store", a.redis, "--threads", "1", "--max-jobs", "8",
                                  "--grpc-addr", f"127.0.0.1:{g}", "--http-addr", f"127.0.0.1:{h}"],
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            procs.append(p)
            replicas.append((g, h, p))
        for g, h, _ in replicas:
            wait_http(h)
        lb_grpc, lb_http = free_port(), free_port()
        conf = os.path.join(work, "nginx.conf")
        LOG.append(os.path.join(work, "error.log"))
        grpc_servers = "".join(f"server 127.0.0.1:{g} max_fails=1 fail_timeout=5s;" for g, _, _ in replicas)
        http_servers = "".join(f"server 127.0.0.1:{h} max_fails=1 fail_timeout=5s;" for _, h, _ in replicas)
        with open(conf, "w") as f:
            f.write(f"""
pid {work}/nginx.pid; error_log {work}/error.log; worker_processes 1;
events {{ worker_connections 1024; }}
http {{
  access_log off; keepalive_requests 1000000; keepalive_timeout 300s;
  client_body_temp_path {work}/body; client_max_body_size 64m;
  proxy_temp_path {work}/proxy; fastcgi_temp_path {work}/fcgi; uwsgi_temp_path {work}/uwsgi; scgi_temp_path {work}/scgi;
  upstream grpc_replicas {{ {grpc_servers} }}
  upstream http_replicas {{ {http_servers} keepalive 16; }}
  server {{ listen 127.0.0.1:{lb_grpc} http2;
    location / {{ grpc_pass grpc://grpc_replicas; grpc_next_upstream error timeout; }} }}
  server {{ listen 127.0.0.1:{lb_http};
    location / {{ proxy_pass http://http_replicas; proxy_http_version 1.1; proxy_set_header Connection ""; }} }}
}}
""")
        nginx = subprocess.Popen(["nginx", "-p", work, "-c", conf, "-g", "daemon off;"],
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        procs.append(nginx)
        wait_http(lb_http)

        # 1. Load through the balancer.
        import json
        for target in (f"grpc://127.0.0.1:{lb_grpc}", f"http://127.0.0.1:{lb_http}"):
            out = subprocess.run([a.loadgen, "--target", target, "--request", "examples/request.json",
                                  "--concurrency", "3", "--duration-s", "3", "--json"],
                                 check=True, capture_output=True, text=True).stdout
            d = json.loads(out)
            check(d["ok"] > 0 and set(d["by_code"]) == {"OK"},
                  f"load through nginx {target}: {d['ok']} requests, {d['throughput_per_s']:.0f}/s, {d['by_code']}")

        # 2. The same map through the balancer as through one server.
        lb = Client(f"127.0.0.1:{lb_grpc}", timeout=30)
        one = Client(f"127.0.0.1:{replicas[0][0]}", timeout=30)
        maps = []
        for client in (lb, one):
            s = client.create_session(calibration, name="scale-out")
            for k in range(6):
                client.add_capture(s.id, yaw_pose(k), images=images)
            maps.append(client.get_map(s.id))
            client.delete_session(s.id)
        check(len(maps[0].segments) > 0 and geometry(maps[0]) == geometry(maps[1]),
              f"a session through the balancer has the same map as through one server "
              f"({len(maps[0].segments)} segments)")

        # 3. A replica killed mid-stream. A replica killed after it answered a call's headers
        # but before its trailers leaves nginx nothing to send but a reset of the stream, which
        # a gRPC client reports as INTERNAL ("RST_STREAM"): a transport failure, like
        # UNAVAILABLE, not the service's error — and either way the capture may have been
        # stored. Each capture is named, so the client sends it again under its name until
        # it is acknowledged: stored once, whichever replica answers.
        def transport(code, message):
            return code == "UNAVAILABLE" or (code == "INTERNAL" and "RST_STREAM" in message)

        s = lb.create_session(calibration, name="kill")
        acked, errors, after_kill, duplicates, lost = {}, [], [], [], []
        killed = threading.Event()
        stop = threading.Event()

        def stream(k0):
            c = Client(f"127.0.0.1:{lb_grpc}", timeout=30)
            k = k0
            while not stop.is_set():
                name = f"stream-{k0}/{k}"
                for attempt in range(20):
                    try:
                        r = c.add_capture(s.id, yaw_pose(k % 12), images=images, capture_id=name)
                    except TrinocularError as e:
                        errors.append((e.code.name, e.message))
                        if not transport(e.code.name, e.message):
                            break
                        time.sleep(0.1)
                        continue
                    acked[name] = r.capture_index
                    if r.duplicate:
                        duplicates.append(name)
                    if killed.is_set():
                        after_kill.append(r.capture_index)
                    break
                else:
                    lost.append(name)
                k += 3

        threads = [threading.Thread(target=stream, args=(i,)) for i in range(3)]
        for t in threads:
            t.start()
        time.sleep(1.5)
        replicas[1][2].send_signal(signal.SIGKILL)
        replicas[1][2].wait()
        killed.set()
        time.sleep(2.5)
        stop.set()
        for t in threads:
            t.join()
        stored = lb.get_session(s.id).captures
        indices = sorted(acked.values())
        check(all(transport(c, m) for c, m in errors) and not lost,
              f"clients saw only transport errors: {len(errors)} x "
              f"{sorted(set(errors)) or 'none'}; every failed call sent again until "
              f"acknowledged ({len(duplicates)} of the retries found their capture stored)")
        check(len(acked) > 0 and indices == list(range(stored)),
              f"every capture stored exactly once: {len(acked)} acknowledged, {stored} stored")
        check(len(after_kill) > 0, f"captures went on after the kill: {len(after_kill)} acknowledged")
        lb.delete_session(s.id)
        print("scale-out: all checks passed")
    finally:
        for p in procs:
            if p.poll() is None:
                p.terminate()
        for p in procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
