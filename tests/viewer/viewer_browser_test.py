#!/usr/bin/env python3
"""End-to-end test of the web viewer in a real headless Chromium.

Starts a real clnerf-server (gRPC and HTTP on 127.0.0.1:0) on a fresh store,
uploads two scans of the procedural changing scene with the real CLI, then
drives Debian's chromium through chromium-driver (python3-selenium) and
checks what a user sees:
  * the canvas is not blank;
  * during a drag, frames are preview-sized and the image changes; within 2 s
    of releasing, a full-resolution frame arrives;
  * moving the time slider changes the image, and moving it back returns the
    first image;
  * two different versions differ, the same version twice does not;
  * the jobs panel shows the progress of a running update;
  * picking another place shows that place's model, and the URL names it;
  * no page error, no HTTP 5xx;
  * SIGTERM with the page still open stops the server within 5 s;
and saves screenshots under --out. The page runs with frames=server: the
server renders every frame (service_baked_browser_test.py covers the
baked asset's frames). Never skips: a missing browser or driver
is a failure (scripts/install-deps.sh installs them).

Usage: viewer_browser_test.py --server BIN --client BIN --out DIR
"""
import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from viewer_driver import (Server, canvas_pixels, fail, frames, full_shown, mean_abs_diff, run_client,  # noqa: E402
                           select_value, set_slider, start_chromium, variance, wait_for)
