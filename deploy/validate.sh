#!/usr/bin/env bash
# Validates deploy/ as far as a machine without a Docker engine or a cluster allows:
#   1. every YAML file parses (PyYAML: the system's, else a venv under /tmp);
#   2. the Dockerfile, compose.yaml and k8s manifests: ports 8080/50051, probes /readyz and
#      /healthz, HEALTHCHECK, non-root user, VOLUME, HPA/PDB/kustomization shape;
#   3. every --flag given to `trinocular serve` (Dockerfile ENTRYPOINT+CMD, compose command,
#      k8s args) is listed by `$TRINOCULAR_BIN serve --help`;
#   4. the ConfigMap's trinocular.toml is accepted: the binary starts on it (store -> memory,
#      addresses -> 127.0.0.1:0) and logs "listening";
#   5. the image's command line (ENTRYPOINT + CMD, binary -> local one, /data -> a temp dir,
#      addresses -> free local ports) starts and answers /healthz; so does compose's command
#      with redis://redis -> the local Redis (skipped, saying so, when none answers);
#   6. nginx.conf passes `nginx -t` (upstream host -> 127.0.0.1) if nginx is installed.
# Usage: TRINOCULAR_BIN=target/release/trinocular deploy/validate.sh
set -euo pipefail
HERE="$(cd "$(dirname "$0")" && pwd)"
# TRINOCULAR_BIN relative to the caller's directory; default: the repository's release build.
BIN="${TRINOCULAR_BIN:-$HERE/../target/release/trinocular}"
[ -x "$BIN" ] || { echo "validate: no trinocular binary at $BIN (set TRINOCULAR_BIN)" >&2; exit 2; }
BIN="$(cd "$(dirname "$BIN")" && pwd)/$(basename "$BIN")"
cd "$HERE"
[ -x "$BIN" ] || { echo "validate: no trinocular binary at $BIN (set TRINOCULAR_BIN)" >&2; exit 2; }

PY=python3
if ! python3 -c 'import yaml' 2>/dev/null; then
  venv="${TRINOCULAR_DEPLOY_VENV:-/tmp/trinocular-deploy-venv}"
  echo "== PyYAML not importable: venv $venv"
  [ -x "$venv/bin/python" ] || python3 -m venv "$venv"
  "$venv/bin/pip" install --quiet --disable-pip-version-check 'PyYAML>=6,<7'
  PY="$venv/bin/python"
fi
export BIN
exec "$PY" - <<'PYEOF'
import glob, json, os, re, shlex, shutil, signal, socket, subprocess, sys, tempfile, time
import urllib.request
import yaml

BIN = os.environ["BIN"]
failures = []
def check(cond, what):
    print(("  ok   " if cond else "  FAIL ") + what)
    if not cond:
        failures.append(what)

# ---- 1. YAML ------------------------------------------------------------------------------
print("== 1. YAML parses")
docs = {}
for path in sorted(glob.glob("*.yaml") + glob.glob("k8s/*.yaml")):
    try:
        docs[path] = [d for d in yaml.safe_load_all(open(path)) if d is not None]
        check(True, f"{path}: {len(docs[path])} document(s)")
    except yaml.YAMLError as e:
        check(False, f"{path}: {e}")
k8s = [d for p, ds in docs.items() if p.startswith("k8s/") and p != "k8s/kustomization.yaml" for d in ds]
def kind(k):
    return [d for d in k8s if d.get("kind") == k]

# ---- 2. shape -----------------------------------------------------------------------------
print("== 2. Dockerfile, compose, k8s shape")
dockerfile = open("Dockerfile").read()
def instr(name):
    # last occurrence of an instruction (the runtime stage), JSON form
    found = re.findall(rf"^{name}\s+(\[.*\])\s*$", dockerfile, re.M)
    return json.loads(found[-1]) if found else None
