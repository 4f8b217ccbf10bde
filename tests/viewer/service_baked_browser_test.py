#!/usr/bin/env python3
"""The service's viewer on baked assets, in a real headless Chromium with
software WebGL2 (SwiftShader).

Starts a real clnerf-server (gRPC and HTTP on 127.0.0.1:0), uploads two scans
of the procedural changing scene with the real CLI (each publish bakes its
latest time step), opens the viewer with frames=baked and checks:
  * the first frame is the baked asset, drawn by the page (the badge says
    "baked"), and not blank;
  * dragging changes the frame and every frame meanwhile is baked; with a
    1 ms budget (bakedms=1) moving frames are drawn smaller, and the still
    camera whole (400x300);
  * the time slider loads the other time step's asset (baked on request)
    and the image changes;
  * the server rendered nothing at all: /metrics counts no render, only
    asset downloads;
  * with frames=auto, a still camera gets the exact server frame and the
    badge says "exact";
  * no page error, no HTTP 5xx;
and saves screenshots under --out. Never skips.

Usage: service_baked_browser_test.py --server BIN --client BIN --out DIR
"""
import argparse
import os
import re
import shutil
import sys
import tempfile
import time
import urllib.request

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from viewer_driver import (Server, canvas_pixels, fail, frames, mean_abs_diff, run_client,  # noqa: E402
                           set_slider, start_chromium, variance, wait_for)
from selenium.webdriver.common.action_chains import ActionChains  # noqa: E402
from selenium.webdriver.common.by import By  # noqa: E402
from selenium.webdriver.support.ui import Select  # noqa: E402


def metric(port, name):
    body = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10).read().decode()
    total = 0.0
    for line in body.splitlines():
        m = re.match(r"^([a-zA-Z_:][a-zA-Z0-9_:]*)(\{[^}]*\})? (\S+)$", line)
        if m and m.group(1) == name:
            total += float(m.group(3))
    return total


