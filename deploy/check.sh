#!/usr/bin/env bash
# Lints the deployment files without Docker, Kubernetes or a running systemd.
# Prints one line per check (PASS / FAIL / SKIP) and exits non-zero if any
# check fails. Usage: bash deploy/check.sh
#
# Environment:
#   DEPLOY_DIR     directory to check (default: the directory of this script)
#   CLNERF_SERVER  server binary for the flag check (default build/server/clnerf-server)
#   CLNERF_CLIENT  client binary for the health-check flags (default build/client/clnerf)
#   CLNERF_IMAGE_CODEC  image codec module the binaries load (default build/core/libclnerf_oiio.so)
#   PYTHON         interpreter (default /usr/bin/python3, else python3 on PATH)
#   CHECK_NO_PYYAML=1  behave as if PyYAML were missing (tests the fallback)
#
# Checks:
#   yaml     every *.yaml parses (PyYAML), else a minimal structural check
#   k8s      one Deployment of clnerf-server (component server, replicas >= 2,
#            grace >= 60 s, non-root); selectors match labels; HTTP probes
#            (/healthz liveness+startup, /readyz readiness) on the http port,
#            which equals server.json "http"; every Service targetPort resolves
#            to a container port of the pods it selects, the server Service's
#            grpc/http to the container's; a PodDisruptionBudget for the server
#            pods; the store is one ReadWriteMany PVC defined in deploy/k8s;
#            --config is a ConfigMap key with valid JSON whose keys the server
#            knows and whose model_memory_budget is set below the memory limit;
#            server.json "etcd" is HOST:PORT of a Service here that fronts an
#            etcd StatefulSet (command etcd, odd replicas == --initial-cluster
#            members, data on a volumeClaimTemplate, probes on its ports), or an
#            external endpoint named in a comment of the ConfigMap's file;
#            optional Secret env
#   docker   build stage runs scripts/install-deps.sh with the portable flags,
#            Dockerfile.dockerignore keeps the sources, runtime packages are
#            known to dpkg/apt-cache and cover the NEEDED libraries of the
#            built binaries and of the image codec module, which the
#            runtime copies to /usr/local/lib/clnerf/
#   compose  one service, named store volume, CLNERF_TOKEN, stop_grace_period >= 60s
#   consistency  listen port, store path and health check agree across
#            Dockerfile, compose, systemd and k8s
#   flags    every --flag passed to clnerf-server appears in its --help (not
#            the etcd container's command)
#   systemd  key settings + `systemd-analyze verify`
set -uo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
export CHECK_ROOT=$ROOT
export DEPLOY_DIR=${DEPLOY_DIR:-$ROOT/deploy}
export CLNERF_SERVER=${CLNERF_SERVER:-$ROOT/build/server/clnerf-server}
export CLNERF_CLIENT=${CLNERF_CLIENT:-$ROOT/build/client/clnerf}
export CLNERF_IMAGE_CODEC=${CLNERF_IMAGE_CODEC:-$ROOT/build/core/libclnerf_oiio.so}

PY=${PYTHON:-/usr/bin/python3}
if [ ! -x "$PY" ]; then PY=$(command -v python3 || true); fi
if [ -z "$PY" ]; then
  echo "FAIL  python3 not found (needed for the checks)"
  exit 1
fi
if [ ! -d "$DEPLOY_DIR" ]; then
  echo "FAIL  DEPLOY_DIR $DEPLOY_DIR is not a directory"
  exit 1
fi

exec "$PY" - <<'PY'
import json, os, re, shlex, shutil, subprocess, sys

ROOT = os.environ["CHECK_ROOT"]
D = os.path.abspath(os.environ["DEPLOY_DIR"])
fails = 0
counts = {"PASS": 0, "FAIL": 0, "SKIP": 0}

def rel(p):
    return os.path.relpath(p, os.path.dirname(D))

def report(status, msg):
    global fails
    counts[status] += 1
    if status == "FAIL":
        fails += 1
    print(f"{status:<5} {msg}", flush=True)

def check(ok, msg, detail=""):
    report("PASS" if ok else "FAIL", msg if ok or not detail else f"{msg}: {detail}")
    return ok

def run(cmd, timeout=30):
    try:
        p = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                           text=True, timeout=timeout)
        return p.returncode, p.stdout
    except (OSError, subprocess.TimeoutExpired) as e:
        return -1, str(e)

def seconds(v):
    """'60s', '1m30s', '60', '1min' -> seconds (None if unparseable)."""
    s = str(v).strip()
    if re.fullmatch(r"\d+", s):
        return int(s)
    total, pos = 0.0, 0
    for m in re.finditer(r"(\d+(?:\.\d+)?)\s*(ms|msec|sec|s|min|m|h)", s):
        if m.start() != pos:
            return None
        n, u = float(m.group(1)), m.group(2)
        total += n * {"ms": 0.001, "msec": 0.001, "s": 1, "sec": 1, "m": 60, "min": 60, "h": 3600}[u]
        pos = m.end()
    return total if pos == len(s) and pos else None

def flags_of(args):
    return [a.split("=", 1)[0] for a in args if a.startswith("--")]

def arg_value(args, flag):
    for i, a in enumerate(args):
        if a == flag and i + 1 < len(args):
            return args[i + 1]
        if a.startswith(flag + "="):
            return a.split("=", 1)[1]
    return None

def port_of(hostport):
    m = re.search(r":(\d+)$", hostport or "")
    return int(m.group(1)) if m else None

# Collected for the cross-file checks: source -> list of server args.
server_args = {}
facts = {}   # name -> {source: value}
def fact(name, source, value):
    facts.setdefault(name, {})[source] = value

# ----------------------------------------------------------------- files
paths = {
    "dockerfile": os.path.join(D, "Dockerfile"),
    "compose": os.path.join(D, "compose.yaml"),
    "unit": os.path.join(D, "clnerf-server.service"),
    "k8s": os.path.join(D, "k8s"),
}
for k, p in paths.items():
    check(os.path.exists(p), f"exists: {rel(p)}")

yaml_files = sorted(
    os.path.join(dp, f) for dp, _, fs in os.walk(D) for f in fs
    if f.endswith((".yaml", ".yml")))