entrypoint, cmd = instr("ENTRYPOINT"), instr("CMD")
check(entrypoint == ["trinocular", "serve"], f"Dockerfile ENTRYPOINT {entrypoint}")
check(re.search(r"^FROM rust:1\.95-slim-bookworm AS builder", dockerfile, re.M) is not None, "Dockerfile builder rust:1.95-slim-bookworm")
check("cargo build --release --locked" in dockerfile, "Dockerfile cargo build --release --locked")
check(re.search(r"^EXPOSE 8080 50051$", dockerfile, re.M) is not None, "Dockerfile EXPOSE 8080 50051")
check(re.search(r"^HEALTHCHECK .*\n?.*127\.0\.0\.1:8080/healthz", dockerfile, re.M) is not None, "Dockerfile HEALTHCHECK /healthz on 8080")
users = re.findall(r"^USER\s+(\S+)", dockerfile, re.M)
check(bool(users) and not users[-1].startswith(("root", "0")), f"Dockerfile non-root USER {users[-1:]}")
check(re.search(r'^VOLUME \["/data"\]', dockerfile, re.M) is not None, "Dockerfile VOLUME /data")
check(cmd is not None and "--data-dir" in cmd and cmd[cmd.index("--data-dir") + 1] == "/data", "Dockerfile CMD --data-dir /data")

compose = docs["compose.yaml"][0]
svc = compose["services"]
check(svc["trinocular"]["deploy"]["replicas"] == 3, "compose: trinocular deploy.replicas 3")
check(svc["redis"]["image"].startswith("redis:7") and "--appendonly" in svc["redis"]["command"], "compose: redis:7 --appendonly yes")
check(any(str(v).startswith("redis-data:") for v in svc["redis"].get("volumes", [])), "compose: redis volume")
check("./nginx.conf:/etc/nginx/nginx.conf:ro" in svc["nginx"]["volumes"], "compose: nginx mounts nginx.conf")
check({"8080:8080", "50051:50051"} <= set(map(str, svc["nginx"]["ports"])), "compose: nginx publishes 8080 and 50051")
nginx_conf = open("nginx.conf").read()
check(re.search(r"grpc_pass grpc://trinocular_grpc;", nginx_conf) is not None, "nginx.conf grpc_pass grpc://trinocular_grpc")
check(re.search(r"upstream trinocular_grpc \{[^}]*server trinocular:50051;", nginx_conf) is not None, "nginx.conf upstream trinocular_grpc -> :50051")
check(re.search(r"listen 50051 http2;", nginx_conf) is not None, "nginx.conf listen 50051 http2")
check(re.search(r"proxy_pass http://trinocular_http;", nginx_conf) is not None and "server trinocular:8080;" in nginx_conf, "nginx.conf proxy_pass -> :8080")

dep = kind("Deployment")
check(len(dep) == 1, "k8s: one Deployment")
pod = dep[0]["spec"]["template"]["spec"]
c = pod["containers"][0]
ports = {p["containerPort"] for p in c["ports"]}
check(ports == {8080, 50051}, f"k8s Deployment containerPorts {sorted(ports)}")
sp_, lp = c["startupProbe"].get("httpGet", {}), c["livenessProbe"]["httpGet"]
check((sp_.get("path"), sp_.get("port")) == ("/readyz", 8080), f"k8s startupProbe {sp_}")
check((lp["path"], lp["port"]) == ("/healthz", 8080), f"k8s livenessProbe {lp}")
check(pod.get("terminationGracePeriodSeconds") == 30, "k8s terminationGracePeriodSeconds 30")
pre = c.get("lifecycle", {}).get("preStop", {})
check("sleep" in json.dumps(pre), f"k8s preStop sleep {pre}")
res = c.get("resources", {})
check(all(k in res.get(s, {}) for s in ("requests", "limits") for k in ("cpu", "memory")), "k8s resources requests+limits cpu/memory")
check(pod["securityContext"].get("runAsNonRoot") is True, "k8s runAsNonRoot")
check(c.get("readinessProbe", {}).get("grpc", {}).get("port") == 50051, "k8s gRPC readiness probe on 50051 (grpc.health.v1)")
images = [x["image"] for d in k8s for x in d.get("spec", {}).get("template", {}).get("spec", {}).get("containers", [])]
images += [s.get("image", "") for s in svc.values()]
check(all(":" in i and not i.endswith(":latest") for i in images if i), f"no latest or untagged images: {images}")
redis_sts = kind("StatefulSet")
check(bool(redis_sts) and redis_sts[0]["spec"]["template"]["spec"].get("securityContext", {}).get("runAsNonRoot") is True
      and redis_sts[0]["spec"]["template"]["spec"]["containers"][0].get("securityContext", {}).get("allowPrivilegeEscalation") is False,
      "k8s Redis runs as non-root without privilege escalation")
