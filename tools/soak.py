#!/usr/bin/env python3
"""Soak test of the skybake service: the storms below (abandoned, slow, swapped cache files, jobs), on loopback only, bounded in count and time.

    tools/soak.py [--bin target/release/skybake] [--port 18190] [--quick]

Python 3.8+ standard library only (no packages). Every storm starts a fresh server on 127.0.0.1
with its own cache directory (removed afterwards), and each is bounded: at most STORM_CLIENTS
clients, a per-storm deadline, and a global deadline of DEADLINE_S. Figures are printed as one JSON
object at the end (and each line as it is measured).

Storms
  1. abandoned : the latency of a fresh cold default sky request (new ground albedo) on an idle
                 server; then 12 clients that each ask for a different cold default sky and hang up
                 after 0.5 s (a `curl -m 0.5` storm); then the same fresh request again.
                 Reported: both latencies, their ratio (must be <= 2), cancelled computations.
  2. slow      : 400 connections that send half a request line and stall; reported: how many the
                 server held, how long until it closed them, whether a normal request was answered
                 meanwhile, and how long SIGTERM took to end the server with stalled clients open.
  3. swap      : the sun-23 deg cache file copied over the sun-24 deg one, server restarted:
                 the 24 deg request must be a miss answering 24 deg (key mismatch counted).
  4. jobs      : 30 job bodies of ~980 kB against a 1 MiB disk budget: accepted, refused, bytes of
                 job files on disk, and whether DELETE removed a finished job's files.
  5. slowbody  : 500 uploads (POST /v1/plan, Content-Length 500) trickling one byte a second, from
                 127.0.0.2 and 127.0.0.3 (250 each, under the default per-client cap of 256), with
                 the concurrency limit lowered to 64; meanwhile 300 cached /v1/sun requests one
                 after another from 127.0.0.1. Reported: the cached requests' statuses and latency
                 percentiles (p50, p99, max), the slow uploads' answers (408 expected) and when they
                 came, and a 257th connection from one address (closed at accept).
"""
import argparse
import http.client
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time

HOST = "127.0.0.1"  # loopback only, by construction
DEADLINE_S = 900.0
STORM_CLIENTS = 400
START = time.monotonic()
RESULTS = {}


def left():
    return DEADLINE_S - (time.monotonic() - START)


def report(name, value):
    RESULTS[name] = value
    print(f"{name}: {json.dumps(value)}", flush=True)


class Server:
    def __init__(self, binary, port, env=None, cache=None):
        self.port = port
        self.own_cache = cache is None
        self.cache = cache or tempfile.mkdtemp(prefix="skybake-soak-")
        e = dict(os.environ)
        e = {k: v for k, v in e.items() if not k.startswith("SKYBAKE_")}
        e.update({"SKYBAKE_BIND": f"{HOST}:{port}", "SKYBAKE_CACHE_DIR": self.cache})
        e.update(env or {})
        self.log = open(os.path.join(tempfile.gettempdir(), f"skybake-soak-{port}.log"), "ab")
        self.proc = subprocess.Popen([binary, "serve"], env=e, stdout=self.log, stderr=self.log)
        for _ in range(200):
            try:
                if get(port, "/healthz", timeout=1)[0] == 200:
                    return
            except OSError:
                pass
            time.sleep(0.05)
        raise RuntimeError("server did not start")

    def stop(self, remove=True):
        t0 = time.monotonic()
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.log.close()
        if remove and self.own_cache:
            shutil.rmtree(self.cache, ignore_errors=True)
        return time.monotonic() - t0


def get(port, path, timeout=300, headers=None, method="GET", body=None):
    c = http.client.HTTPConnection(HOST, port, timeout=timeout)
    try:
        c.request(method, path, body=body, headers=headers or {})
        r = c.getresponse()
        data = r.read()
        return r.status, dict(r.getheaders()), data
    finally:
        c.close()


def metric(port, name):
    _, _, text = get(port, "/metrics", timeout=10)
    for line in text.decode().splitlines():
        if line.startswith(name + " "):
            return float(line.split()[1])
    return None


def timed(port, path):
    t0 = time.monotonic()
    status, _, body = get(port, path)
    return status, time.monotonic() - t0, body


def abandon(port, path, after_s):
    """Sends a GET and hangs up after `after_s` without reading (curl -m 0.5)."""
    s = socket.create_connection((HOST, port), timeout=5)
    s.sendall(f"GET {path} HTTP/1.1\r\nHost: {HOST}\r\nConnection: close\r\n\r\n".encode())
    time.sleep(after_s)
    s.close()