# ----------------------------------------------------------------- (a) YAML
yaml = None
if os.environ.get("CHECK_NO_PYYAML") != "1":
    try:
        import yaml  # noqa: F811
    except ImportError:
        yaml = None

docs = {}  # path -> list of documents (PyYAML only)
if yaml is not None:
    for p in yaml_files:
        try:
            with open(p, encoding="utf-8") as f:
                docs[p] = [d for d in yaml.safe_load_all(f) if d is not None]
            check(bool(docs[p]), f"yaml: {rel(p)} parses", "no documents")
        except Exception as e:  # yaml.YAMLError, UnicodeError
            report("FAIL", f"yaml: {rel(p)} does not parse: {str(e).splitlines()[0]}")
else:
    report("SKIP", "skipped full YAML parse (no PyYAML); structural check only")
    for p in yaml_files:
        problems = []
        try:
            text = open(p, encoding="utf-8").read()
        except UnicodeError as e:
            text, problems = "", [f"not UTF-8 ({e})"]
        body = [l for l in text.splitlines() if l.strip() and not l.lstrip().startswith("#")]
        if not body:
            problems.append("empty")
        block = None  # indent of the key that opened a block scalar (| or >)
        for n, l in enumerate(text.splitlines(), 1):
            if re.match(r"^ *\t", l):
                problems.append(f"line {n}: tab in indentation")
            ind = len(l) - len(l.lstrip(" "))
            if block is not None:
                if not l.strip() or ind > block:
                    continue
                block = None
            if re.search(r":\s*[|>][-+0-9]*\s*(#.*)?$", l):
                block = ind
            code = re.sub(r"\s#.*$", "", re.sub(r"\"[^\"]*\"|'[^']*'", "", l))
            if code.count("[") != code.count("]") or code.count("{") != code.count("}"):
                problems.append(f"line {n}: unbalanced brackets")
        if "/k8s/" in p:
            for i, doc in enumerate(re.split(r"(?m)^---\s*$", text)):
                if re.search(r"(?m)^[^#\s]", doc) and not (
                        re.search(r"(?m)^apiVersion:", doc) and re.search(r"(?m)^kind:", doc)):
                    problems.append(f"document {i}: no top-level apiVersion/kind")
        check(not problems, f"yaml (structural): {rel(p)}", "; ".join(problems))

def flow_list(line):
    m = re.search(r"\[(.*)\]", line)
    if not m:
        return []
    return [t.strip().strip("\"'") for t in m.group(1).split(",") if t.strip()]

# ----------------------------------------------------------------- Dockerfile
def dockerfile_instructions(path):
    out, cur = [], ""
    for line in open(path, encoding="utf-8").read().splitlines():
        s = line.strip()
        if s.startswith("#") or (not s and not cur):
            continue
        if s.endswith("\\"):
            cur += s[:-1] + " "
            continue
        cur += s
        if cur.strip():
            parts = cur.strip().split(None, 1)
            out.append((parts[0].upper(), parts[1] if len(parts) > 1 else ""))
        cur = ""
    return out

def exec_form(rest):
    rest = rest.strip()
    if rest.startswith("["):
        try:
            return json.loads(rest)
        except ValueError:
            return None
    return shlex.split(rest)

runtime_pkgs = []
if os.path.exists(paths["dockerfile"]):
    ins = dockerfile_instructions(paths["dockerfile"])
    stages = []
    for op, rest in ins:
        if op == "FROM":
            m = re.match(r"(?:--\S+\s+)*(\S+)(?:\s+AS\s+(\S+))?", rest, re.I)
            stages.append({"image": m.group(1), "name": (m.group(2) or "").lower(), "ins": []})
        elif stages:
            stages[-1]["ins"].append((op, rest))
    ok = len(stages) >= 2
    check(ok, "docker: multi-stage Dockerfile", f"{len(stages)} stage(s)")
    if ok:
        build = next((s for s in stages if s["name"] == "build"), None)
        rt = stages[-1]
        check(build is not None and build["image"].startswith("debian:bookworm"),
              "docker: build stage is 'FROM debian:bookworm AS build'",
              build["image"] if build else "no stage named build")
        check(rt["image"] == "debian:bookworm-slim", "docker: runtime stage is debian:bookworm-slim",
              rt["image"])
        if build:
            runs = " ; ".join(r for o, r in build["ins"] if o == "RUN")
            check(re.search(r"scripts/install-deps\.sh", runs) is not None,
                  "docker: build stage runs scripts/install-deps.sh")
            m = re.search(r"scripts/build\.sh([^;&|]*)", runs)
            bargs = m.group(1) if m else ""
            check(m is not None and "-DCLNERF_NATIVE=OFF" in bargs and "-DCLNERF_BUILD_TESTS=OFF" in bargs,
                  "docker: build stage runs scripts/build.sh -DCLNERF_NATIVE=OFF -DCLNERF_BUILD_TESTS=OFF",
                  "not found")
        # runtime packages
        for o, r in rt["ins"]:
            if o != "RUN":
                continue
            for seg in re.split(r"&&|;|\|\|", r):
                toks = shlex.split(seg)
                if "apt-get" in toks and "install" in toks:
                    after = toks[toks.index("install") + 1:]
                    runtime_pkgs += [t for t in after if not t.startswith("-")]
        check(bool(runtime_pkgs), "docker: runtime stage installs packages with apt-get",
              "no apt-get install found")
        dev = [p for p in runtime_pkgs if p.endswith("-dev") or p in ("build-essential", "cmake")]
        check(not dev, "docker: runtime stage has no build-only packages", " ".join(dev))
        copies = " ".join(r for o, r in rt["ins"] if o == "COPY")
        check("clnerf-server" in copies and re.search(r"/clnerf(\s|$)", copies) is not None
              and "/usr/local/bin" in copies,
              "docker: runtime copies clnerf-server and clnerf to /usr/local/bin")
        # The binaries load OpenImageIO from a module (core/data/image_codec.h)
        # beside them or in ../lib/clnerf/.
        check(re.search(r"libclnerf_oiio\.so\s+/usr/local/lib/clnerf/?(\s|$)", copies) is not None,
              "docker: runtime copies the image codec module to /usr/local/lib/clnerf/")
        user = [r for o, r in rt["ins"] if o == "USER"]
        check(bool(user) and user[-1].split(":")[0] not in ("root", "0"),
              "docker: runtime runs as a non-root USER", user[-1] if user else "no USER")
        ep = [exec_form(r) for o, r in rt["ins"] if o == "ENTRYPOINT"]
        cmd = [exec_form(r) for o, r in rt["ins"] if o == "CMD"]
        epv = ep[-1] if ep else None
        if check(bool(epv) and os.path.basename(epv[0]) == "clnerf-server",
                 "docker: ENTRYPOINT is clnerf-server (exec form)", repr(epv)):
            args = epv[1:] + ((cmd[-1] or []) if cmd else [])
            server_args["Dockerfile ENTRYPOINT/CMD"] = args
            fact("listen port", "Dockerfile --listen", port_of(arg_value(args, "--listen")))
            fact("store path", "Dockerfile --store", arg_value(args, "--store"))
            facts.setdefault("image", {})["entrypoint"] = args
        for o, r in rt["ins"]:
            if o == "EXPOSE":
                for t in r.split():
                    fact("listen port", "Dockerfile EXPOSE", int(t.split("/")[0]))
            if o == "VOLUME":
                v = exec_form(r) or []
                fact("store path", "Dockerfile VOLUME", v[0] if v else None)
            if o == "HEALTHCHECK":
                hc = re.sub(r"^(--\S+\s+)*", "", r.strip())
                if hc.upper().startswith("CMD"):
                    fact("health check", "Dockerfile HEALTHCHECK", ["CMD"] + (exec_form(hc[3:]) or []))

