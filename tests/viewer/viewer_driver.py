"""Shared helpers for driving clnerf's web viewer in headless Chromium: the
end-to-end test (viewer_browser_test.py) and the benchmark
(bench/viewer_bench.py) use the same server launcher, browser set-up and
canvas read-back.

Needs python3-selenium, chromium and chromium-driver (Debian packages,
installed by scripts/install-deps.sh). Missing pieces are failures, not skips.
"""
import base64
import os
import re
import shutil
import subprocess
import sys
import time


def fail(msg):
    print("FAIL: " + msg, flush=True)
    sys.exit(1)


try:
    from selenium import webdriver
    from selenium.common.exceptions import StaleElementReferenceException
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select
except ImportError as e:  # Not a skip: CI must run the viewer test.
    fail(f"python3-selenium is missing ({e}); run scripts/install-deps.sh")


def wait_for(what, cond, timeout=20.0, every=0.05):
    end = time.time() + timeout
    while time.time() < end:
        v = cond()
        if v:
            return v
        time.sleep(every)
    fail(f"timed out after {timeout:.0f} s waiting for {what}")


def select_value(driver, element_id, value, timeout=30.0):
    """Picks `value` in the <select> `element_id` once it offers it. The page
    rebuilds some lists as it polls (places, versions), so an option found
    may be replaced before it is clicked: then it is found again."""
    def pick():
        try:
            sel = Select(driver.find_element(By.ID, element_id))
            if value not in [o.get_attribute("value") for o in sel.options]:
                return False
            sel.select_by_value(value)
            return True
        except StaleElementReferenceException:
            return False
    wait_for(f"option '{value}' of #{element_id}", pick, timeout=timeout)


class Server:
    """clnerf-server with gRPC and HTTP on 127.0.0.1:0; ports read from stdout."""

    def __init__(self, binary, store, log_path, extra_args=()):
        self.log = open(log_path, "w")
        self.proc = subprocess.Popen(
            [binary, "--store", store, "--listen", "127.0.0.1:0", "--http", "127.0.0.1:0", *extra_args],
            stdout=subprocess.PIPE, stderr=self.log, text=True)
        self.grpc = self.http = None
        while self.http is None:
            line = self.proc.stdout.readline()
            if not line:
                fail(f"server exited early; see {log_path}")
            m = re.search(r"clnerf-server listening on port (\d+)", line)  # Plain or in a JSON record.
            if m:
                self.grpc = int(m.group(1))
            m = re.search(r"clnerf-server http on port (\d+)", line)
            if m:
                self.http = int(m.group(1))

    def terminate_timed(self, timeout=30):
        """SIGTERM; returns (exit code, seconds until the process exited)."""
        t = time.time()
        self.proc.terminate()
        try:
            rc = self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            rc = None
        return rc, time.time() - t

    def stop(self):
        if self.proc.poll() is not None:
            self.log.close()
            return
        self.proc.terminate()
        try:
            self.proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        self.log.close()


def run_client(client, args, env, what, timeout=None):
    r = subprocess.run([client, "--log-level", "warn", *args], env=env, capture_output=True, text=True,
                       timeout=timeout)
    if r.returncode != 0:
        fail(f"{what} failed: {r.stdout[-2000:]} {r.stderr[-2000:]}")
    return r.stdout


def start_chromium(window="1400,1000", software_webgl=False, script_timeout=30):
    """Headless Chromium through chromedriver. software_webgl: WebGL2 on
    SwiftShader (the baked asset's page) instead of no GPU at all."""
    chromium = shutil.which("chromium") or "/usr/bin/chromium"
    driver_bin = shutil.which("chromedriver") or "/usr/bin/chromedriver"
    for b in (chromium, driver_bin):
        if not os.path.exists(b):
            fail(f"{b} not found: install chromium and chromium-driver (scripts/install-deps.sh)")
    opts = webdriver.ChromeOptions()
    opts.binary_location = chromium
    gpu = (("--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist") if software_webgl
           else ("--disable-gpu",))
    for a in ("--headless=new", "--no-sandbox", *gpu, "--disable-dev-shm-usage",
              f"--window-size={window}", "--no-first-run", "--disable-extensions"):
        opts.add_argument(a)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(driver_bin), options=opts)
    driver.set_script_timeout(script_timeout)
    return driver


def canvas_pixels(driver, canvas_id="canvas-A"):
    """The canvas as RGBA bytes (read back through getImageData)."""
    b64 = driver.execute_script(
        """const c = document.getElementById(arguments[0]);
           const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
           let s = ''; for (let i = 0; i < d.length; i += 8192) s += String.fromCharCode.apply(null, d.subarray(i, i + 8192));
           return btoa(s);""", canvas_id)
    return base64.b64decode(b64)


def mean_abs_diff(a, b):
    """Mean absolute RGB difference of two RGBA buffers, in 0..255."""
    if len(a) != len(b):
        return 255.0
    total = sum(abs(a[i] - b[i]) + abs(a[i + 1] - b[i + 1]) + abs(a[i + 2] - b[i + 2]) for i in range(0, len(a), 4))
    return total / (3 * len(a) / 4)


def variance(px):
    vals = [px[i] for i in range(0, len(px), 4)] + [px[i + 1] for i in range(0, len(px), 4)]
    m = sum(vals) / len(vals)
    return sum((v - m) ** 2 for v in vals) / len(vals)


def full_shown(driver, panel="A"):
    """The panel's frame if it is full resolution and nothing is in flight."""
    s = driver.execute_script("return window.clnerfViewer.shown(arguments[0]);", panel)
    busy = driver.execute_script("return window.clnerfViewer.busy(arguments[0]);", panel)
    return s if s and s["full"] and not busy else None


def frames(driver):
    return driver.execute_script("return window.clnerfViewer.frames;")


def set_slider(driver, element_id, value):
    driver.execute_script(
        """const e = document.getElementById(arguments[0]); e.value = arguments[1];
           e.dispatchEvent(new Event('input', {bubbles: true}));""", element_id, str(value))
