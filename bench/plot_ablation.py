#!/usr/bin/env python3
"""Ablation of `clnerf bench scenes` runs: one suite per configuration.

Each argument is LABEL=DIR[,DIR...], each DIR a `--out` of `bench/scenes.sh` (its
scenes.json), all run on one machine, one after another. Prints a markdown
table (per scene and configuration: test PSNR, SSIM, speckle, blur, samples
per ray, render ms per view, training s, and the change against the first
configuration) and, with matplotlib, writes OUT.png: one panel per scene,
held-out PSNR against training time, a line per configuration (the curve's
few held-out views; a star: the whole test split at the end).

Usage: plot_ablation.py --out OUT.png LABEL=DIR[,DIR...] [LABEL=DIR[,DIR...] ...]
Example (docs/clean_fields.md):
  OUT=/tmp/gd01 bash bench/scenes.sh --grid-decay 0.1
  python3 bench/plot_ablation.py --out gd.png default=/tmp/default "grid decay 0.1=/tmp/gd01"
"""
import argparse
import json
import os
import sys


def load(spec):
    label, _, dirs = spec.partition("=")
    if not dirs:
        sys.exit(f"{spec}: expected LABEL=DIR[,DIR...]")
    runs = {}
    for d in dirs.split(","):
        with open(os.path.join(d, "scenes.json")) as f:
            runs.update({s["scene"]: s for s in json.load(f)["scenes"]})
    return label, runs


def table(configs):
    scenes = list(dict.fromkeys(name for _, runs in configs for name in runs))
    print("| scene | configuration | test PSNR (Δ) | SSIM | speckle | blur | samples/ray | render ms | train s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in scenes:
        base = configs[0][1].get(name)
        for label, runs in configs:
            s = runs.get(name)
            if s is None or s.get("psnr") is None:
                continue
            delta = "" if base is None or s is base else f" ({s['psnr'] - base['psnr']:+.2f})"
            print(f"| {name} | {label} | {s['psnr']:.2f}{delta} | {s['ssim']:.3f} | {s['speckle']:.5f} | "
                  f"{s['blur']:.5f} | {s['samples_per_ray']:.0f} | {s['render_ms']:.0f} | {s['train_seconds']:.0f} |")
    return scenes


def chart(configs, scenes, out):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not installed (apt install python3-matplotlib); no chart written", file=sys.stderr)
        return
    cols = min(3, len(scenes))
    rows = (len(scenes) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.4 * rows), dpi=110, squeeze=False)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, name in enumerate(scenes):
        ax = axes[i // cols][i % cols]
        for k, (label, runs) in enumerate(configs):
            s = runs.get(name)
            if s is None:
                continue
            c = colours[k % len(colours)]
            curve = s.get("curve") or []
            ax.plot([p["train_seconds"] for p in curve], [p["psnr"] for p in curve], "-o", ms=2.5, color=c,
                    label=label)
            if s.get("psnr") is not None:
                ax.plot([s["train_seconds"]], [s["psnr"]], "*", ms=10, color=c, markeredgecolor="k")
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("training s", fontsize=8)
        ax.set_ylabel("PSNR dB", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="lower right")
    for j in range(len(scenes), rows * cols):
        axes[j // cols][j % cols].axis("off")
    fig.suptitle("Held-out PSNR against training time per configuration (stars: whole test split)", fontsize=10)
    fig.tight_layout()
    fig.savefig(out)
    print(f"wrote {out}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, help="PNG to write")
    ap.add_argument("configs", nargs="+", help="LABEL=DIR[,DIR...]")
    a = ap.parse_args()
    configs = [load(c) for c in a.configs]
    chart(configs, table(configs), a.out)


if __name__ == "__main__":
    main()