# build context filter must keep the sources
ign = os.path.join(D, "Dockerfile.dockerignore")
if os.path.exists(ign):
    import fnmatch
    pats = [l.strip() for l in open(ign, encoding="utf-8")
            if l.strip() and not l.lstrip().startswith(("#", "!"))]
    needed = ["CMakeLists.txt", "scripts/install-deps.sh", "scripts/build.sh",
              "core/CMakeLists.txt", "proto/CMakeLists.txt", "server/CMakeLists.txt",
              "client/CMakeLists.txt"]
    def ignored(path):
        parts = path.split("/")
        for pat in pats:
            pat = pat.strip("/")
            for i in range(1, len(parts) + 1):  # a matched parent dir excludes its files
                prefix = "/".join(parts[:i])
                if fnmatch.fnmatchcase(prefix, pat) or (
                        pat.startswith("**/") and fnmatch.fnmatchcase(parts[i - 1], pat[3:])):
                    return pat
        return None
    hits = [f"{p} ({ignored(p)})" for p in needed if ignored(p)]
    check(not hits, "docker: Dockerfile.dockerignore keeps the build sources", "excluded: " + ", ".join(hits))

# (d) runtime packages known locally
if runtime_pkgs:
    dpkg_q, aptc = shutil.which("dpkg-query"), shutil.which("apt-cache")
    if not dpkg_q and not aptc:
        report("SKIP", "docker: runtime package names not verified (no dpkg-query or apt-cache)")
    else:
        unknown = []
        installed = set()
        if dpkg_q:  # One call for every package (unknown names only add an error line).
            rc, out = run([dpkg_q, "-W", "-f=${Package} ${Status}\\n"] + list(runtime_pkgs))
            installed = {l.split()[0] for l in out.splitlines() if l.endswith(" installed") and " " in l}
        for p in runtime_pkgs:
            known = p in installed
            if not known and aptc:
                rc, out = run([aptc, "show", "--no-all-versions", p])
                known = rc == 0 and re.search(r"(?m)^Package: ", out) is not None
            if not known:
                unknown.append(p)
        check(not unknown, f"docker: {len(runtime_pkgs)} runtime packages exist in dpkg/apt-cache",
              "unknown: " + " ".join(unknown))

# (d) runtime packages cover the NEEDED libraries of the built binaries
BASE_IMAGE_PKGS = {"libc6", "libgcc-s1", "libstdc++6", "zlib1g"}  # in debian:bookworm-slim
def needed_libs(binary):
    tool = shutil.which("readelf")
    if not tool:
        return None
    rc, out = run([tool, "-d", binary])
    return re.findall(r"\(NEEDED\)\s+Shared library: \[([^\]]+)\]", out) if rc == 0 else None

def lib_candidates(lib, ldcache):
    cands = []
    if lib in ldcache:
        cands += [ldcache[lib], os.path.realpath(ldcache[lib])]
    for d in ("/lib/x86_64-linux-gnu", "/usr/lib/x86_64-linux-gnu", "/lib", "/usr/lib", "/lib64"):
        cands.append(os.path.join(d, lib))
    out = []
    for c in cands:
        for path in (c, os.path.realpath(c)):
            if path not in out:
                out.append(path)
    return out

def path_owners(paths):
    """dpkg -S over every path at once (one call: each reads dpkg's database)."""
    rc, out = run(["dpkg", "-S"] + sorted(set(paths)), timeout=60)
    owners = {}
    for line in out.splitlines():
        if ": /" not in line or line.startswith("dpkg-query:"):
            continue
        pkgs, path = line.rsplit(": ", 1)
        owners.setdefault(path.strip(), {x.strip().split(":")[0] for x in pkgs.split(",")})
    return owners

def lib_package(lib, ldcache, owners):
    for path in lib_candidates(lib, ldcache):
        if path in owners:
            return owners[path]
    return None

bins = [b for b in (os.environ["CLNERF_SERVER"], os.environ["CLNERF_CLIENT"]) if os.access(b, os.X_OK)]
if bins and os.path.isfile(os.environ["CLNERF_IMAGE_CODEC"]):
    bins.append(os.environ["CLNERF_IMAGE_CODEC"])
if not runtime_pkgs:
    pass
elif not bins:
    report("SKIP", "docker: library coverage not checked (no built binaries)")
