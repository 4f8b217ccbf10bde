#!/usr/bin/env python3
"""Summarises bench/lego.sh results: a JSON summary plus a Markdown table."""
import json
import os
import sys

out = sys.argv[1]
def load(name):
    p = os.path.join(out, name)
    return json.load(open(p)) if os.path.exists(p) else None

train, ev, render = load("train.json"), load("eval.json"), load("render.json")
summary = {
    "psnr": ev["psnr"], "ssim": ev["ssim"], "num_images": ev["num_images"],
    "train_seconds": train["train_seconds"], "samples_per_second": train["samples_per_second"],
    "rays_per_second": train["rays_per_second"], "model_bytes": train["model_bytes"],
    "composited_samples_per_second": train.get("composited_samples_per_second"),
    "iterations": train["iterations"],
    "render_ms": {str(r["size"]): r["mean_ms"] for r in render["results"]},
    "curve": train["curve"], "sweep": [],
}
for f in sorted(os.listdir(out)):
    if f.startswith("sweep_t") and f.endswith(".json"):
        s = json.load(open(os.path.join(out, f)))
        summary["sweep"].append({k: s.get(k) for k in
                                 ("log2_table_size", "model_bytes", "psnr", "ssim", "train_seconds",
                                  "samples_per_second")})
json.dump(summary, open(os.path.join(out, "summary.json"), "w"), indent=2)
print(f"lego_100: test PSNR {summary['psnr']:.2f} dB, SSIM {summary['ssim']:.4f} over {summary['num_images']} images; "
      f"train {summary['train_seconds']:.0f}s ({summary['iterations']} steps), "
      f"{summary['samples_per_second']/1e3:.0f}k samples/s marched, {summary['composited_samples_per_second']/1e3:.0f}k composited; model {summary['model_bytes']/1e6:.1f} MB; "
      f"render " + ", ".join(f"{k}px {v:.0f} ms" for k, v in summary["render_ms"].items()))
print("\n| train s | step | PSNR (25 test views) | SSIM |\n|---|---|---|---|")
for c in summary["curve"]:
    print(f"| {c['train_seconds']:.0f} | {c['iteration']} | {c['psnr']:.2f} | {c['ssim']:.4f} |")
print("\n| table | model MB | PSNR | SSIM | train s | samples/s |\n|---|---|---|---|---|---|")
for s in summary["sweep"]:
    print(f"| 2^{s['log2_table_size']} | {s['model_bytes']/1e6:.1f} | {s['psnr']:.2f} | {s['ssim']:.4f} | "
          f"{s['train_seconds']:.0f} | {s['samples_per_second']/1e3:.0f}k |")