def storm_abandoned(binary, port, quick):
    srv = Server(binary, port)
    try:
        n = 4 if quick else 12
        status, idle_s, _ = timed(port, "/v1/sky?ground_albedo=0.301")
        report("abandoned.idle_fresh_request_s", round(idle_s, 2))
        threads = [
            threading.Thread(target=abandon, args=(port, f"/v1/sky?ground_albedo=0.{10 + i}1", 0.5))
            for i in range(n)
        ]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        status2, storm_s, _ = timed(port, "/v1/sky?ground_albedo=0.302")
        report("abandoned.clients", n)
        report("abandoned.fresh_request_after_storm_status", status2)
        report("abandoned.fresh_request_after_storm_s", round(storm_s, 2))
        report("abandoned.latency_ratio", round(storm_s / idle_s, 2))
        report("abandoned.cancelled", metric(port, "skybake_computations_cancelled_total"))
        report("abandoned.in_flight_after", metric(port, "skybake_computations_in_flight"))
    finally:
        srv.stop()


def storm_slow(binary, port, quick):
    timeout_s = 5.0
    srv = Server(binary, port, env={"SKYBAKE_HEADER_READ_TIMEOUT_S": str(timeout_s),
                                    "SKYBAKE_SHUTDOWN_GRACE_S": "5"})
    socks = []
    try:
        n = 50 if quick else STORM_CLIENTS
        for _ in range(n):
            try:
                s = socket.create_connection((HOST, port), timeout=5)
                s.sendall(b"GET /v1/sky?sun_elev")
                socks.append(s)
            except OSError:
                break
        report("slow.connections_opened", len(socks))
        report("slow.connections_open_on_server", metric(port, "skybake_connections_open"))
        status, ok_s, _ = timed(port, "/healthz")
        report("slow.healthz_during_storm", [status, round(ok_s, 3)])
        t0 = time.monotonic()
        closed = 0
        for s in socks:
            s.settimeout(max(1.0, timeout_s * 3 - (time.monotonic() - t0)))
            try:
                if s.recv(1024) is not None:
                    closed += 1
            except OSError:
                pass
        report("slow.closed_by_server", closed)
        report("slow.all_closed_after_s", round(time.monotonic() - t0, 2))
        # SIGTERM with stalled clients open: the shutdown must end within its grace period.
        stalled = []
        for _ in range(20):
            s = socket.create_connection((HOST, port), timeout=5)
            s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")
            stalled.append(s)
        report("slow.sigterm_exit_s", round(srv.stop(), 2))
        for s in stalled:
            s.close()
    finally:
        for s in socks:
            s.close()
        srv.stop()


def storm_swap(binary, port, quick):
    cache = tempfile.mkdtemp(prefix="skybake-soak-swap-")
    try:
        q = "/v1/sun?method=fast&quality=draft&wavelengths=550&sun_elevation_deg="
        srv = Server(binary, port, cache=cache)
        a = get(port, q + "23")
        b = get(port, q + "24")
        key_a, key_b = a[1]["x-skybake-cache-key"], b[1]["x-skybake-cache-key"]
        srv.stop(remove=False)
        paths = {}
        for root, _, files in os.walk(cache):
            for f in files:
                for k in (key_a, key_b):
                    if f.startswith(k):
                        paths[k] = os.path.join(root, f)
        shutil.copyfile(paths[key_a], paths[key_b])
        srv = Server(binary, port, cache=cache)
        status, headers, body = get(port, q + "24")
        answered = json.loads(body).get("sun_elevation_deg")
        report("swap.status", status)
        report("swap.x_cache", headers.get("x-cache"))
        report("swap.answered_sun_elevation_deg", answered)
        report("swap.key_mismatches", metric(port, "skybake_cache_key_mismatches_total"))
        srv.stop(remove=False)
    finally:
        shutil.rmtree(cache, ignore_errors=True)


def storm_jobs(binary, port, quick):
    srv = Server(binary, port, env={"SKYBAKE_DISK_BUDGET_BYTES": str(1 << 20),
                                    "SKYBAKE_MAX_LIVE_JOBS": "1000"})
    try:
        pad = ",".join(f"{i % 80}:{i % 170}" for i in range(4000))
        item = {"product": "sky", "method": "fast", "quality": "draft", "wavelengths": "550",
                "elevation_count": 5, "azimuth_count": 4, "probe": pad}
        # ~980 kB: the same product (4000 probes, the most a request takes) listed 39 times (each
        # a cache hit after the first).
        body = json.dumps({"products": [item] * 39})
        report("jobs.body_bytes", len(body))
        accepted, refused, statuses = [], 0, {}
        for _ in range(6 if quick else 30):
            status, _, data = get(port, "/v1/jobs", method="POST", body=body,
                                  headers={"Content-Type": "application/json"})
            statuses[status] = statuses.get(status, 0) + 1
            if status == 202:
                accepted.append(json.loads(data)["id"])
            else:
                refused += 1
        report("jobs.statuses", statuses)
        on_disk = 0
        for root, _, files in os.walk(os.path.join(srv.cache, "jobs")):
            on_disk += sum(os.path.getsize(os.path.join(root, f)) for f in files)
        report("jobs.bytes_on_disk", on_disk)
        deleted = None
        if accepted:
            jid = accepted[0]
            for _ in range(600):
                st = json.loads(get(port, f"/v1/jobs/{jid}")[2])
                if st["state"] in ("completed", "cancelled"):
                    break
                time.sleep(0.1)
            status, _, data = get(port, f"/v1/jobs/{jid}", method="DELETE")
            deleted = [status, json.loads(data).get("deleted"),
                       os.path.exists(os.path.join(srv.cache, "jobs", jid))]
        report("jobs.delete_finished [status, deleted, dir_still_there]", deleted)
        listing = json.loads(get(port, "/v1/jobs")[2])
        report("jobs.listed", listing["total"])
    finally:
        srv.stop()