elif not shutil.which("dpkg") or not shutil.which("readelf"):
    report("SKIP", "docker: library coverage not checked (needs dpkg and readelf)")
else:
    ldcache = {}
    rc, out = run(["ldconfig", "-p"]) if shutil.which("ldconfig") else (1, "")
    if rc != 0 and os.path.exists("/sbin/ldconfig"):
        rc, out = run(["/sbin/ldconfig", "-p"])
    for m in re.finditer(r"^\s*(\S+) \(([^)]*)\) => (\S+)", out, re.M):
        if "x86-64" in m.group(2) or "x86-64" not in out:
            ldcache.setdefault(m.group(1), m.group(3))
    for b in bins:
        with open(b, "rb") as f:
            if f.read(4) != b"\x7fELF":
                report("SKIP", f"docker: {b} is not an ELF binary; library coverage not checked")
                continue
        libs = needed_libs(b)
        if libs is None:
            report("FAIL", f"docker: cannot read NEEDED entries of {b}")
            continue
        missing, unowned = [], []
        owners = path_owners([c for lib in libs for c in lib_candidates(lib, ldcache)])
        for lib in libs:
            pk = lib_package(lib, ldcache, owners)
            if pk is None:
                unowned.append(lib)
            elif not pk & (set(runtime_pkgs) | BASE_IMAGE_PKGS):
                missing.append(f"{lib} ({'/'.join(sorted(pk))})")
        check(not missing and not unowned,
              f"docker: runtime packages cover the {len(libs)} libraries {os.path.basename(b)} links",
              "; ".join(missing + [f"{l} (no package owns it)" for l in unowned]))

# ----------------------------------------------------------------- compose
def compose_checks(c):
    svcs = (c or {}).get("services") or {}
    if not check(len(svcs) == 1, "compose: exactly one service", f"{len(svcs)}"):
        return
    name, s = next(iter(svcs.items()))
    b = s.get("build") or {}
    if isinstance(b, str):
        b = {"context": b}
    df = os.path.normpath(os.path.join(D, b.get("context", "."), b.get("dockerfile", "Dockerfile")))
    check(df == os.path.normpath(paths["dockerfile"]),
          "compose: build uses deploy/Dockerfile with the repo root as context", df)
    if "entrypoint" in s:
        report("FAIL", "compose: overrides the image ENTRYPOINT (keep it in the Dockerfile)")
    cmd = s.get("command", [])
    cmd = shlex.split(cmd) if isinstance(cmd, str) else list(cmd or [])
    server_args["compose command"] = facts.get("image", {}).get("entrypoint", []) + cmd
    ports = [str(p) for p in s.get("ports", [])]
    for p in ports:
        fact("listen port", f"compose ports {p}", int(p.split(":")[-1].split("/")[0]))
    env = s.get("environment") or {}
    names = list(env) if isinstance(env, dict) else [e.split("=", 1)[0] for e in env]
    check("CLNERF_TOKEN" in names, "compose: CLNERF_TOKEN passed from the environment")
    vols = (c.get("volumes") or {})
    store = [v for v in s.get("volumes", []) if isinstance(v, str) and ":" in v]
    named = [v.split(":")[0] for v in store if not v.startswith((".", "/", "~"))]
    check(bool(named) and all(n in vols for n in named), "compose: store on a declared named volume",
          f"{store} vs {list(vols)}")
    for v in store:
        fact("store path", f"compose volume {v.split(':')[0]}", v.split(":")[1])
    hc = (s.get("healthcheck") or {}).get("test")
    fact("health check", "compose healthcheck", hc)
    g = seconds(s.get("stop_grace_period", "10s"))
    check(g is not None and g >= 60, "compose: stop_grace_period >= 60s", str(s.get("stop_grace_period")))

if os.path.exists(paths["compose"]):
    if yaml is not None and paths["compose"] in docs:
        compose_checks(docs[paths["compose"]][0])
    elif yaml is None:
        report("SKIP", "compose: semantic checks need PyYAML")
        for l in open(paths["compose"], encoding="utf-8"):
            if re.match(r"\s*command:", l):
                server_args["compose command"] = facts.get("image", {}).get("entrypoint", []) + flow_list(l)

# ----------------------------------------------------------------- k8s
# Layout (deploy/k8s): a Deployment of N clnerf-server replicas (component
# server) over one ReadWriteMany PVC, a Service and a PodDisruptionBudget for
# them, the ConfigMap with server.json, and etcd (a StatefulSet running the
# same image with command: [etcd, ...] behind a headless Service) unless
# server.json's "etcd" names an external endpoint documented in a comment of
# the ConfigMap's file.
def labels_match(sel, labels):
    return bool(sel) and all(labels.get(k) == v for k, v in sel.items())

def resolve_port(port, cports):
    """A named or numbered container port -> its number (None if absent)."""
    if isinstance(port, str) and not port.isdigit():
        return cports.get(port)
    try:
        n = int(port)
    except (TypeError, ValueError):
        return None
    return n if n in cports.values() else None

def quantity(q):
    """Kubernetes memory quantity ('4Gi', '512M', '1e9', 1024) -> bytes (None if unset/unparseable)."""
    m = re.fullmatch(r"(\d+(?:\.\d+)?(?:e\d+)?)(Ki|Mi|Gi|Ti|k|M|G|T)?", str(q).strip()) if q is not None else None
    if not m:
        return None
    mult = {None: 1, "k": 10**3, "M": 10**6, "G": 10**9, "T": 10**12,
            "Ki": 2**10, "Mi": 2**20, "Gi": 2**30, "Ti": 2**40}[m.group(2)]
    return int(float(m.group(1)) * mult)

def is_server_container(c):
    if "clnerf-server" not in str(c.get("image", "")):
        return False
    cmd = c.get("command") or []
    return not cmd or os.path.basename(str(cmd[0])) == "clnerf-server"

def cmd_value(cmd, flag):
    return arg_value([str(a) for a in cmd], flag)