def shown(driver):
    return driver.execute_script("return window.clnerfViewer.shown('A');")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--server", required=True)
    ap.add_argument("--client", required=True)
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    work = tempfile.mkdtemp(prefix="clnerf_service_baked_")
    subprocess_env = dict(os.environ)
    run_client(args.client, ["scans", "--out", f"{work}/scans", "--scans", "2", "--size", "32", "--train-views",
                             "20", "--test-views", "2"], subprocess_env, "scans")
    with open(f"{work}/config.json", "w") as f:
        f.write('{"batch_rays": 512, "target_samples": 8192, "bake": {"resolution": 128, "fit_rays": 16384}}')
    server = Server(args.server, f"{work}/store", f"{args.out}/server.log",
                    ["--iters", "120", "--first-scan-iters", "300", "--config", f"{work}/config.json", "--log-level", "debug"])
    env = dict(os.environ, CLNERF_SERVER=f"127.0.0.1:{server.grpc}")
    driver = None
    try:
        for t in (0, 1):
            run_client(args.client, ["upload", f"{work}/scans/scan_00{t}", "--pose-frame", "place", "--watch"], env,
                       f"upload of scan {t}")
        driver = start_chromium(software_webgl=True, script_timeout=120)
        driver.get(f"http://127.0.0.1:{server.http}/#frames=baked&res=400x300&bakedms=1")
        if not driver.execute_script("return window.clnerfViewer.bakedSupported;"):
            fail("the page found no WebGL2 in Chromium with SwiftShader")

        # 1. The baked asset, drawn in the page.
        wait_for("the first baked frame", lambda: (shown(driver) or {}).get("baked"), timeout=120)
        badge = driver.execute_script("return window.clnerfViewer.badge('A');")
        print(f"badge: {badge}", flush=True)
        if "baked" not in badge:
            fail(f"the badge does not say 'baked': {badge!r}")
        first = canvas_pixels(driver)
        if variance(first) < 20:
            fail(f"the canvas looks blank (variance {variance(first):.1f})")
        driver.save_screenshot(f"{args.out}/service_baked.png")

        # 2. A drag: frames change, and every one is baked.
        n0 = len(frames(driver))
        canvas = driver.find_element(By.ID, "canvas-A")
        chain = ActionChains(driver).move_to_element(canvas).click_and_hold()
        for _ in range(6):
            chain = chain.move_by_offset(12, 2).pause(0.2)
        chain.release().perform()
        wait_for("a frame after the drag", lambda: len(frames(driver)) > n0)
        time.sleep(1.0)
        drag = frames(driver)[n0:]
        if not all(f.get("baked") for f in drag):
            fail(f"non-baked frames during the drag: {[f for f in drag if not f.get('baked')][:3]}")
        moved = canvas_pixels(driver)
        if mean_abs_diff(moved, first) < 1.0:
            fail("dragging did not change the frame")
        print(f"drag: {len(drag)} baked frames, {sum(f['ms'] for f in drag) / len(drag):.0f} ms each in "
              f"software WebGL2, scales {[f['scale'] for f in drag]}", flush=True)
        # With a 1 ms budget (bakedms=1) moving frames shrink; the still
        # camera is drawn whole.
        if min(f["scale"] for f in drag) >= 1:
            fail(f"moving baked frames over their budget were not drawn smaller: {drag[:4]}")
        wait_for("the still baked frame drawn whole", lambda: (shown(driver) or {}).get("scale") == 1)
        if (shown(driver)["w"], shown(driver)["h"]) != (400, 300):
            fail(f"the still baked frame is {shown(driver)['w']}x{shown(driver)['h']}, not 400x300")

        # 3. The time slider: time step 0's asset (baked on request), another image.
        before = canvas_pixels(driver)
        set_slider(driver, "time-A", 0)
        wait_for("time step 0's asset", lambda: any(
            l.get("key", "").endswith("|0") and "ms" in l
            for l in driver.execute_script("return window.clnerfViewer.bakedLoads;")), timeout=120)
        wait_for("a baked frame of time step 0", lambda: (shown(driver) or {}).get("t") == 0 and shown(driver)["baked"])
        time.sleep(0.5)
        past = canvas_pixels(driver)
        print(f"time 1 -> 0: mean |diff| {mean_abs_diff(past, before):.2f}", flush=True)
        if mean_abs_diff(past, before) < 1.0:
            fail("the time slider did not change the image")
        driver.save_screenshot(f"{args.out}/service_baked_t0.png")

        # 4. No server render at all: only asset downloads.
        renders = metric(server.http, "clnerf_renders_total")
        asset_bytes = metric(server.http, "clnerf_asset_bytes_total")
        bakes = metric(server.http, "clnerf_asset_bakes_total")
        print(f"server: {renders:.0f} renders, {asset_bytes / 1e6:.2f} MB of assets sent, {bakes:.0f} baked on "
              "request", flush=True)
        if renders != 0:
            fail(f"the server rendered {renders:.0f} frames for a baked viewer")
        if asset_bytes <= 0 or bakes != 1:
            fail(f"asset downloads {asset_bytes} bytes, {bakes} bakes on request (expected 1: time step 0)")

        # 5. frames=auto: a still camera gets the exact server frame.
        Select(driver.find_element(By.ID, "frames")).select_by_value("auto")
        wait_for("the exact frame", lambda: (shown(driver) or {}).get("full"), timeout=60)
        badge = driver.execute_script("return window.clnerfViewer.badge('A');")
        if "exact" not in badge:
            fail(f"the badge does not say 'exact': {badge!r}; last frames {frames(driver)[-4:]}")
        exact = canvas_pixels(driver)
        print(f"exact against baked at the same camera: mean |diff| {mean_abs_diff(exact, past):.2f}", flush=True)
        driver.save_screenshot(f"{args.out}/service_exact.png")

        errors = driver.execute_script("return window.clnerfViewer.pageErrors;")
        http_errors = driver.execute_script("return window.clnerfViewer.httpErrors;")
        failed_loads = [l for l in driver.execute_script("return window.clnerfViewer.bakedLoads;") if "error" in l]
        if errors or http_errors or failed_loads:
            fail(f"page errors {errors[:3]}, HTTP errors {http_errors[:3]}, asset loads {failed_loads[:3]}")
    finally:
        if driver:
            driver.quit()
        server.stop()
        shutil.rmtree(work, ignore_errors=True)
    print("PASS")


if __name__ == "__main__":
    main()
