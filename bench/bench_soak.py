#!/usr/bin/env python3
"""Soak and fuzz of btfvq-server (issue 21 part 4), both against a real server on loopback.

Soak: CLIENTS threads (default 50, each from its own loopback address 127.0.0.N, so the per-client
connection cap of the default configuration applies to each as it would to 50 users) for
SOAK_SECONDS (default 600) do a mix of what users do: status polls of jobs, job lists, catalogue
listings, database metadata, ranged and whole downloads of database content, event streams (SSE)
of jobs, job submissions of small synthetic samples (`btfvq synth --size 16`, uploaded with PUT
then POST /v1/jobs), cancels, /healthz and /metrics. Every request's latency and outcome is kept;
the server's VmRSS and thread count are sampled every 2 s from /proc. A request fails when it gets
no answer, a 5xx, or a status that was not the one expected (a deliberate 4xx, such as the 404 of an
unknown job or the 409 of cancelling a finished job, is counted apart and is no failure).

Fuzz: FUZZ_REQUESTS (default 30000) requests from a fixed seed, over raw sockets (so that broken
request lines, headers and bodies reach the server as sent), to every route of server/routes.cpp
and beyond: random and junk methods, paths (traversal, very long, percent-encoding junk, NUL),
queries, headers (huge, many, duplicate, bad Content-Length, bad Range and Content-Range, chunked
junk), bodies (random bytes, broken JSON, deep nesting, NaN, huge numbers, almost valid job
requests). Answers are counted by status class; a 5xx, a server exit or a /healthz that does not
answer afterwards is a failure, and the data directory must hold no temporary file afterwards.

Usage: bench_soak.py --bin DIR --json OUT --scratch DIR [--quick] [--soak-seconds S] [--clients N]
       [--fuzz-requests N] [--seed S] [--only soak|fuzz]
With --strict the exit status is 1 when the acceptance of issue 21 part 4 is not met (the section is
written either way).
"""
import argparse
import http.client
import json
import os
import random
import re
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PRESETS = ["wool", "fabric", "leather", "wood", "tile", "corduroy", "foil"]


# ------------------------------------------------------------------------------------------ server
class Server:
    def __init__(self, bin_dir, data, log, config=None):
        args = [str(Path(bin_dir) / "btfvq-server"), "--listen", "127.0.0.1:0", "--data", str(data), "--workers", "1"]
        if config:
            args += ["--config", str(config)]
        self.log_path = log
        self.log = open(log, "w")
        env = dict(os.environ, BTFVQ_LOG="warn")
        self.proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=self.log, env=env)
        self.port = None
        until = time.time() + 30
        while time.time() < until and self.port is None:
            m = re.search(r"listening on http://127\.0\.0\.1:(\d+)", Path(log).read_text())
            if m:
                self.port = int(m.group(1))
            elif self.proc.poll() is not None:
                raise RuntimeError("btfvq-server exited: " + Path(log).read_text())
            time.sleep(0.05)
        if self.port is None:
            raise RuntimeError("btfvq-server did not say where it listens")
        self.data = Path(data)

    def proc_status(self):
        fields = {}
        try:
            for line in open(f"/proc/{self.proc.pid}/status"):
                k, _, v = line.partition(":")
                fields[k] = v.strip()
        except OSError:
            return None
        return {"rss_kb": int(fields["VmRSS"].split()[0]), "threads": int(fields["Threads"])}

    def alive(self):
        return self.proc.poll() is None

    def healthz(self, timeout=5):
        try:
            c = http.client.HTTPConnection("127.0.0.1", self.port, timeout=timeout)
            c.request("GET", "/healthz")
            r = c.getresponse()
            r.read()
            c.close()
            return r.status == 200
        except OSError:
            return False

    def stop(self):
        if self.alive():
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.log.close()
        return self.proc.returncode


def stray_files(data):
    """Temporary files left in the data directory (names of data_dir.h: .<name>.tmp-<pid>-<n>.<ext>)."""
    return [str(p.relative_to(data)) for p in Path(data).rglob("*") if p.is_file() and ".tmp-" in p.name]


def percentile(values, q):
    if not values:
        return None
    v = sorted(values)
    return v[min(len(v) - 1, int(round(q / 100 * (len(v) - 1))))]