cm = kind("ConfigMap")
check(len(cm) == 1 and "trinocular.toml" in cm[0]["data"], "k8s ConfigMap with trinocular.toml")
mounts = {m["name"]: m["mountPath"] for m in c["volumeMounts"]}
vols = {v["name"]: v for v in pod["volumes"]}
cfg_mount = [n for n, v in vols.items() if v.get("configMap", {}).get("name") == cm[0]["metadata"]["name"]]
args = c.get("args", [])
cfg_path = args[args.index("--config") + 1] if "--config" in args else None
check(bool(cfg_mount) and cfg_path == mounts[cfg_mount[0]] + "/trinocular.toml", f"k8s --config {cfg_path} is the mounted ConfigMap")
toml_text = cm[0]["data"]["trinocular.toml"]
m = re.search(r'^url\s*=\s*"([^"]*)"', toml_text, re.M)
check(m is not None and m.group(1).startswith("redis://"), f"ConfigMap [store] url is redis ({m and m.group(1)})")
# Memory: the documented bound (docs/HARDENING.md#memory) of the ConfigMap's budgets inside the
# pod's limit — base 25 MiB + 2 x request bodies + working memory + 24 MiB per compute thread.
# (tests/hostile runs the ConfigMap's file under a burst and checks the peak RSS against the same
# limit; compose runs the defaults on <= 4 CPUs, which another test holds under 512 MiB.)
def mib(q):
    q = str(q)
    for suffix, f in (("Gi", 1024.0), ("Mi", 1.0), ("G", 1024.0), ("M", 1.0)):
        if q.endswith(suffix):
            return float(q[: -len(suffix)]) * f
    return float(q) / 2**20
def toml_int(key):
    m_ = re.search(rf"^{key}\s*=\s*(\d+)", toml_text, re.M)
    return int(m_.group(1)) if m_ else None
budgets = {k: toml_int(k) for k in ("max_bodies_mib", "max_working_mib", "threads")}
if None in budgets.values():
    check(False, f"ConfigMap sets max_bodies_mib, max_working_mib and threads: {budgets}")
else:
    bound = 25 + 2 * budgets["max_bodies_mib"] + budgets["max_working_mib"] + 24 * budgets["threads"]
    pod_mib = mib(res["limits"]["memory"])
    check(bound <= pod_mib, f"k8s memory bound {bound} MiB (ConfigMap budgets) within the pod limit {pod_mib:.0f} MiB")
climits = svc["trinocular"]["deploy"]["resources"]["limits"]
check(mib(climits["memory"]) >= 512 and float(climits["cpus"]) <= 4,
      f"compose: the defaults on {climits['cpus']} CPUs (<= 4) within {climits['memory']} (>= 512 MiB)")