def k8s_checks(all_docs):
    by_kind = {}
    for p, ds in all_docs.items():
        for d in ds:
            if isinstance(d, dict):
                by_kind.setdefault(d.get("kind"), []).append((p, d))
    name_of = lambda d: (d.get("metadata") or {}).get("name")
    def pod_parts(d):
        spec = d.get("spec") or {}
        tmpl = spec.get("template") or {}
        return spec, (tmpl.get("metadata") or {}).get("labels") or {}, tmpl.get("spec") or {}

    # workloads: every pod template, for the Service selectors
    workloads = []   # (kind, name, labels, containers)
    for kind in ("Deployment", "StatefulSet", "DaemonSet"):
        for _, d in by_kind.get(kind, []):
            _, lb, ps = pod_parts(d)
            workloads.append((kind, name_of(d), lb, ps.get("containers") or []))

    # the server: exactly one Deployment running clnerf-server, component server
    deps = []
    for _, d in by_kind.get("Deployment", []):
        _, lb, ps = pod_parts(d)
        if lb.get("app.kubernetes.io/component") == "server" and any(
                is_server_container(c) for c in ps.get("containers") or []):
            deps.append(d)
    stray = [f"{k} {n}" for k, n, lb, cs in workloads
             if any(is_server_container(c) for c in cs) and not any(n == name_of(d) and k == "Deployment" for d in deps)]
    check(not stray, "k8s: clnerf-server runs only in the server Deployment", ", ".join(stray))
    if not check(len(deps) == 1, "k8s: exactly one Deployment runs clnerf-server (component: server)",
                 str(len(deps))):
        return
    dep = deps[0]
    dname = name_of(dep)
    spec, tlabels, pspec = pod_parts(dep)
    sel = (spec.get("selector") or {}).get("matchLabels") or {}
    check(labels_match(sel, tlabels), f"k8s: Deployment {dname} selector matches template labels",
          f"{sel} vs {tlabels}")
    replicas = spec.get("replicas", 1)
    check(isinstance(replicas, int) and replicas >= 2,
          f"k8s: Deployment {dname} replicas >= 2 (replicas share the store through etcd)", str(replicas))
    strat = spec.get("strategy") or {}
    mu = (strat.get("rollingUpdate") or {}).get("maxUnavailable", "25%")
    check(strat.get("type", "RollingUpdate") == "RollingUpdate"
          and (not isinstance(mu, int) or not isinstance(replicas, int) or mu < replicas),
          f"k8s: Deployment {dname} rolls out with replicas serving (RollingUpdate, maxUnavailable {mu})",
          f"type={strat.get('type')} maxUnavailable={mu} replicas={replicas}")
    g = pspec.get("terminationGracePeriodSeconds", 30)
    check(isinstance(g, int) and g >= 60, "k8s: terminationGracePeriodSeconds >= 60", str(g))
    psc = pspec.get("securityContext") or {}
    check(psc.get("runAsNonRoot") is True, "k8s: pod securityContext runAsNonRoot")
    c = next(c for c in pspec.get("containers") or [] if is_server_container(c))
    if c.get("command"):
        args = [str(a) for a in c["command"][1:]] + [str(a) for a in c.get("args", [])]
    else:
        args = facts.get("image", {}).get("entrypoint", []) + [str(a) for a in c.get("args", [])]
    server_args["k8s container command/args"] = args

    # --config file is provided by a ConfigMap key and is valid JSON
    vols = {v.get("name"): v for v in pspec.get("volumes", [])}
    cms = {name_of(d): (p, d) for p, d in by_kind.get("ConfigMap", [])}
    cfg_json = {}
    cfg_file = None   # the ConfigMap's manifest, for the documented external etcd
    cfg = arg_value(args, "--config")
    if check(cfg is not None, "k8s: the server is started with --config (http, etcd come from it)"):
        found = None
        for m in c.get("volumeMounts", []):
            v = vols.get(m.get("name")) or {}
            if "configMap" not in v:
                continue
            mp = m.get("mountPath", "").rstrip("/")
            key = m.get("subPath") if m.get("subPath") else (
                cfg[len(mp) + 1:] if cfg.startswith(mp + "/") else None)
            if (m.get("subPath") and cfg != mp) or not key:
                continue
            items = v["configMap"].get("items")
            if items:
                key = next((i.get("key") for i in items if i.get("path") == key), None)
            cp, cd = cms.get(v["configMap"].get("name")) or (None, {})
            data = cd.get("data") or {}
            if key in data:
                found = (v["configMap"].get("name"), key, data[key], cp)
        if check(found is not None, f"k8s: --config {cfg} is a key of a mounted ConfigMap"):
            try:
                cfg_json = json.loads(found[2])
                ok = isinstance(cfg_json, dict)
                check(ok, f"k8s: ConfigMap {found[0]} key {found[1]} is valid JSON", "not a JSON object")
                cfg_json = cfg_json if ok else {}
                cfg_file = found[3]
            except ValueError as e:
                report("FAIL", f"k8s: ConfigMap {found[0]} key {found[1]} is not valid JSON: {e}")
    opts_src = os.path.join(ROOT, "server", "server_options.cc")
    if cfg_json and os.path.exists(opts_src):
        known = set(re.findall(r'\bk == "(\w+)"', open(opts_src, encoding="utf-8").read()))
        bad = sorted(k for k in cfg_json if k not in known)
        check(not bad, "k8s: server.json keys are config keys of server/server_options.cc",
              "unknown: " + " ".join(bad))
    elif cfg_json:
        report("SKIP", "k8s: server.json keys not checked (no server/server_options.cc)")
    if cfg_json:
        # 0 = half the node's memory, which the container's limit does not cap
        budget = cfg_json.get("model_memory_budget", 0)
        limit = quantity((c.get("resources") or {}).get("limits", {}).get("memory"))
        check(isinstance(budget, int) and budget > 0 and (limit is None or budget < limit),
              f"k8s: server.json model_memory_budget {budget} is set and below the memory limit {limit}",
              "0 = half the node's memory" if budget == 0 else "")
    if "listen" in cfg_json:
        fact("listen port", "k8s server.json listen", port_of(str(cfg_json["listen"])))
    if "store" in cfg_json:
        fact("store path", "k8s server.json store", cfg_json["store"])

    # ports: grpc (the listen port) and http (server.json "http")
    cports = {p.get("name"): p.get("containerPort") for p in c.get("ports", [])}
    if check("grpc" in cports, "k8s: container port named grpc", f"have {cports}"):
        fact("listen port", "k8s containerPort grpc", cports["grpc"])
    http_port = cports.get("http")
    if check(http_port is not None, "k8s: container port named http", f"have {cports}"):
        hp = port_of(str(cfg_json.get("http", "")))
        check(hp is not None and hp == http_port,
              f"k8s: containerPort http {http_port} == port of server.json \"http\"",
              f"server.json http={cfg_json.get('http')!r}")
    want_path = {"startupProbe": ("/healthz", "/readyz"), "livenessProbe": ("/healthz",),
                 "readinessProbe": ("/readyz",)}
    for pk, paths_ok in want_path.items():
        pr = c.get(pk)
        if pr is None:
            if pk != "startupProbe":
                report("FAIL", f"k8s: {pk} missing")
            continue
        hg = pr.get("httpGet")
        if not check(hg is not None, f"k8s: {pk} is an httpGet probe", f"has {sorted(pr)}"):
            continue
        rp = resolve_port(hg.get("port"), cports)
        check(rp is not None and rp == http_port,
              f"k8s: {pk} port {hg.get('port')} -> http containerPort {http_port}",
              f"resolves to {rp} (container ports {cports})")
        check(hg.get("path") in paths_ok, f"k8s: {pk} path {hg.get('path')} is {' or '.join(paths_ok)}")

    # Services: each selects pods defined here, every targetPort resolves
    svcs = [(p, d) for p, d in by_kind.get("Service", [])]
    server_svcs = []
    for _, s in svcs:
        sname, sspec = name_of(s), s.get("spec") or {}
        ssel = sspec.get("selector") or {}
        sel_w = [w for w in workloads if labels_match(ssel, w[2])]
        if not check(bool(sel_w), f"k8s: Service {sname} selects pods defined in deploy/k8s",
                     f"selector {ssel} matches no pod template"):
            continue
        is_server = labels_match(ssel, tlabels)
        if is_server:
            server_svcs.append(sname)
            check(all(w[0] == "Deployment" and w[1] == dname for w in sel_w),
                  f"k8s: Service {sname} selects only the server pods", str([f"{w[0]} {w[1]}" for w in sel_w]))
        for sp in sspec.get("ports", []):
            tp = sp.get("targetPort", sp.get("port"))
            for kind, wname, _, wcs in sel_w:
                wports = {p.get("name"): p.get("containerPort") for wc in wcs for p in wc.get("ports", [])}
                resolved = resolve_port(tp, wports)
                check(resolved is not None,
                      f"k8s: Service {sname} port {sp.get('name')} targetPort {tp} -> {kind} {wname} containerPort {resolved}",
                      f"no container port {tp!r} (have {wports})")
            if not is_server:
                continue
            resolved = resolve_port(tp, cports)
            pn, ap = sp.get("name"), sp.get("appProtocol")
            check(pn in ("grpc", "http") and ap == pn,
                  f"k8s: Service {sname} port {pn} has appProtocol {pn} (grpc or http)", f"appProtocol={ap}")
            if pn in cports:
                check(resolved == cports[pn], f"k8s: Service {sname} port {pn} targets containerPort {pn}",
                      f"targetPort {tp} -> {resolved}, containerPort {pn} = {cports[pn]}")
            if pn == "grpc":
                fact("listen port", f"k8s Service {sname} targetPort grpc", resolved)
    check(bool(server_svcs), "k8s: a Service selects the server pods", "none")

    # PodDisruptionBudget for the server pods
    pdbs = [d for _, d in by_kind.get("PodDisruptionBudget", [])
            if labels_match(((d.get("spec") or {}).get("selector") or {}).get("matchLabels") or {}, tlabels)]
    if check(bool(pdbs), "k8s: a PodDisruptionBudget selects the server pods"):
        for d in pdbs:
            ps_ = d.get("spec") or {}
            mu_, ma_ = ps_.get("maxUnavailable"), ps_.get("minAvailable")
            ok = (mu_ is None) != (ma_ is None)
            if ok and isinstance(mu_, int):
                ok = mu_ >= 1
            if ok and isinstance(ma_, int) and isinstance(replicas, int):
                ok = ma_ < replicas
            check(ok, f"k8s: PodDisruptionBudget {name_of(d)} allows one disruption "
                      f"({'maxUnavailable' if mu_ is not None else 'minAvailable'} "
                      f"{mu_ if mu_ is not None else ma_})",
                  f"maxUnavailable={mu_} minAvailable={ma_} replicas={replicas}")

    # volumes: the store is a ReadWriteMany PVC defined here
    pvcs = {name_of(d): d for _, d in by_kind.get("PersistentVolumeClaim", [])}
    store_mounts = []
    for m in c.get("volumeMounts", []):
        n = m.get("name")
        if not check(n in vols, f"k8s: volumeMount {n} -> volume", f"no volume named {n!r} (volumes {list(vols)})"):
            continue
        pv = vols[n].get("persistentVolumeClaim")
        if pv is not None:
            store_mounts.append((m, pv.get("claimName")))
    if check(len(store_mounts) == 1, "k8s: the store is mounted from one persistentVolumeClaim",
             f"{len(store_mounts)} PVC mounts"):
        m, claim = store_mounts[0]
        fact("store path", f"k8s PVC {claim} mountPath", m.get("mountPath"))
        if check(claim in pvcs, f"k8s: PVC {claim} is defined in deploy/k8s", f"defined: {list(pvcs)}"):
            modes = (pvcs[claim].get("spec") or {}).get("accessModes") or []
            check("ReadWriteMany" in modes, f"k8s: PVC {claim} accessModes include ReadWriteMany (shared by the replicas)",
                  str(modes))
    for n, v in vols.items():
        if "configMap" in v:
            cm = v["configMap"].get("name")
            check(cm in cms, f"k8s: volume {n} references ConfigMap {cm} defined in deploy/k8s",
                  f"defined: {list(cms)}")
    for e in c.get("env", []):
        ref = (e.get("valueFrom") or {}).get("secretKeyRef")
        if ref:
            check(ref.get("optional") is True,
                  f"k8s: env {e.get('name')} from Secret {ref.get('name')} is optional (Secret not shipped)")

    # etcd: server.json "etcd" is HOST:PORT of a Service here (or documented external)
    ev = str(cfg_json.get("etcd") or "")
    m = re.fullmatch(r"([A-Za-z0-9.-]+):(\d+)", ev)
    if not check(m is not None, f"k8s: server.json \"etcd\" is HOST:PORT ({ev or 'unset'})",
                 "replicas need etcd"):
        return
    host, eport = m.group(1), int(m.group(2))
    svc_by_name = {name_of(s): s for _, s in svcs}
    short = host.split(".")[0]
    in_cluster = short in svc_by_name and (host == short or re.fullmatch(
        re.escape(short) + r"\.[a-z0-9-]+(\.svc(\.cluster\.local)?)?", host) is not None)
    if not in_cluster:
        text = open(cfg_file, encoding="utf-8").read() if cfg_file else ""
        doc = any(ev in l for l in text.splitlines() if l.lstrip().startswith("#"))
        check(doc, f"k8s: etcd {ev} is external and documented in a comment of {rel(cfg_file) if cfg_file else 'the ConfigMap'}",
              f"{host!r} is not a Service in deploy/k8s {sorted(svc_by_name)}")
        return
    es = svc_by_name[short]
    sports = [sp.get("port") for sp in (es.get("spec") or {}).get("ports", [])]
    check(eport in sports, f"k8s: etcd port {eport} is a port of Service {short}", f"ports {sports}")
    ests = [d for _, d in by_kind.get("StatefulSet", []) if (d.get("spec") or {}).get("serviceName") == short]
    if not check(len(ests) == 1, f"k8s: one etcd StatefulSet with serviceName {short}", str(len(ests))):
        return
    est = ests[0]
    espec, elabels, epspec = pod_parts(est)
    esel = (espec.get("selector") or {}).get("matchLabels") or {}
    check(labels_match(esel, elabels), f"k8s: StatefulSet {name_of(est)} selector matches template labels",
          f"{esel} vs {elabels}")
    essel = (es.get("spec") or {}).get("selector") or {}
    check(labels_match(essel, elabels) and not labels_match(essel, tlabels),
          f"k8s: Service {short} selects the etcd pods, not the server pods")
    check((es.get("spec") or {}).get("clusterIP") == "None", f"k8s: Service {short} is headless (peer DNS names)")
    check(((epspec.get("securityContext") or {}).get("runAsNonRoot")) is True,
          f"k8s: StatefulSet {name_of(est)} pod securityContext runAsNonRoot")
    ec = next((x for x in epspec.get("containers") or []
               if os.path.basename(str((x.get("command") or [""])[0])) == "etcd"), None)
    if not check(ec is not None, f"k8s: StatefulSet {name_of(est)} runs command etcd"):
        return
    ecmd = [str(a) for a in ec["command"]] + [str(a) for a in ec.get("args", [])]
    ereps = espec.get("replicas", 1)
    members = [x for x in (cmd_value(ecmd, "--initial-cluster") or "").split(",") if x]
    check(isinstance(ereps, int) and ereps % 2 == 1 and len(members) == ereps,
          f"k8s: etcd replicas {ereps} is odd and --initial-cluster lists {len(members)} member(s)",
          str(members))
    ecports = {p.get("name"): p.get("containerPort") for p in ec.get("ports", [])}
    lc = port_of(cmd_value(ecmd, "--listen-client-urls") or "")
    svc_tp = next((sp.get("targetPort", sp.get("port")) for sp in (es.get("spec") or {}).get("ports", [])
                   if sp.get("port") == eport), None)
    check(lc is not None and resolve_port(svc_tp, ecports) == lc,
          f"k8s: Service {short}:{eport} reaches etcd's --listen-client-urls port {lc}",
          f"targetPort {svc_tp} -> {resolve_port(svc_tp, ecports)}")
    dd = cmd_value(ecmd, "--data-dir") or ""
    evct = [(v.get("metadata") or {}).get("name") for v in espec.get("volumeClaimTemplates", [])]
    on_pvc = [mm for mm in ec.get("volumeMounts", []) if mm.get("name") in evct
              and (dd == mm.get("mountPath") or dd.startswith(mm.get("mountPath", "").rstrip("/") + "/"))]
    check(bool(on_pvc), f"k8s: etcd --data-dir {dd or '(unset)'} is on a volumeClaimTemplate",
          f"templates {evct}, mounts {[mm.get('mountPath') for mm in ec.get('volumeMounts', [])]}")
    for pk in ("livenessProbe", "readinessProbe"):
        pr = ec.get(pk) or {}
        how = [k for k in ("httpGet", "tcpSocket", "grpc") if k in pr]
        port = (pr.get(how[0]) or {}).get("port") if how else None
        check(bool(how) and resolve_port(port, ecports) is not None,
              f"k8s: etcd {pk} {how[0] if how else '(none)'} on a container port ({port})",
              "missing or not on a container port (etcdctl is not in the image: use httpGet /health or tcpSocket)")