# -------------------------------------------------------------------------------------------- soak
class Soak:
    def __init__(self, server, clients, seconds, samples, seed, submit_every, cancel_every):
        self.s = server
        self.clients = clients
        self.seconds = seconds
        self.samples = samples  # [(preset, bytes, sha256)]
        self.rng = random.Random(seed)
        self.submit_every = submit_every
        self.cancel_every = cancel_every
        self.lock = threading.Lock()
        self.records = []  # (t, kind, latency_s, outcome, status)
        self.failures = []  # first few unexpected outcomes, for the report
        self.jobs = []  # job ids submitted
        self.databases = {}  # name -> (version, size)
        self.next_submit = 0.0
        self.next_cancel = 0.0
        self.submissions = 0
        self.samples_rss = []  # (t, rss_kb, threads)
        self.start = None
        self.stop_at = None
        self.sse_events = 0
        self.bytes_downloaded = 0

    def record(self, kind, t0, outcome, status, detail=""):
        t1 = time.perf_counter()
        with self.lock:
            self.records.append((t0 - self.start, kind, t1 - t0, outcome, status))
            if outcome == "failed" and len(self.failures) < 20:
                self.failures.append(f"{kind}: {status} {detail}"[:300])

    # One request on a kept-alive connection; a broken connection is opened again once (the
    # server closes idle connections after http_idle_timeout_s, which is no failure).
    def request(self, conn_box, method, path, body=None, headers=None):
        for attempt in range(2):
            if conn_box[0] is not None and time.time() - conn_box[2] > 4:
                conn_box[0].close()  # the server closes it after http_idle_timeout_s (5 s) anyway
                conn_box[0] = None
            if conn_box[0] is None:
                conn_box[0] = http.client.HTTPConnection("127.0.0.1", self.s.port, timeout=60,
                                                         source_address=(conn_box[1], 0))
            c = conn_box[0]
            try:
                c.request(method, path, body=body, headers=headers or {})
                r = c.getresponse()
                data = r.read()
                conn_box[2] = time.time()
                if r.getheader("Connection", "").lower() == "close":
                    c.close()
                    conn_box[0] = None
                return r.status, data, r
            except (http.client.RemoteDisconnected, BrokenPipeError, ConnectionResetError) as e:
                c.close()
                conn_box[0] = None
                if attempt == 1 or not (isinstance(e, http.client.RemoteDisconnected) or body is None):
                    raise
        raise RuntimeError("unreachable")

    def timed(self, conn_box, kind, method, path, expect, deliberate=(), body=None, headers=None):
        t0 = time.perf_counter()
        try:
            status, data, r = self.request(conn_box, method, path, body, headers)
        except Exception as e:  # no answer at all
            self.record(kind, t0, "failed", "exception", repr(e))
            return None, None, None
        if status in expect:
            self.record(kind, t0, "ok", status)
        elif status in deliberate:
            self.record(kind, t0, "deliberate_4xx", status)
        else:
            self.record(kind, t0, "failed", status, f"{method} {path} {data[:200]!r}")
        return status, data, r

    def pick_job(self, rng):
        with self.lock:
            return rng.choice(self.jobs) if self.jobs else None

    def pick_db(self, rng):
        with self.lock:
            return rng.choice(list(self.databases.items())) if self.databases else (None, None)

    def refresh_databases(self, data):
        try:
            dbs = json.loads(data)["databases"]
        except (ValueError, KeyError):
            return
        with self.lock:
            for d in dbs:
                self.databases[d["name"]] = (d["version"], d["size"])

    def submit(self, conn_box, rng):
        preset, blob, sha = rng.choice(self.samples)
        with self.lock:
            self.submissions += 1
            n = self.submissions
        upload = f"soak{n}-{preset}"
        st, _, _ = self.timed(conn_box, "upload", "PUT", f"/v1/uploads/{upload}", (201,), body=blob,
                              headers={"X-Sha256": sha, "Content-Type": "application/zip"})
        if st != 201:
            return
        db = f"soak-{'abc'[n % 3]}"
        body = json.dumps({"database": db, "materials": [{"name": f"m{n}", "source": {"upload": upload}}]})
        st, data, _ = self.timed(conn_box, "submit", "POST", "/v1/jobs", (202,), body=body,
                                 headers={"Content-Type": "application/json"})
        if st == 202:
            with self.lock:
                self.jobs.append(json.loads(data)["id"])

    def events(self, rng, address):
        job = self.pick_job(rng)
        if job is None:
            return
        t0 = time.perf_counter()
        try:
            c = http.client.HTTPConnection("127.0.0.1", self.s.port, timeout=60, source_address=(address, 0))
            c.request("GET", f"/v1/jobs/{job}/events", headers={"Accept": "text/event-stream"})
            r = c.getresponse()
            if r.status != 200:
                r.read()
                self.record("events", t0, "failed", r.status)
                c.close()
                return
            first = r.fp.readline()  # "event: ..." or ": keep-alive"
            self.record("events", t0, "ok" if first else "failed", 200, "empty stream")
            # Follow the stream for a while (until its end event, or up to 30 s), as `btfvq watch` does.
            until = time.time() + rng.uniform(2, 30)
            n = 1 if first.startswith(b"event:") else 0
            while time.time() < until and time.time() < self.stop_at:
                line = r.fp.readline()
                if not line:
                    break
                if line.startswith(b"event:"):
                    n += 1
                    if line.startswith(b"event: end"):
                        r.fp.readline()
                        break
            with self.lock:
                self.sse_events += n
            c.close()
        except Exception as e:
            self.record("events", t0, "failed", "exception", repr(e))

    def client(self, index):
        rng = random.Random(self.rng.random() + index)
        address = f"127.0.0.{2 + index}"
        box = [None, address, 0.0]
        while time.time() < self.stop_at:
            now = time.time()
            with self.lock:
                do_submit = now >= self.next_submit
                if do_submit:
                    self.next_submit = now + self.submit_every
                do_cancel = not do_submit and now >= self.next_cancel and self.jobs
                if do_cancel:
                    self.next_cancel = now + self.cancel_every
            if do_submit:
                self.submit(box, rng)
            elif do_cancel:
                with self.lock:
                    job = rng.choice(self.jobs[-4:])
                self.timed(box, "cancel", "DELETE", f"/v1/jobs/{job}", (202,), deliberate=(409,))
            else:
                x = rng.random()
                if x < 0.40:
                    job = self.pick_job(rng)
                    if job:
                        self.timed(box, "status", "GET", f"/v1/jobs/{job}", (200,))
                elif x < 0.45:
                    self.timed(box, "jobs", "GET", "/v1/jobs", (200,))
                elif x < 0.55:
                    st, data, _ = self.timed(box, "databases", "GET", "/v1/databases", (200,))
                    if st == 200:
                        self.refresh_databases(data)
                elif x < 0.62:
                    name, _ = self.pick_db(rng)
                    if name:
                        self.timed(box, "database", "GET", f"/v1/databases/{name}", (200,))
                elif x < 0.78:
                    name, vs = self.pick_db(rng)
                    if name:
                        version, size = vs
                        if rng.random() < 0.05:  # deliberately past the end
                            self.timed(box, "range", "GET", f"/v1/databases/{name}/content?version={version}",
                                       (), deliberate=(416,), headers={"Range": f"bytes={size + 10}-"})
                        else:
                            a = rng.randrange(size)
                            b = min(size - 1, a + rng.randrange(1, 256 << 10))
                            st, data, _ = self.timed(box, "range", "GET", f"/v1/databases/{name}/content?version={version}",
                                                     (206,), headers={"Range": f"bytes={a}-{b}"})
                            if st == 206:
                                with self.lock:
                                    self.bytes_downloaded += len(data)
                elif x < 0.80:
                    name, vs = self.pick_db(rng)
                    if name:
                        st, data, _ = self.timed(box, "download", "GET", f"/v1/databases/{name}/content", (200,))
                        if st == 200:
                            with self.lock:
                                self.bytes_downloaded += len(data)
                elif x < 0.85:
                    self.events(rng, address)
                elif x < 0.90:
                    self.timed(box, "healthz", "GET", "/healthz", (200,))
                elif x < 0.93:
                    self.timed(box, "metrics", "GET", "/metrics", (200,))
                elif x < 0.97:
                    self.timed(box, "not_found", "GET", f"/v1/jobs/j{rng.getrandbits(60):015x}", (), deliberate=(404,))
                else:
                    self.timed(box, "not_found", "GET", f"/v1/databases/nope{rng.randrange(99)}/content", (),
                               deliberate=(404,))
            time.sleep(rng.expovariate(1 / 0.25))  # think time, mean 0.25 s
        if box[0]:
            box[0].close()

    def sampler(self):
        while time.time() < self.stop_at + 1:
            st = self.s.proc_status()
            if st:
                self.samples_rss.append((time.time() - self.wall_start, st["rss_kb"], st["threads"]))
            time.sleep(2)

    def run(self):
        self.start = time.perf_counter()
        self.wall_start = time.time()
        self.stop_at = self.wall_start + self.seconds
        threads = [threading.Thread(target=self.client, args=(i,), daemon=True) for i in range(self.clients)]
        sampler = threading.Thread(target=self.sampler, daemon=True)
        sampler.start()
        for t in threads:
            t.start()
            time.sleep(0.02)
        for t in threads:
            t.join(self.seconds + 120)
        sampler.join(10)
        hung = sum(t.is_alive() for t in threads)
        return hung