def percentile(values, q):
    v = sorted(values)
    return v[min(len(v) - 1, int(round(q * (len(v) - 1))))]


def connect_from(source, port):
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    s.bind((source, 0))
    s.settimeout(5)
    s.connect((HOST, port))
    return s


def storm_slowbody(binary, port, quick):
    srv = Server(binary, port, env={"SKYBAKE_CONCURRENCY_LIMIT": "64"})
    socks = []
    stop = threading.Event()
    try:
        sun = "/v1/sun?method=fast&quality=draft&wavelengths=550"
        if get(port, sun)[0] != 200:
            raise RuntimeError("the cached request failed")
        n = 100 if quick else 500
        head = (b"POST /v1/plan HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                b"Content-Length: 500\r\n\r\n")
        t0 = time.monotonic()
        for i in range(n):
            s = connect_from(f"127.0.0.{2 + i % 2}", port)
            s.sendall(head + b"{")
            socks.append(s)

        def trickle():
            # One byte a second on every slow connection until it is answered.
            while not stop.is_set():
                for s in socks:
                    try:
                        s.send(b" ")
                    except OSError:
                        pass
                stop.wait(1.0)

        feeder = threading.Thread(target=trickle, daemon=True)
        feeder.start()
        report("slowbody.clients", len(socks))
        report("slowbody.connections_open_on_server", metric(port, "skybake_connections_open"))
        # A connection over the per-client cap (256) of one address is closed at accept.
        extra = [connect_from("127.0.0.4", port) for _ in range(257)]
        time.sleep(0.3)
        report("slowbody.client_connections_refused",
               metric(port, "skybake_client_connections_refused_total"))
        for s in extra:
            s.close()
        statuses, lat = {}, []
        for _ in range(60 if quick else 300):
            status, dt, _ = timed(port, sun)
            statuses[status] = statuses.get(status, 0) + 1
            lat.append(dt * 1e3)
        report("slowbody.cached_statuses", statuses)
        report("slowbody.cached_latency_ms", {"p50": round(percentile(lat, 0.5), 2),
                                              "p99": round(percentile(lat, 0.99), 2),
                                              "max": round(max(lat), 2)})
        answers, when = {}, []
        for s in socks:
            s.settimeout(max(1.0, 60 - (time.monotonic() - t0)))
            try:
                data = s.recv(4096)
                when.append(time.monotonic() - t0)
                code = data[9:12].decode() if data else "closed"
            except OSError:
                code = "none"
            answers[code] = answers.get(code, 0) + 1
        report("slowbody.upload_answers", answers)
        report("slowbody.answered_after_s", [round(min(when), 1), round(max(when), 1)] if when else None)
        report("slowbody.body_timeouts", metric(port, "skybake_body_timeouts_total"))
        report("slowbody.load_shed", metric(port, "skybake_load_shed_total"))
    finally:
        stop.set()
        for s in socks:
            s.close()
        srv.stop()


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    here = os.path.dirname(os.path.abspath(__file__))
    ap.add_argument("--bin", default=os.path.join(here, "..", "target", "release", "skybake"))
    ap.add_argument("--port", type=int, default=18190)
    ap.add_argument("--quick", action="store_true", help="smaller storms (a minute or two)")
    ap.add_argument("--only", choices=["abandoned", "slow", "swap", "jobs", "slowbody"], action="append")
    args = ap.parse_args()
    storms = {"abandoned": storm_abandoned, "slow": storm_slow, "swap": storm_swap, "jobs": storm_jobs,
              "slowbody": storm_slowbody}
    for name, storm in storms.items():
        if args.only and name not in args.only:
            continue
        if left() < 60:
            report(f"{name}.skipped", "global deadline")
            continue
        storm(args.bin, args.port, args.quick)
    print(json.dumps(RESULTS, indent=1))


if __name__ == "__main__":
    sys.exit(main())