k8s_files = [p for p in yaml_files if os.path.dirname(p) == paths["k8s"]]
if yaml is not None:
    if all(p in docs for p in k8s_files):
        k8s_checks({p: docs[p] for p in k8s_files})
    else:
        report("FAIL", "k8s: consistency not checked (a manifest does not parse)")
else:
    report("SKIP", "k8s: consistency checks need PyYAML")
    # Only the server's args (the Deployment): the etcd StatefulSet's command is not clnerf-server.
    for p in k8s_files:
        text = open(p, encoding="utf-8").read()
        for doc in re.split(r"(?m)^---\s*$", text):
            if not re.search(r"(?m)^kind:\s*Deployment\s*$", doc) or "clnerf-server" not in doc:
                continue
            for l in doc.splitlines():
                if re.match(r"\s*args:", l):
                    server_args["k8s container command/args"] = facts.get("image", {}).get("entrypoint", []) + flow_list(l)

# ----------------------------------------------------------------- systemd
if os.path.exists(paths["unit"]):
    sect, kv = None, {}
    for l in open(paths["unit"], encoding="utf-8").read().replace("\\\n", " ").splitlines():
        l = l.strip()
        if not l or l.startswith(("#", ";")):
            continue
        if l.startswith("["):
            sect = l.strip("[]")
            continue
        k, _, v = l.partition("=")
        kv.setdefault((sect, k.strip()), []).append(v.strip())
    get = lambda k: (kv.get(("Service", k)) or [None])[-1]
    for k, want in (("Type", "simple"), ("User", "clnerf"), ("StateDirectory", "clnerf"),
                    ("Restart", "on-failure"), ("KillSignal", "SIGTERM"), ("NoNewPrivileges", "true"),
                    ("ProtectSystem", "strict")):
        check(get(k) == want, f"systemd: {k}={want}", f"found {get(k)}")
    t = seconds(get("TimeoutStopSec") or "90")
    check(t is not None and t >= 60, "systemd: TimeoutStopSec >= 60", str(get("TimeoutStopSec")))
    check(any("/etc/clnerf/env" in v for v in kv.get(("Service", "EnvironmentFile"), [])),
          "systemd: EnvironmentFile=-/etc/clnerf/env (CLNERF_TOKEN)")
    ex = get("ExecStart")
    if check(ex is not None, "systemd: ExecStart present"):
        toks = shlex.split(ex.lstrip("-@:+!"))
        check(os.path.basename(toks[0]) == "clnerf-server", "systemd: ExecStart runs clnerf-server", toks[0])
        # $VARS expand at run time; only literal arguments are checked
        server_args["systemd ExecStart"] = [t for t in toks[1:] if not t.startswith("$")]
        store = arg_value(toks, "--store")
        fact("store path", "systemd --store", store)
        fact("store path", "systemd StateDirectory", "/var/lib/" + (get("StateDirectory") or "?"))
        fact("listen port", "systemd --listen", port_of(arg_value(toks, "--listen")))
        rw = " ".join(kv.get(("Service", "ReadWritePaths"), [])).split()
        check(store in rw or any(store and store.startswith(p.rstrip("/") + "/") for p in rw),
              "systemd: ReadWritePaths covers --store", f"{store} not in {rw}")
    sa = shutil.which("systemd-analyze")
    if not sa:
        report("SKIP", "systemd: systemd-analyze verify (systemd-analyze not installed)")
    else:
        rc, out = run([sa, "verify", paths["unit"]], timeout=60)
        lines = [l for l in out.splitlines() if l.strip()]
        absent = [l for l in lines if re.search(r"Command /\S+ is not executable: No such file", l)]
        other = [l for l in lines if l not in absent]
        if other or (rc != 0 and not absent):
            report("FAIL", "systemd: systemd-analyze verify: " + " | ".join(other or [f"exit {rc}"]))
        elif absent:
            report("PASS", "systemd: systemd-analyze verify (only complaint: binary not installed here)")
        else:
            report("PASS", "systemd: systemd-analyze verify")