def job_states(port):
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    c.request("GET", "/v1/jobs")
    jobs = json.loads(c.getresponse().read())["jobs"]
    c.close()
    out = {}
    for j in jobs:
        out[j["state"]] = out.get(j["state"], 0) + 1
    return out


def run_soak(a, bin_dir, scratch):
    samples = []
    for i, preset in enumerate(["wool", "fabric", "leather", "wood"]):
        z = scratch / f"{preset}16.zip"
        subprocess.run([str(bin_dir / "btfvq"), "synth", "--preset", preset, "--size", str(a.sample_size), "--seed",
                        str(i + 1), "--out", str(z)], check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        blob = z.read_bytes()
        import hashlib
        samples.append((preset, blob, hashlib.sha256(blob).hexdigest()))
    data = scratch / "soak-data"
    server = Server(bin_dir, data, scratch / "soak-server.log")
    try:
        # One database to download from when the clients start: a first job, waited for.
        soak = Soak(server, a.clients, a.soak_seconds, samples, a.seed, a.submit_every, a.cancel_every)
        soak.start = time.perf_counter()
        box = [None, "127.0.0.1", 0.0]
        soak.submit(box, random.Random(a.seed))
        t0 = time.time()
        while time.time() - t0 < 600:
            st, data_, _ = soak.request(box, "GET", f"/v1/jobs/{soak.jobs[0]}")
            if json.loads(data_)["state"] in ("succeeded", "failed", "cancelled"):
                break
            time.sleep(0.5)
        first_job_s = time.time() - t0
        st, data_, _ = soak.request(box, "GET", "/v1/databases")
        soak.refresh_databases(data_)
        if box[0]:
            box[0].close()
        soak.records.clear()
        idle = server.proc_status()
        load_before = os.getloadavg()
        hung = soak.run()
        alive = server.alive()
        healthy = server.healthz()
        states = job_states(server.port) if healthy else {}
        after = server.proc_status()
        load_after = os.getloadavg()
    finally:
        code = server.stop()
    internal = [l for l in Path(server.log_path).read_text().splitlines() if "internal error" in l][:5]
    return summarize_soak(a, soak, first_job_s, idle, after, alive, healthy, hung, states, code, internal,
                          stray_files(data), load_before, load_after)


def summarize_soak(a, soak, first_job_s, idle, after, alive, healthy, hung, states, code, internal, stray,
                   load_before, load_after):
    kinds = {}
    for t, kind, lat, outcome, status in soak.records:
        k = kinds.setdefault(kind, {"n": 0, "ok": 0, "deliberate_4xx": 0, "failed": 0, "lat": []})
        k["n"] += 1
        k[outcome] += 1
        k["lat"].append(lat)
    table = {}
    for kind, k in sorted(kinds.items(), key=lambda kv: -kv[1]["n"]):
        table[kind] = {"requests": k["n"], "ok": k["ok"], "deliberate_4xx": k["deliberate_4xx"], "failed": k["failed"],
                       "p50_ms": percentile(k["lat"], 50) * 1e3, "p95_ms": percentile(k["lat"], 95) * 1e3,
                       "p99_ms": percentile(k["lat"], 99) * 1e3, "max_ms": max(k["lat"]) * 1e3}
    total = len(soak.records)
    failed = sum(k["failed"] for k in table.values())
    deliberate = sum(k["deliberate_4xx"] for k in table.values())

    # The resident memory of a minute is the median of its samples: a compression job running at one
    # sampling moment holds a few hundred MiB for seconds, which says nothing about a leak.
    def minute(first, last):
        v = [s for s in soak.samples_rss if first <= s[0] < last] or [min(soak.samples_rss, key=lambda s: abs(s[0] - last))]
        return (0.5 * (first + last), percentile([s[1] for s in v], 50), len(v), min(s[1] for s in v), max(s[1] for s in v))

    m2 = minute(a.soak_seconds * 0.1, a.soak_seconds * 0.2)  # the 2nd minute of 10
    m10 = minute(a.soak_seconds * 0.9, a.soak_seconds + 1)    # the 10th
    growth = (m10[1] - m2[1]) / m2[1] * 100
    growth_min = (m10[3] - m2[3]) / m2[3] * 100  # of the lowest sample of each minute (between jobs)
    peak_threads = max(s[2] for s in soak.samples_rss)
    return {"clients": a.clients, "seconds": a.soak_seconds, "requests": total, "failed": failed,
            "deliberate_4xx": deliberate, "per_kind": table, "failures": soak.failures,
            "rss_kb": {"idle_before": idle["rss_kb"], "minute_2": m2[1], "end": m10[1], "peak": max(s[1] for s in soak.samples_rss),
                       "t_minute_2": m2[0], "t_end": m10[0], "minute_2_range": [m2[3], m2[4]], "end_range": [m10[3], m10[4]],
                       "minute_2_samples": m2[2], "end_samples": m10[2]},
            "rss_growth_pct": growth, "rss_growth_of_minimum_pct": growth_min, "threads": {"idle_before": idle["threads"], "peak": peak_threads,
                                                  "end": after["threads"] if after else None},
            "rss_series": [(round(t, 1), r, th) for t, r, th in soak.samples_rss[::5]],
            "submissions": soak.submissions, "job_states": states, "first_job_s": first_job_s,
            "sse_events": soak.sse_events, "bytes_downloaded": soak.bytes_downloaded,
            "server_alive": alive, "healthz_after": healthy, "hung_clients": hung, "exit_code": code,
            "internal_errors_logged": internal, "stray_files": stray, "load_before": load_before,
            "load_after": load_after, "sample_size": a.sample_size,
            "submit_every_s": a.submit_every, "cancel_every_s": a.cancel_every}


# -------------------------------------------------------------------------------------------- fuzz
ROUTES = [  # (method, path template) from server/routes.cpp
    ("GET", "/healthz"), ("GET", "/v1/healthz"), ("GET", "/metrics"), ("GET", "/v1/metrics"),
    ("POST", "/v1/jobs"), ("GET", "/v1/jobs"), ("GET", "/v1/jobs/{job}"), ("DELETE", "/v1/jobs/{job}"),
    ("GET", "/v1/jobs/{job}/events"), ("PUT", "/v1/uploads/{upload}"), ("GET", "/v1/uploads/{upload}"),
    ("GET", "/v1/databases"), ("GET", "/v1/databases/{db}"),
    ("GET", "/v1/databases/{db}/materials/{material}/preview.png"), ("GET", "/v1/databases/{db}/content"),
]
METHODS = ["GET", "POST", "PUT", "DELETE", "HEAD", "OPTIONS", "PATCH", "TRACE", "CONNECT", "PRI", "get", "Get",
           "PROPFIND", "GET GET", "", "\x00", "G\rET", "A" * 300, "*", "POST\t"]


class Fuzzer:
    def __init__(self, port, seed, known):
        self.port = port
        self.rng = random.Random(seed)
        self.known = known  # {"job": [...], "upload": [...], "db": [...], "material": [...]}

    def junk(self, n):
        return bytes(self.rng.getrandbits(8) for _ in range(n))

    def segment(self, kind):
        r = self.rng
        x = r.random()
        if x < 0.35 and self.known.get(kind):
            return r.choice(self.known[kind])
        choices = ["..", "%2e%2e", "..%2f..%2fetc%2fpasswd", "%2F", "%00", "a%00b", "%zz", "%", "%%41", "%c0%af", "~",
                   "a" * r.choice([64, 65, 1000, 70000]), "s" + "0" * 32, "x" * 8, "%E2%80%AE", "\u00e9".encode().decode("latin-1"),
                   "CON", "-", ".", ".hidden", "a.b", "j" + "f" * 15, "..\\..\\", "%2e%2e%5c", "a;b", "a b", "a\tb",
                   "a?b", "a#b", "%ff%fe", "%0d%0aX-Injected:%201", "*", "{id}", "null", "0", "-1", "1e309"]
        return r.choice(choices)

    def path(self):
        r = self.rng
        method, tmpl = r.choice(ROUTES)
        p = re.sub(r"\{(\w+)\}", lambda m: self.segment(m.group(1)), tmpl)
        x = r.random()
        if x < 0.08:
            p = p.replace("/v1/", r.choice(["/v1//", "//v1/", "/V1/", "/v2/", "/v1/../v1/", "/./v1/", "/v1/%2e/"]))
        elif x < 0.12:
            p += r.choice(["/", "//", "/..", "/extra", "%00", ".json", "?" * 5])
        elif x < 0.16:
            p = "/" + "/".join(self.segment("job") for _ in range(r.randrange(1, 8)))
        elif x < 0.18:
            p = r.choice(["*", "", "http://127.0.0.1/healthz", "healthz", "/" + "a/" * 5000, "/%", "/\x7f",
                          "/v1/jobs/" + "%41" * 20000])
        if r.random() < 0.35:
            params = []
            for _ in range(r.randrange(1, 4)):
                k = r.choice(["version", "size", "light", "scene", "env", "x", "", "version[]", "%zz"])
                v = r.choice(["1", "0", "-1", "2", "99999999999999999999999", "1e3", "NaN", "nan", "inf", "-inf",
                              "1.5", "0x10", "", "abc", "%00", "45,135", "nan,nan", "1e308,1e308", "90,", ",",
                              "-90,-720", "sphere", "plane", "cube", "16", "15", "2048", "2049", "999999", "1", "0"])
                params.append(f"{k}={v}" if r.random() < 0.9 else k)
            p += "?" + "&".join(params)
        return method, p

    def body(self, method, path):
        r = self.rng
        x = r.random()
        if method in ("GET", "DELETE", "HEAD") and x < 0.7:
            return b""
        if x < 0.12:
            return self.junk(r.choice([1, 10, 100, 5000, 70000]))
        if x < 0.2:
            depth = r.choice([100, 1000, 10000, 100000, 500000])
            o, c = r.choice([("[", "]"), ('{"a":', "}")])
            return (o * depth + "1" + c * (depth if r.random() < 0.5 else depth // 2)).encode()
        if x < 0.28:
            return r.choice([b"{", b"}", b"[", b'{"database":', b'{"database": "x", "materials": [', b"null", b"true",
                             b"0", b'""', b"NaN", b'{"a": NaN}', b'{"a": Infinity}', b"1e999999", b"-1e400",
                             b'{"database": "db", "materials": []}', b"\xef\xbb\xbf{}", b'{"\x00": 1}',
                             b'"\\ud800"', b'{"a": "\\u0000"}', b"[" + b"1," * 100000 + b"1]",
                             b'{"a":' + b"9" * 5000 + b"}"])
        # an almost valid job request
        size = r.choice([4, 8, 0, -1, 3, 2049, 1e20, 1e400, "8", None, 8.5, True, [], {}, -0.0, 2 ** 64])
        seed = r.choice([0, 1, -1, 2 ** 53, 2 ** 53 + 1, 2 ** 64, 1.5, "1", None, 1e300])
        preset = r.choice(PRESETS + ["", "nope", "../wool", "wool\x00", 7, None])
        source = r.choice([
            {"synthetic": {"preset": preset, "size": size, "seed": seed}},
            {"upload": r.choice(self.known.get("upload", []) + ["nope", "", "../../x", 5, None])},
            {"path": r.choice(["/etc/passwd", "../../etc", "", "a.zip", 5, None, "x" * 5000])},
            {}, {"synthetic": {}, "upload": "x"}, None, "wool", [],
        ])
        m = {"source": source}
        if r.random() < 0.5:
            m["name"] = r.choice(["a", "", "../x", "x" * 65, "x" * 64, "a b", "é", None, 5, "m1", "CON"])
        if r.random() < 0.2:
            m["extra"] = 1
        req = {"database": r.choice(self.known.get("db", []) + ["fz", "", "../x", "a" * 65, "a/b", None, 5, ".x", "x\x00"]),
               "materials": r.choice([[m], [m, m], [], None, m, [None], [m] * 50])}
        if r.random() < 0.3:
            req["pipeline"] = r.choice([{"grid": {"n_beta": r.choice([11, 0, -5, 1e9, "x", None, float("nan")])}},
                                        {"nope": 1}, [], None, {"grid": []}, {"grid": {"nope": 1}}, 5])
        if r.random() < 0.2:
            req["quality"] = r.choice([50, -1, 101, float("nan"), float("inf"), "50", None, 1e308])
        if r.random() < 0.1:
            req["target_mssim"] = r.choice([0.9, 0, 1, float("nan"), -1, "x"])
        if r.random() < 0.1:
            req[r.choice(["id", "state", "", "x" * 1000])] = 1
        try:
            # NaN, Infinity: Python writes them, JSON does not allow them; the server must say 400.
            return json.dumps(req).encode()
        except (TypeError, ValueError, OverflowError):
            return b"{}"

    def headers(self, method, path, body):
        r = self.rng
        h = [("Host", "127.0.0.1")]
        cl = str(len(body))
        x = r.random()
        if x < 0.55:
            if body or method in ("POST", "PUT"):
                h.append(("Content-Length", cl))
        elif x < 0.6:
            h.append(("Content-Length", r.choice(["-1", "abc", "99999999999999999999999", "1e3", " 5", "0x10", "",
                                                  str(len(body) + 1000), str(max(0, len(body) - 3)), "+5"])))
        elif x < 0.63:
            h += [("Content-Length", cl), ("Content-Length", str(len(body) + 7))]
        elif x < 0.68:
            h.append(("Transfer-Encoding", "chunked"))
            if r.random() < 0.5 and body:
                body = b"%x\r\n" % len(body) + body + b"\r\n0\r\n\r\n"
            else:
                body = r.choice([b"zz\r\nabc\r\n0\r\n\r\n", b"ffffffffffffffffff\r\nab\r\n", b"5\r\nab", b"-1\r\n\r\n",
                                 b"0\r\n\r\n", b"3;ext=1\r\nabc\r\n0\r\nTrailer: x\r\n\r\n"])
            if r.random() < 0.3:
                h.append(("Content-Length", cl))
        elif x < 0.7:
            h.append(("Transfer-Encoding", r.choice(["gzip", "chunked, gzip", "identity", "x"])))
        for _ in range(r.choice([0, 0, 1, 2, 3])):
            y = r.random()
            if y < 0.2:
                h.append(("Range", r.choice(["bytes=0-10", "bytes=-5", "bytes=5-", "bytes=5-1", "bytes=-0", "bytes=0-0",
                                             "bytes=99999999999999999999-", "bytes=0-99999999999999999999999",
                                             "bytes=1-2,3-4,5-6", "bytes=" + ",".join(["0-1"] * 2000), "bytes=",
                                             "bytes=a-b", "items=0-5", "bytes=--5", "bytes=-", "bytes=0-10, 5-15",
                                             "bytes=18446744073709551615-", "bytes=-18446744073709551616"])))
            elif y < 0.35:
                h.append(("Content-Range", r.choice(["bytes 0-9/10", "bytes 0-0/1", "bytes 5-4/10", "bytes 0-9/*",
                                                     "bytes 0-99999999999999999999/1", "bytes 10-19/20", "bytes x-y/z",
                                                     "bytes 0-9/99999999999999999999", "bytes 0-" + str(len(body) - 1) + "/" + str(len(body) * 2 + 1),
                                                     "bytes -1-9/10", "bytes 0-9/10/11", ""])))
            elif y < 0.45:
                h.append(("X-Sha256", r.choice(["0" * 64, "Z" * 64, "", "a" * 1000, "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"])))
            elif y < 0.52:
                h.append(("X-Huge", "a" * r.choice([8000, 70000, 200000])))
            elif y < 0.57:
                h += [(f"X-Many-{i}", "v") for i in range(r.choice([100, 1000, 5000]))]
            elif y < 0.62:
                h.append(("Authorization", r.choice(["Bearer ", "Bearer x", "Basic Zm9vOmJhcg==", "\x00"])))
            elif y < 0.67:
                h.append(("If-None-Match", r.choice(['"x"', "*", "", '"' + "0" * 64 + '"'])))
            elif y < 0.72:
                h.append(("Expect", "100-continue"))
            elif y < 0.77:
                h.append(("Accept", r.choice(["text/event-stream", "*/*", "\xff"])))
            elif y < 0.82:
                h.append((r.choice(["", " ", "X Bad", "X:Colon", "\x00", "Content-Length "]), "v"))
            elif y < 0.87:
                h.append(("Connection", r.choice(["keep-alive", "close", "upgrade", "Upgrade, HTTP2-Settings"])))
            else:
                h.append(("X-Junk", self.junk(r.randrange(1, 50)).decode("latin-1")))
        return h, body

    def request(self):
        r = self.rng
        method, path = self.path()
        if r.random() < 0.2:
            method = r.choice(METHODS)
        body = self.body(method, path)
        headers, body = self.headers(method, path, body)
        version = r.choice(["HTTP/1.1"] * 12 + ["HTTP/1.0", "HTTP/2.0", "HTTP/1.1 x", "HTTP/9.9", "", "http/1.1"])
        line = f"{method} {path} {version}".rstrip() if version else f"{method} {path}"
        if not any(k.lower() == "connection" for k, _ in headers):
            headers.append(("Connection", "close"))
        raw = (line + "\r\n" + "".join(f"{k}: {v}\r\n" if r.random() > 0.01 else f"{k}{v}\r\n" for k, v in headers)
               + "\r\n").encode("latin-1", "replace") + body
        if r.random() < 0.03:  # cut off mid-request
            raw = raw[: r.randrange(1, max(2, len(raw)))]
        return method, path, raw

    def send(self, raw, timeout):
        """The status of the answer (None: closed without one; 'timeout': no answer in time)."""
        s = socket.create_connection(("127.0.0.1", self.port), timeout=timeout)
        try:
            try:
                s.sendall(raw)
            except (BrokenPipeError, ConnectionResetError):
                pass  # the server may answer and close before reading all of it
            try:
                s.shutdown(socket.SHUT_WR)
            except OSError:
                pass
            got = b""
            deadline = time.time() + timeout
            while time.time() < deadline:
                m = re.match(rb"HTTP/1\.[01] (\d{3})[^\r\n]*\r\n", got)
                if m and m.group(1).startswith(b"1"):  # an interim 100 Continue: the answer follows
                    end = got.find(b"\r\n\r\n")
                    if end >= 0:
                        got = got[end + 4:]
                        continue
                elif m:
                    return int(m.group(1))
                elif b"\r\n" in got:
                    return None
                try:
                    chunk = s.recv(4096)
                except socket.timeout:
                    return "timeout"
                except ConnectionResetError:
                    break
                if not chunk:
                    break
                got += chunk
            m = re.match(rb"HTTP/1\.[01] (\d{3})", got)
            if m and not m.group(1).startswith(b"1"):
                return int(m.group(1))
            return None if time.time() < deadline else "timeout"
        finally:
            s.close()


def run_fuzz(a, bin_dir, scratch):
    data = scratch / "fuzz-data"
    server = Server(bin_dir, data, scratch / "fuzz-server.log")
    classes = {"1xx": 0, "2xx": 0, "3xx": 0, "4xx": 0, "5xx": 0, "no_answer": 0, "timeout": 0}
    statuses, five = {}, []
    t0 = time.time()
    crashed = None
    try:
        # Something to find: one database with a material, one upload, two jobs.
        c = http.client.HTTPConnection("127.0.0.1", server.port, timeout=120)
        zip_path = scratch / "fuzz-sample.zip"
        subprocess.run([str(bin_dir / "btfvq"), "synth", "--preset", "wool", "--size", "8", "--seed", "1", "--out",
                        str(zip_path)], check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        c.request("PUT", "/v1/uploads/fz1", body=zip_path.read_bytes())
        c.getresponse().read()
        c.request("POST", "/v1/jobs", body=json.dumps({"database": "fzdb", "materials": [
            {"name": "wool8", "source": {"upload": "fz1"}}]}))
        job = json.loads(c.getresponse().read())["id"]
        while True:
            c.request("GET", f"/v1/jobs/{job}")
            if json.loads(c.getresponse().read())["state"] in ("succeeded", "failed", "cancelled"):
                break
            time.sleep(0.5)
        c.close()
        known = {"job": [job], "upload": ["fz1"], "db": ["fzdb"], "material": ["wool8"]}
        fuzzer = Fuzzer(server.port, a.seed, known)
        n = 0
        deadline = t0 + a.fuzz_max_seconds
        previous = b""
        crashes, silent = [], []
        while n < a.fuzz_requests and time.time() < deadline:
            method, path, raw = fuzzer.request()
            try:
                st = fuzzer.send(raw, timeout=a.fuzz_timeout)
            except OSError as e:
                st = None
            if not server.alive():
                # The request that got no answer, or the one before it (an exit between two requests).
                crashed = (f"server exited ({server.proc.returncode}) at request {n}: {raw[:300]!r} "
                           f"(the one before: {previous[:300]!r}); log: {Path(server.log_path).read_text()[-300:]!r}")
                crashes.append(crashed)
                print("bench_soak: " + crashed, file=sys.stderr)
                if not a.fuzz_restart:
                    break
                server.stop()
                server = Server(bin_dir, data, scratch / f"fuzz-server.{len(crashes)}.log")
                fuzzer.port = server.port
            previous = raw
            n += 1
            if st == "timeout":
                classes["timeout"] += 1
            elif st is None:
                classes["no_answer"] += 1
                if len(silent) < 40:
                    silent.append(raw[:160])
            else:
                classes[f"{st // 100}xx"] += 1
                statuses[st] = statuses.get(st, 0) + 1
                if st >= 500 and len(five) < 20:
                    five.append(f"{st}: {raw[:300]!r}")
            if n % 2000 == 0:
                print(f"bench_soak: fuzz {n} requests, {classes}", file=sys.stderr)
        seconds = time.time() - t0
        alive = server.alive()
        healthy = server.healthz(10)
        st = server.proc_status()
    finally:
        code = server.stop()
    internal = [l for l in Path(server.log_path).read_text().splitlines() if "internal error" in l][:5]
    return {"requests": n, "seed": a.seed, "crashes": crashes, "no_answer_examples": [repr(x) for x in silent], "seconds": seconds, "classes": classes,
            "statuses": {str(k): v for k, v in sorted(statuses.items())}, "five_xx": five,
            "crashed": crashed, "server_alive": alive, "healthz_after": healthy, "exit_code": code,
            "threads_end": st["threads"] if st else None, "rss_kb_end": st["rss_kb"] if st else None,
            "internal_errors_logged": internal, "stray_files": stray_files(data), "timeout_s": a.fuzz_timeout}


# ---------------------------------------------------------------------------------------- report
def markdown(a, soak, fuzz, others):
    md = []
    ok = True
    if soak:
        s = soak
        md += [f"**Soak**: {s['clients']} clients (each from its own loopback address 127.0.0.2..) for {s['seconds'] / 60:.0f} "
               f"minutes against one btfvq-server (default configuration, `--workers 1`, fresh data directory), each "
               "client repeating a random request after a think time of mean 0.25 s: status polls of submitted jobs (40%), "
               "ranged downloads of database content (16%; 5% of them deliberately past the end: 416), catalogue listings "
               "(10%) and database metadata (7%), SSE event streams followed 2-30 s or to their end (5%), /healthz (5%), "
               "job lists (5%), unknown jobs and databases (7%, deliberate 404), /metrics (3%), whole downloads (2%); "
               f"plus one job submission every {s['submit_every_s']:.0f} s (a `btfvq synth --size {s['sample_size']}` sample "
               f"of wool, fabric, leather or wood uploaded by PUT, then POST /v1/jobs into one of three databases) and a "
               f"cancel of one of the last 4 jobs every {s['cancel_every_s']:.0f} s (409 when it had finished: deliberate). "
               f"Latency is from sending the request to the end of the answer's body (for event streams: to the first "
               f"event), measured by the Python clients (bench/bench_soak.py, stdlib http.client, one kept-alive "
               f"connection per client), which share the 2 cores with the server and its compressions.", "",
               "| request | count | ok | deliberate 4xx | failed | p50 ms | p95 ms | p99 ms | max ms |",
               "|---|---|---|---|---|---|---|---|---|"]
        for kind, k in s["per_kind"].items():
            md.append(f"| {kind} | {k['requests']} | {k['ok']} | {k['deliberate_4xx']} | {k['failed']} | "
                      f"{k['p50_ms']:.1f} | {k['p95_ms']:.1f} | {k['p99_ms']:.1f} | {k['max_ms']:.0f} |")
        r = s["rss_kb"]
        md += ["", f"Requests: {s['requests']} ({s['requests'] / s['seconds']:.0f}/s), failed (no answer, 5xx or an "
               f"unexpected status): **{s['failed']}**, deliberate 4xx: {s['deliberate_4xx']}. "
               f"p99 of status polls: **{s['per_kind'].get('status', {}).get('p99_ms', float('nan')):.1f} ms**. "
               f"Jobs: {s['submissions']} submitted, at the end {json.dumps(s['job_states'])}; "
               f"{s['sse_events']} SSE events received, {s['bytes_downloaded'] / 2**20:.0f} MiB of database content.", "",
               f"Server memory (VmRSS, sampled every 2 s; a minute's figure is the median of its samples, since a "
               f"compression job holds a few hundred MiB for seconds): {r['idle_before'] / 1024:.1f} MiB idle before the "
               f"soak (after the first job), **{r['minute_2'] / 1024:.1f} MiB in the 2nd minute "
               f"({r['minute_2_range'][0] / 1024:.0f}-{r['minute_2_range'][1] / 1024:.0f}), {r['end'] / 1024:.1f} MiB in the last "
               f"({r['end_range'][0] / 1024:.0f}-{r['end_range'][1] / 1024:.0f}): growth {s['rss_growth_pct']:+.1f}%** "
               f"(acceptance: at most 10%); of the lowest sample of each minute (between jobs) {s['rss_growth_of_minimum_pct']:+.1f}%; "
               f"peak {r['peak'] / 1024:.1f} MiB. Threads: {s['threads']['idle_before']} idle before, peak "
               f"{s['threads']['peak']}, {s['threads']['end']} at the end (the HTTP threads are created as connections "
               "need them and kept until the server stops, docs/api.md \"Connections\": the count does not shrink "
               "after a burst, but it stays bounded by the connection caps).", "",
               "RSS over time (minute: MiB, threads): " + ", ".join(
                   f"{t / 60:.1f}: {rk / 1024:.0f}, {th}" for t, rk, th in s["rss_series"][:: max(1, len(s["rss_series"]) // 12)]) + ".", "",
               f"After the soak: server alive {s['server_alive']}, /healthz answered {s['healthz_after']}, clients hung "
               f"{s['hung_clients']}, clean exit code {s['exit_code']} on SIGTERM, temporary files left "
               f"{len(s['stray_files'])}, 'internal error' log lines {len(s['internal_errors_logged'])}. Load average "
               f"before {s['load_before'][0]:.1f}, after {s['load_after'][0]:.1f}."]
        if s["failures"]:
            md += ["", "First failures: " + "; ".join(f"`{f}`" for f in s["failures"][:5])]
        ok = ok and s["failed"] == 0 and s["rss_growth_pct"] <= 10 and s["server_alive"] and s["healthz_after"]
    if fuzz:
        f = fuzz
        c = f["classes"]
        md += ["", f"**Fuzz**: {f['requests']} requests in {f['seconds']:.0f} s (seed {f['seed']}), one connection each over "
               "a raw socket, to every route of server/routes.cpp (and beyond): random and junk methods; paths with "
               "traversal, percent-encoding junk, NUL, 70000-character segments, unknown ids and the known ones of a real "
               "database; queries with NaN, inf, huge and negative numbers; headers huge (to 200 kB), many (to 5000), "
               "duplicate or bad Content-Length, chunked junk, bad Range and Content-Range, bad X-Sha256; bodies of random "
               "bytes, broken JSON, nesting 500000 deep, NaN and huge numbers, and almost valid job requests; 3% cut off "
               "mid-request.", "",
               "| answers | 2xx | 3xx | 4xx | 5xx | closed without an answer | no answer in " + f"{f['timeout_s']:.0f} s |",
               "|---|---|---|---|---|---|---|",
               f"| {f['requests']} | {c['2xx']} | {c['3xx']} | {c['4xx']} | **{c['5xx']}** | {c['no_answer']} | {c['timeout']} |",
               "", "Statuses: " + ", ".join(f"{k}: {v}" for k, v in f["statuses"].items()) + ". "
               f"Crashes: **{len(f['crashes'])}**{' (' + f['crashed'][:400] + ')' if f['crashed'] else ''}; after the fuzz "
               f"the server was alive ({f['server_alive']}), /healthz answered ({f['healthz_after']}), it exited with "
               f"{f['exit_code']} on SIGTERM; temporary files left in the data directory: {len(f['stray_files'])}; "
               f"'internal error' log lines: {len(f['internal_errors_logged'])}."]
        if f["five_xx"]:
            md += ["", "5xx answers: " + "; ".join(f"`{x[:200]}`" for x in f["five_xx"][:5])]
        ok = ok and c["5xx"] == 0 and not f["crashed"] and f["server_alive"] and f["healthz_after"] and not f["stray_files"]
    binary = "a RelWithDebInfo build (cmake -DCMAKE_BUILD_TYPE=RelWithDebInfo)" if "build-release" not in a.bin else "the -O3 release build of make bench"
    extra = " ".join(sys.argv[1:])
    extra = re.sub(r"--(json|scratch|testdata|figures|bin) \S+ ?", "", extra).strip()
    md += ["", f"Command: `BENCH_ONLY=bench_soak bash bench/run.sh {a.bin}`{' with `' + extra + '`' if extra else ''} "
           f"({binary} of btfvq-server and btfvq). Busy processes on the machine at the end (other sessions "
           f"compiling and testing on the same 2 cores): {others or 'none'}."]
    return "\n".join(md), ok


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", required=True)
    ap.add_argument("--json", required=True)
    ap.add_argument("--scratch", required=True)
    ap.add_argument("--testdata", default=None)
    ap.add_argument("--figures", default=None)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--soak-seconds", type=float, default=None)
    ap.add_argument("--clients", type=int, default=50)
    ap.add_argument("--sample-size", type=int, default=16)
    ap.add_argument("--submit-every", type=float, default=20)
    ap.add_argument("--cancel-every", type=float, default=45)
    ap.add_argument("--fuzz-requests", type=int, default=None)
    ap.add_argument("--fuzz-max-seconds", type=float, default=900)
    ap.add_argument("--fuzz-timeout", type=float, default=15)
    ap.add_argument("--seed", type=int, default=21)
    ap.add_argument("--fuzz-restart", action="store_true", help="restart a crashed server and go on (to find more bugs in one run)")
    ap.add_argument("--only", choices=["soak", "fuzz"], default=None)
    ap.add_argument("--strict", action="store_true", help="exit 1 when the acceptance is not met")
    a = ap.parse_args()
    if a.soak_seconds is None:
        a.soak_seconds = 60 if a.quick else 600
    if a.fuzz_requests is None:
        a.fuzz_requests = 2000 if a.quick else 30000
    bin_dir = Path(a.bin).resolve()
    scratch = Path(a.scratch)
    scratch.mkdir(parents=True, exist_ok=True)
    fuzz = run_fuzz(a, bin_dir, scratch) if a.only != "soak" else None
    if fuzz:
        print(f"bench_soak: fuzz {json.dumps({k: fuzz[k] for k in ('requests', 'classes', 'crashed')})}", file=sys.stderr)
    soak = run_soak(a, bin_dir, scratch) if a.only != "fuzz" else None
    others = subprocess.run("ps -eo pcpu,args --sort=-pcpu | awk 'NR > 1 && $1 > 5 {print $2}' | xargs -n1 basename "
                            "2>/dev/null | sort | uniq -c | awk '{print $2 \" x\" $1}' | paste -sd, -", shell=True,
                            capture_output=True, text=True).stdout.strip()
    md, ok = markdown(a, soak, fuzz, others)
    json.dump({"title": "HTTP service: soak and fuzz", "order": 90, "markdown": md,
               "figures": {"soak": soak, "fuzz": fuzz, "acceptance_met": ok}}, open(a.json, "w"), indent=1)
    print(md, file=sys.stderr)
    if not ok:
        print("bench_soak: the acceptance of issue 21 part 4 is NOT met (see the section)", file=sys.stderr)
    return 0 if ok or not a.strict else 1


if __name__ == "__main__":
    sys.exit(main())