from selenium.webdriver.common.action_chains import ActionChains  # noqa: E402
from selenium.webdriver.common.by import By  # noqa: E402
from selenium.webdriver.support.ui import Select  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--server", required=True)
    ap.add_argument("--client", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--iters", type=int, default=120)  # Updates outlast the panel's 2.5 s idle poll.
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    work = tempfile.mkdtemp(prefix="clnerf_viewer_")
    t_start = time.time()
    subprocess.run([args.client, "--log-level", "warn", "scans", "--out", f"{work}/scans", "--scans", "3",
                    "--size", "32", "--train-views", "20", "--test-views", "2"], check=True)
    # Small batches, as the server tests train (server_test_util.h: TinyServerOptions).
    with open(f"{work}/config.json", "w") as f:
        # Each publish bakes for the browser (issue 41); this test looks at
        # server frames, so a coarse bake keeps the updates quick.
        f.write('{"batch_rays": 512, "target_samples": 8192, "bake": {"resolution": 64, "fit_rays": 4096}}')
    server = Server(args.server, f"{work}/store", f"{args.out}/server.log",
                    ["--iters", str(args.iters), "--first-scan-iters", "150", "--config", f"{work}/config.json",
                     "--log-level", "debug"])  # Every request and its status (and why, when refused).
    env = dict(os.environ, CLNERF_SERVER=f"127.0.0.1:{server.grpc}")
    driver = None
    try:
        for t in (0, 1):
            run_client(args.client, ["upload", f"{work}/scans/scan_00{t}", "--pose-frame", "place", "--watch"], env, f"upload of scan {t}")
        print(f"two versions trained in {time.time() - t_start:.1f} s", flush=True)

        driver = start_chromium()
        # Server frames (the path without WebGL2, or for a version that could
        # not be baked); the baked path is service_baked_browser_test.py's.
        base = f"http://127.0.0.1:{server.http}/#frames=server"
        driver.get(base)

        # 1. A full-resolution frame arrives and the canvas is not blank.
        wait_for("the first full-resolution frame", lambda: full_shown(driver))
        first = canvas_pixels(driver)
        var = variance(first)
        print(f"first frame: canvas variance {var:.1f}", flush=True)
        if var < 20:
            fail(f"the canvas looks blank (variance {var:.1f})")
        res = driver.execute_script("return window.clnerfViewer.resolution;")
        W, H = res

        # 2. A synthetic drag: preview-sized frames that change; full frame within 2 s of release.
        canvas = driver.find_element(By.ID, "canvas-A")
        n0 = len(frames(driver))
        actions = ActionChains(driver, duration=0)
        actions.move_to_element(canvas).click_and_hold()
        actions.perform()
        snaps = []
        for i in range(30):
            ActionChains(driver, duration=0).move_by_offset(6, 1 if i % 2 else -1).perform()
            time.sleep(0.06)
            if i % 6 == 5:
                snaps.append(canvas_pixels(driver))
        drag_frames = frames(driver)[n0:]
        ActionChains(driver, duration=0).release().perform()
        released = time.time()
        full = wait_for("a full-resolution frame after release", lambda: full_shown(driver), timeout=10)
        settle = time.time() - released
        previews = [f for f in drag_frames if not f["full"]]
        print(f"drag: {len(drag_frames)} frames ({len(previews)} previews, sizes "
              f"{sorted({(f['w'], f['h']) for f in previews})}), full frame {settle:.2f} s after release", flush=True)
        if not previews:
            fail("no preview frames arrived during the drag")
        if any(f["w"] >= W for f in previews):
            fail(f"preview frames should be smaller than {W}x{H}")
        changes = [mean_abs_diff(snaps[i], snaps[i + 1]) for i in range(len(snaps) - 1)]
        if max(changes) < 0.5:
            fail(f"the image did not change during the drag ({changes})")
        if settle > 2.0:
            fail(f"the full-resolution frame took {settle:.2f} s after release (limit 2 s)")
        if (full["w"], full["h"]) != (W, H):
            fail(f"the settled frame is {full['w']}x{full['h']}, not {W}x{H}")

        # 3. The time slider: t0 differs from t1; back to t1 returns the same image.
        set_slider(driver, "time-A", 1)
        wait_for("time step 1", lambda: (full_shown(driver) or {}).get("t") == 1)
        img_t1 = canvas_pixels(driver)
        set_slider(driver, "time-A", 0)
        wait_for("time step 0", lambda: (full_shown(driver) or {}).get("t") == 0)
        img_t0 = canvas_pixels(driver)
        t_flip = time.time()
        set_slider(driver, "time-A", 1)
        wait_for("time step 1 again", lambda: (full_shown(driver) or {}).get("t") == 1)
        flip_s = time.time() - t_flip
        img_t1b = canvas_pixels(driver)
        d_times, d_back = mean_abs_diff(img_t0, img_t1), mean_abs_diff(img_t1, img_t1b)
        print(f"time slider: |t0 - t1| = {d_times:.2f}, |t1 - t1 again| = {d_back:.3f} (flip back {flip_s * 1000:.0f} ms)",
              flush=True)
        if d_times < 1.0:
            fail(f"moving the time slider did not change the image ({d_times:.2f})")
        if d_back > 0.5:
            fail(f"moving the time slider back did not return the first image ({d_back:.3f})")
        driver.save_screenshot(os.path.join(args.out, "viewer_single.png"))

        # 4. Side by side: versions 1 and 2 at the same time step differ; 2 and 2 do not.
        Select(driver.find_element(By.ID, "mode")).select_by_value("side")
        set_slider(driver, "time-A", 0)
        set_slider(driver, "time-B", 0)
        Select(driver.find_element(By.ID, "version-A")).select_by_value("1")
        Select(driver.find_element(By.ID, "version-B")).select_by_value("2")
        wait_for("v1 | v2", lambda: (full_shown(driver, "A") or {}).get("v") == 1 and
                 (full_shown(driver, "B") or {}).get("v") == 2)
        a, b = canvas_pixels(driver, "canvas-A"), canvas_pixels(driver, "canvas-B")
        d_versions = mean_abs_diff(a, b)
        driver.save_screenshot(os.path.join(args.out, "viewer_compare.png"))
        Select(driver.find_element(By.ID, "version-A")).select_by_value("2")
        wait_for("v2 | v2", lambda: (full_shown(driver, "A") or {}).get("v") == 2 and
                 (full_shown(driver, "B") or {}).get("v") == 2)
        a, b = canvas_pixels(driver, "canvas-A"), canvas_pixels(driver, "canvas-B")
        d_same = mean_abs_diff(a, b)
        print(f"versions: |v1 - v2| = {d_versions:.2f}, |v2 - v2| = {d_same:.3f}", flush=True)
        if d_versions < 0.3:
            fail(f"versions 1 and 2 render the same ({d_versions:.2f})")
        if d_same > 0.5:
            fail(f"the same version twice differs ({d_same:.3f})")

        # 5. Swipe mode draws both versions on one canvas.
        Select(driver.find_element(By.ID, "mode")).select_by_value("swipe")
        time.sleep(0.3)

        # 6. The jobs panel shows a running update's progress.
        run_client(args.client, ["upload", f"{work}/scans/scan_002", "--pose-frame", "place"], env, "upload of scan 2", timeout=60)
        text = wait_for("the jobs panel to show training progress",
                        lambda: (lambda t: t if re.search(r"step \d+ / \d+", t) else None)(
                            driver.find_element(By.ID, "jobs").text), timeout=60)
        print("jobs panel: " + " | ".join(text.splitlines()[:3]), flush=True)
        driver.save_screenshot(os.path.join(args.out, "viewer_training.png"))
        wait_for("the update to finish and appear in the panel",
                 lambda: "view v3" in driver.find_element(By.ID, "jobs").text, timeout=120)

        # 7. Places: a second place, picked in the page, shows its own model (one
        # scan, version 1) while "default" has three; the place is in the URL.
        run_client(args.client, ["places", "create", "lab"], env, "places create")
        run_client(args.client, ["upload", f"{work}/scans/scan_000", "--place", "lab", "--pose-frame", "place", "--watch"], env,
                   "upload to place lab")
        select_value(driver, "place", "lab")
        wait_for("the page to reload on place lab",
                 lambda: driver.execute_script("return (window.clnerfViewer.scene || {}).time_steps;") == 1,
                 timeout=60)
        wait_for("a full frame of place lab", lambda: full_shown(driver), timeout=60)
        if "place=lab" not in driver.current_url:
            fail(f"the place is not in the URL: {driver.current_url}")
        lab = canvas_pixels(driver)
        if variance(lab) < 20:
            fail("place lab renders a blank canvas")
        print(f"places: picked 'lab' (1 time step, v{driver.execute_script('return window.clnerfViewer.scene.version;')}),"
              f" url ...{driver.current_url[-40:]}", flush=True)
        driver.save_screenshot(os.path.join(args.out, "viewer_place.png"))

        # 8. No page errors, no HTTP 5xx, no severe console messages.
        errs = driver.execute_script("return window.clnerfViewer.pageErrors.concat(window.clnerfViewer.httpErrors);")
        severe = [e["message"] for e in driver.get_log("browser") if e["level"] == "SEVERE"]
        if errs or severe:
            with open(os.path.join(args.out, "server.log")) as f:
                refused = [line.strip() for line in f if re.search(r"http answer [45]\d\d", line)]
            fail(f"page errors or HTTP 5xx: {errs} console: {severe}; the server refused: {refused[-10:]}")
        with open(os.path.join(args.out, "server.log")) as f:
            if re.search(r"http .* -> 5\d\d", f.read()):
                fail("the server answered 5xx")
        # 9. SIGTERM with the page open (its keep-alive connections idle) stops the server promptly.
        rc, took = server.terminate_timed()
        print(f"SIGTERM with the viewer open: exit code {rc} after {took:.2f} s", flush=True)
        if rc != 0 or took > 5:
            fail(f"the server took {took:.2f} s to stop (exit code {rc}) with a viewer connected")
        print(f"viewer end-to-end: OK in {time.time() - t_start:.1f} s; screenshots in {args.out}", flush=True)
    finally:
        if driver is not None:
            driver.quit()
        server.stop()
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