# ----------------------------------------------------------------- consistency
for name, vals in facts.items():
    if name in ("image",):
        continue
    distinct = {json.dumps(v) for v in vals.values()}
    detail = ", ".join(f"{k}={v}" for k, v in vals.items())
    if name == "health check":
        ok = all(isinstance(v, list) and v[:3] == ["CMD", "clnerf", "info"] for v in vals.values())
        port = facts.get("listen port", {}).get("Dockerfile --listen")
        ok = ok and all(f"localhost:{port}" in v for v in vals.values())
        check(ok, f"consistency: health checks run 'clnerf info --server localhost:{port}'", detail)
    else:
        check(len(distinct) == 1 and None not in vals.values(),
              f"consistency: {name} agrees across {len(vals)} places ({next(iter(vals.values()))})", detail)

# ----------------------------------------------------------------- (c) flags
def help_text(cmd):
    rc, out = run(cmd, timeout=20)
    return out if out.strip() and rc in (0, 1) else None

server = os.environ["CLNERF_SERVER"]
if not os.access(server, os.X_OK):
    report("SKIP", f"flags: no server binary at {server} (set CLNERF_SERVER); --flag check skipped")
    report("SKIP", "flags: client health-check flags not checked (needs the server build)")
else:
    h = help_text([server, "--help"])
    if check(h is not None, f"flags: {server} --help runs"):
        for src, args in server_args.items():
            fl = sorted(set(flags_of(args)))
            bad = [f for f in fl if not re.search(r"(?<![\w-])" + re.escape(f) + r"(?![\w-])", h)]
            check(not bad, f"flags: {src}: {' '.join(fl) or '(none)'} accepted by clnerf-server",
                  "not in --help: " + " ".join(bad))
    client = os.environ["CLNERF_CLIENT"]
    hc = [v for v in facts.get("health check", {}).values() if isinstance(v, list)]
    if not os.access(client, os.X_OK):
        report("SKIP", f"flags: no client binary at {client}; health-check flags not checked")
    elif hc:
        sub = hc[0][2] if len(hc[0]) > 2 else "info"
        h = help_text([client, sub, "--help"])
        fl = sorted(set(flags_of(hc[0])))
        bad = [f for f in fl if h is None or not re.search(r"(?<![\w-])" + re.escape(f) + r"(?![\w-])", h)]
        check(h is not None and not bad, f"flags: health check 'clnerf {sub} {' '.join(fl)}' accepted by the client",
              f"'clnerf {sub} --help' failed" if h is None else "not in --help: " + " ".join(bad))

# ----------------------------------------------------------------- shell
sc = shutil.which("shellcheck")
me = os.path.join(D, "check.sh")
if os.path.exists(me):
    if sc:
        rc, out = run([sc, "-S", "warning", me])
        check(rc == 0, "shell: shellcheck check.sh", out.strip().replace("\n", " | ")[:300])
    else:
        report("SKIP", "shell: shellcheck not installed")

print(f"check.sh: {counts['PASS']} passed, {counts['FAIL']} failed, {counts['SKIP']} skipped ({rel(D)})")
sys.exit(1 if fails else 0)
PY
