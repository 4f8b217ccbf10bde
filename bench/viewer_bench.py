#!/usr/bin/env python3
"""Viewer benchmark: what a user of the web viewer feels, measured in a real
headless Chromium against a real clnerf-server on 2 cores.

For each dataset: starts clnerf-server (default options, HTTP on), uploads
the capture as a scan and lets the service train it (its own default
iterations), opens the viewer at 400x300 and then, with the mouse:
  * drags (orbit) for --drag-seconds and counts the preview frames that
    arrive: previews per second while dragging (target >= 10);
  * releases and times until the full-resolution frame is on screen
    (targets: <= 1.5 s on a real capture such as fox_8, <= 0.5 s on lego_100);
  * repeats both while an update trains (the same capture uploaded again as
    a second scan): release-to-full latency while training vs idle (target
    <= 3x).
Prints a human line per dataset and JSON (also written to --json-out).

Usage: bench/viewer_bench.py --data DIR [--data DIR ...] [--json-out F]
       (bench/viewer.sh runs it on lego_100 and fox_8.)
"""
import argparse
import json
import os
import shutil
import statistics
import sys
import tempfile
import time
import urllib.request

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests", "viewer"))
from viewer_driver import Server, fail, frames, full_shown, run_client, start_chromium, wait_for  # noqa: E402
from selenium.webdriver.common.action_chains import ActionChains  # noqa: E402
from selenium.webdriver.common.by import By  # noqa: E402

TARGETS = {"preview_fps": 10.0, "train_over_idle": 3.0}


def running_job(http_port):
    with urllib.request.urlopen(f"http://127.0.0.1:{http_port}/api/jobs?limit=1") as r:
        jobs = json.load(r)["jobs"]
    return jobs[0] if jobs and not jobs[0]["done"] else None


def drag_and_release(driver, seconds, step_px=8, every_s=0.05):
    """Orbits for `seconds`; returns (preview frames per second, release->full s)."""
    canvas = driver.find_element(By.ID, "canvas-A")
    wait_for("a settled frame before the drag", lambda: full_shown(driver), timeout=60, every=0.25)
    n0 = len(frames(driver))
    ActionChains(driver, duration=0).move_to_element_with_offset(canvas, -120, 0).click_and_hold().perform()
    t0 = time.time()
    i = 0
    while time.time() - t0 < seconds:
        ActionChains(driver, duration=0).move_by_offset(step_px if (i // 20) % 2 == 0 else -step_px, 0).perform()
        i += 1
        time.sleep(every_s)
    drag_s = time.time() - t0
    got = frames(driver)[n0:]
    ActionChains(driver, duration=0).release().perform()
    # Timed on the page's own clock (release event -> full frame drawn), and
    # polled slowly, so the benchmark's polling does not load the 2 cores.
    released = driver.execute_script("return window.clnerfViewer.releasedAt;")
    full = wait_for("the full-resolution frame after release",
                    lambda: next((f for f in frames(driver) if f["full"] and f["at"] > released), None),
                    timeout=60, every=0.25)
    settle = (full["at"] - released) / 1000
    previews = [f for f in got if not f["full"]]
    return len(previews) / drag_s, settle, sorted({(f["w"], f["h"]) for f in previews}), full.get("renderMs", 0)


def bench_dataset(args, data):
    name = os.path.basename(os.path.normpath(data))
    work = tempfile.mkdtemp(prefix="clnerf_viewer_bench_")
    server = Server(args.server, f"{work}/store", os.path.join(args.out, f"{name}_server.log"), args.server_args)
    env = dict(os.environ, CLNERF_SERVER=f"127.0.0.1:{server.grpc}")
    driver = None
    try:
        t = time.time()
        run_client(args.client, ["upload", data, "--name", f"{name}-0", "--watch"], env, f"upload of {data}")
        train_s = time.time() - t
        driver = start_chromium()
        driver.get(f"http://127.0.0.1:{server.http}/#res=400x300")
        wait_for("the first frame", lambda: full_shown(driver), timeout=120)
        idle = [drag_and_release(driver, args.drag_seconds) for _ in range(args.repeats)]

        run_client(args.client, ["upload", data, "--name", f"{name}-1"], env, "second upload")
        wait_for("the update to start training",
                 lambda: (running_job(server.http) or {}).get("phase") == "training", timeout=300, every=0.2)
        busy = []
        while len(busy) < args.repeats:
            job = running_job(server.http)
            if not job or job["phase"] != "training":
                break
            busy.append(drag_and_release(driver, args.drag_seconds))
        if not busy:
            fail(f"{name}: the update finished before any drag while training; use a longer update")
        errs = driver.execute_script("return window.clnerfViewer.pageErrors.concat(window.clnerfViewer.httpErrors);")
        med = lambda xs: statistics.median(xs)  # noqa: E731
        r = {
            "dataset": name,
            "resolution": "400x300",
            "upload_to_served_s": round(train_s, 1),
            "idle_release_to_full_s": [round(x[1], 3) for x in idle],
            "idle_release_to_full_median_s": round(med([x[1] for x in idle]), 3),
            "idle_full_render_ms": [x[3] for x in idle],
            "idle_preview_fps": [round(x[0], 1) for x in idle],
            "idle_preview_fps_median": round(med([x[0] for x in idle]), 1),
            "preview_sizes": [list(s) for s in idle[-1][2]],
            "training_release_to_full_s": [round(x[1], 3) for x in busy],
            "training_release_to_full_median_s": round(med([x[1] for x in busy]), 3),
            "training_full_render_ms": [x[3] for x in busy],
            "training_preview_fps_median": round(med([x[0] for x in busy]), 1),
            "page_errors": errs,
        }
        r["training_over_idle"] = round(r["training_release_to_full_median_s"] /
                                        max(r["idle_release_to_full_median_s"], 1e-3), 2)
        return r
    finally:
        if driver is not None:
            driver.quit()
        server.stop()
        shutil.rmtree(work, ignore_errors=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", action="append", required=True, help="dataset folder (repeatable)")
    ap.add_argument("--server", default=os.path.join(HERE, "..", "build", "server", "clnerf-server"))
    ap.add_argument("--client", default=os.path.join(HERE, "..", "build", "client", "clnerf"))
    ap.add_argument("--out", default=os.path.join(HERE, "results", "viewer"))
    ap.add_argument("--json-out", default="")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--drag-seconds", type=float, default=2.0)
    ap.add_argument("--server-args", nargs="*", default=[], help="extra clnerf-server flags")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    results = []
    for data in args.data:
        if not os.path.isdir(data):
            print(f"viewer bench: {data} not found; skipped", flush=True)
            continue
        r = bench_dataset(args, data)
        results.append(r)
        print(f"{r['dataset']}: release -> full 400x300 {r['idle_release_to_full_median_s']:.2f} s idle, "
              f"{r['training_release_to_full_median_s']:.2f} s while training ({r['training_over_idle']:.1f}x); "
              f"previews {r['idle_preview_fps_median']:.1f}/s idle, {r['training_preview_fps_median']:.1f}/s "
              f"while training", flush=True)
    out = {"targets": {"release_to_full_s": {"fox_8": 1.5, "lego_100": 0.5}, **TARGETS}, "results": results}
    text = json.dumps(out, indent=1)
    print(text)
    if args.json_out:
        with open(args.json_out, "w") as f:
            f.write(text + "\n")


if __name__ == "__main__":
    main()