redis_svcs = [s["metadata"]["name"] for s in kind("Service")]
check(m is not None and m.group(1).split("//")[1].split(":")[0] in redis_svcs, "ConfigMap redis host is a Service of the manifests")
svcs = [s for s in kind("Service") if s["metadata"]["name"] == "trinocular"]
sp = {p["port"]: p for p in svcs[0]["spec"]["ports"]} if svcs else {}
check(set(sp) == {8080, 50051}, f"k8s Service ports {sorted(sp)}")
check(sp.get(50051, {}).get("appProtocol") == "grpc", "k8s Service 50051 appProtocol grpc")
check(svcs and svcs[0]["spec"]["selector"].items() <= dep[0]["spec"]["template"]["metadata"]["labels"].items(), "k8s Service selects the Deployment's pods")
hpa = kind("HorizontalPodAutoscaler")
check(len(hpa) == 1 and hpa[0]["apiVersion"] == "autoscaling/v2" and hpa[0]["spec"]["scaleTargetRef"]["name"] == dep[0]["metadata"]["name"]
      and hpa[0]["spec"]["metrics"][0]["resource"]["name"] == "cpu", "k8s HPA autoscaling/v2 on CPU for the Deployment")
pdb = kind("PodDisruptionBudget")
check(len(pdb) == 1 and pdb[0]["spec"].get("minAvailable") == 1, "k8s PDB minAvailable 1")
check(len(kind("StatefulSet")) == 1, "k8s Redis StatefulSet")
kust = docs["k8s/kustomization.yaml"][0]
listed = set(kust["resources"])
present = {os.path.basename(p) for p in glob.glob("k8s/*.yaml")} - {"kustomization.yaml"}
check(listed == present, f"kustomization lists every manifest ({sorted(listed)})")

# ---- 3. flags -----------------------------------------------------------------------------
print("== 3. every flag is one `trinocular serve --help` lists")
help_text = subprocess.run([BIN, "serve", "--help"], capture_output=True, text=True, check=True).stdout
known = set(re.findall(r"(--[a-z][a-z0-9-]*)", help_text))
used = {
    "Dockerfile ENTRYPOINT+CMD": entrypoint[2:] + (cmd or []),
    "compose trinocular.command": svc["trinocular"]["command"],
    "k8s Deployment args": args,
}
for where, argv in used.items():
    for flag in [a.split("=")[0] for a in argv if a.startswith("--")]:
        check(flag in known, f"{where}: {flag}")

# ---- helpers for 4 and 5 --------------------------------------------------------------------
def free_port():
    s = socket.socket(); s.bind(("127.0.0.1", 0)); p = s.getsockname()[1]; s.close(); return p

def start(argv, what):
    log = tempfile.NamedTemporaryFile(prefix="trinocular-validate-", suffix=".log", delete=False)
    print("  $ " + shlex.join(argv))
    proc = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    return proc, log.name

def wait_listening(proc, logname, seconds=20):
    deadline = time.time() + seconds
    while time.time() < deadline:
        if "listening" in open(logname).read():
            return True
        if proc.poll() is not None:
            return False
        time.sleep(0.1)
    return False

def stop(proc, logname, ok):
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            rc = proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill(); rc = proc.wait()
    else:
        rc = proc.returncode
    if not ok:
        print(open(logname).read()[-3000:])
    os.unlink(logname)
    return rc

def get(url):
    try:
        with urllib.request.urlopen(url, timeout=5) as r:
            return r.status, r.read().decode()
    except Exception as e:
        return None, str(e)

# ---- 4. the ConfigMap's TOML --------------------------------------------------------------
print("== 4. the ConfigMap's trinocular.toml starts the binary")
tmp = tempfile.mkdtemp(prefix="trinocular-validate-")
t = re.sub(r'^url\s*=.*$', 'url = "memory"', toml_text, flags=re.M)
t = re.sub(r'^(grpc_addr|http_addr)\s*=.*$', r'\1 = "127.0.0.1:0"', t, flags=re.M)
t = re.sub(r'^data_dir\s*=.*$', f'data_dir = "{tmp}/data"', t, flags=re.M)
cfg = os.path.join(tmp, "trinocular.toml")
open(cfg, "w").write(t)
proc, logname = start([BIN, "serve", "--config", cfg], "configmap")
ok = wait_listening(proc, logname)
check(ok, "ConfigMap TOML (store memory, ports 127.0.0.1:0) reaches \"listening\"")
rc = stop(proc, logname, ok)
check(rc == 0, f"stopped by SIGTERM with exit {rc}")

