#!/usr/bin/env python3
"""Many browsers viewing one place at once: what they cost the server.

Starts a real clnerf-server (HTTP on loopback), uploads a procedural scan
(or --data, a capture the CLI can upload) and waits for its version, then
opens --viewers separate headless Chromium browsers (SwiftShader WebGL2) on
the viewer with frames=baked. Each draws the baked asset and is dragged, so
it draws more frames. Then it reads the server's /metrics and prints JSON
and a human line: server renders (the claim: 0), asset requests and bytes
sent, asset files read from disk (the claim: once each, however many
viewers), the server's CPU seconds over the viewing beside what it uses
idle in as long, and each browser's time to its first baked frame.

Usage: baked_viewers.py --server BIN --client BIN --out DIR [--viewers 20] [--data DIR]
(bench/baked_viewers.sh runs it with the built binaries.) Never run beside
another benchmark: the browsers and the server share the machine's cores.
"""
import argparse
import json
import os
import sys
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "viewer"))
from viewer_driver import Server, fail, frames, run_client, start_chromium, wait_for  # noqa: E402
from service_baked_browser_test import metric, shown  # noqa: E402
from selenium.webdriver.common.action_chains import ActionChains  # noqa: E402
from selenium.webdriver.common.by import By  # noqa: E402


def cpu_seconds(pid):
    """User + system CPU seconds of a process (from /proc)."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--server", required=True)
    ap.add_argument("--client", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--viewers", type=int, default=20)
    ap.add_argument("--data", help="a capture to upload (default: a procedural scan)")
    ap.add_argument("--json-out")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    work = tempfile.mkdtemp(prefix="clnerf_viewers_")
    env = dict(os.environ)
    scan = args.data
    if not scan:
        run_client(args.client, ["scans", "--out", f"{work}/scans", "--scans", "1", "--size", "64",
                                 "--train-views", "24", "--test-views", "2"], env, "scans")
        scan = f"{work}/scans/scan_000"
    server = Server(args.server, f"{work}/store", f"{args.out}/server.log", ["--first-scan-iters", "600"])
    env["CLNERF_SERVER"] = f"127.0.0.1:{server.grpc}"
    drivers = []
    try:
        t = time.time()
        run_client(args.client, ["upload", scan, "--watch"], env, "upload", timeout=3600)
        print(f"uploaded, trained and baked in {time.time() - t:.1f} s", flush=True)
        before = {k: metric(server.http, k) for k in (
            "clnerf_renders_total", "clnerf_asset_requests_total", "clnerf_asset_bytes_total",
            "clnerf_asset_file_reads_total", "clnerf_asset_bakes_total")}
        # The server's own background work (job polls, metrics) while idle,
        # for comparison with the viewing below.
        idle0, t_idle = cpu_seconds(server.proc.pid), time.time()
        time.sleep(20)
        idle_rate = (cpu_seconds(server.proc.pid) - idle0) / (time.time() - t_idle)
        cpu0, t_view = cpu_seconds(server.proc.pid), time.time()
        url = f"http://127.0.0.1:{server.http}/#frames=baked&res=400x300"
        first_frame = []
        for i in range(args.viewers):
            d = start_chromium(window="700,600", software_webgl=True, script_timeout=120)
            drivers.append(d)
            t = time.time()
            d.get(url)
            if not d.execute_script("return window.clnerfViewer.bakedSupported;"):
                fail(f"browser {i}: no WebGL2")
            wait_for(f"browser {i}'s first baked frame", lambda: (shown(d) or {}).get("baked"), timeout=120)
            first_frame.append(time.time() - t)
        drawn = 0
        for i, d in enumerate(drivers):  # Every browser moves its camera: more baked frames.
            n0 = len(frames(d))
            canvas = d.find_element(By.ID, "canvas-A")
            ActionChains(d).move_to_element(canvas).click_and_hold().move_by_offset(30, 5).release().perform()
            wait_for(f"browser {i}'s frame after a drag", lambda: len(frames(d)) > n0, timeout=60)
            new = frames(d)[n0:]
            if not all(f.get("baked") for f in new):
                fail(f"browser {i} showed a server frame while frames=baked")
            drawn += len(frames(d))
        cpu = cpu_seconds(server.proc.pid) - cpu0
        view_seconds = time.time() - t_view
        after = {k: metric(server.http, k) for k in before}
        delta = {k: after[k] - before[k] for k in before}
        files = delta["clnerf_asset_file_reads_total"]
        result = {"baked_viewers": {
            "viewers": args.viewers, "frames_drawn": drawn,
            "server_renders": delta["clnerf_renders_total"],
            "asset_requests": delta["clnerf_asset_requests_total"],
            "asset_bytes_sent": delta["clnerf_asset_bytes_total"],
            "asset_file_reads": files, "asset_bakes": delta["clnerf_asset_bakes_total"],
            "server_cpu_seconds": round(cpu, 3), "viewing_seconds": round(view_seconds, 1),
            "server_idle_cpu_seconds_per_second": round(idle_rate, 4),
            "first_frame_seconds": {"min": round(min(first_frame), 2), "max": round(max(first_frame), 2)}}}
        print(json.dumps(result))
        print(f"{args.viewers} browsers drew {drawn} baked frames; the server rendered "
              f"{delta['clnerf_renders_total']:.0f}, answered {delta['clnerf_asset_requests_total']:.0f} asset "
              f"requests ({delta['clnerf_asset_bytes_total'] / 1e6:.2f} MB sent), read {files:.0f} files from disk "
              f"and used {cpu:.2f} CPU s over {view_seconds:.0f} s (idle: {idle_rate * view_seconds:.2f} CPU s "
              f"in as long)")
        if args.json_out:
            with open(args.json_out, "w") as f:
                json.dump(result, f, indent=1)
        if delta["clnerf_renders_total"] != 0:
            fail("the server rendered frames for baked viewers")
    finally:
        for d in drivers:
            d.quit()
        server.stop()
    print("PASS")


if __name__ == "__main__":
    main()