# ---- 5. the container's command line ----------------------------------------------------
def run_cmdline(argv, what):
    argv = list(argv)
    argv[0] = BIN
    hp, gp = free_port(), free_port()
    for i, a in enumerate(argv):
        if i and argv[i - 1] == "--data-dir":
            argv[i] = os.path.join(tmp, "data-" + what.split()[0])
        elif i and argv[i - 1] == "--http-addr":
            argv[i] = f"127.0.0.1:{hp}"
        elif i and argv[i - 1] == "--grpc-addr":
            argv[i] = f"127.0.0.1:{gp}"
    if "--http-addr" not in argv:
        argv += ["--http-addr", f"127.0.0.1:{hp}"]
    if "--grpc-addr" not in argv:
        argv += ["--grpc-addr", f"127.0.0.1:{gp}"]
    proc, logname = start(argv, what)
    ok = wait_listening(proc, logname)
    status, body = get(f"http://127.0.0.1:{hp}/healthz") if ok else (None, "not listening")
    check(ok and status == 200 and body.startswith("ok"), f"{what}: /healthz -> {status} {body.strip()!r}")
    status, body = get(f"http://127.0.0.1:{hp}/readyz") if ok else (None, "not listening")
    check(ok and status == 200, f"{what}: /readyz -> {status} {body.strip()!r}")
    rc = stop(proc, logname, ok and status == 200)
    check(rc == 0, f"{what}: exit {rc} on SIGTERM")

print("== 5. the image's ENTRYPOINT + CMD starts and answers /healthz")
run_cmdline(entrypoint + cmd, "Dockerfile ENTRYPOINT+CMD")
def redis_up():
    try:
        socket.create_connection(("127.0.0.1", 6379), timeout=1).close(); return True
    except OSError:
        return False
ccmd = [re.sub(r"redis://redis:", "redis://127.0.0.1:", a) for a in svc["trinocular"]["command"]]
if redis_up():
    run_cmdline(entrypoint + ccmd, "compose command (redis -> 127.0.0.1)")
else:
    print("  SKIP compose command: no Redis on 127.0.0.1:6379")
kargs = ["--config", cfg]
run_cmdline(entrypoint + kargs, "k8s args (ConfigMap TOML as in 4)")

# ---- 6. nginx -----------------------------------------------------------------------------
print("== 6. nginx.conf syntax")
nginx = shutil.which("nginx") or ("/usr/sbin/nginx" if os.path.exists("/usr/sbin/nginx") else None)
if nginx:
    conf = os.path.join(tmp, "nginx.conf")
    # "trinocular" only resolves inside compose's network: test against 127.0.0.1.
    open(conf, "w").write(re.sub(r"server trinocular:", "server 127.0.0.1:", nginx_conf))
    r = subprocess.run([nginx, "-t", "-c", conf], capture_output=True, text=True)
    check(r.returncode == 0, f"nginx -t -c nginx.conf (upstream host -> 127.0.0.1): {r.stderr.strip().splitlines()[-1] if r.stderr.strip() else r.returncode}")
    if r.returncode:
        print(r.stderr)
else:
    print("  SKIP nginx -t: nginx is not installed (apt-get install -y nginx-light to run this check)")

shutil.rmtree(tmp, ignore_errors=True)
print()
if failures:
    print(f"validate: {len(failures)} check(s) FAILED:")
    for f in failures:
        print("  - " + f)
    sys.exit(1)
print("validate: all checks passed (not run here: docker build, compose up, kubectl apply)")
PYEOF
