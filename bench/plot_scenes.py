#!/usr/bin/env python3
"""Charts of `clnerf bench scenes` results (DIR/scenes.json).

Writes DIR/scenes_psnr_vs_time.png: held-out PSNR against training time, one
line per scene (the curve's points on a few held-out views; a star marks the
final PSNR over the whole test split), and, when the run had
--capacity-sweep, DIR/scenes_psnr_vs_bytes.png: test PSNR against model bytes
(log scale), one line per scene through its hash-table sizes, the default
(derived) configuration ringed and the smallest within the tolerance of the
best marked: the Pareto chart for "model no more than a scene needs".
`clnerf bench scenes` runs this itself; run it by hand to redraw.
Usage: plot_scenes.py DIR   (exit 2: matplotlib missing)
"""
import json
import os
import sys


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    d = sys.argv[1]
    with open(os.path.join(d, "scenes.json")) as f:
        j = json.load(f)
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not installed (apt install python3-matplotlib); no chart written", file=sys.stderr)
        sys.exit(2)
    threads = j.get("threads")
    cores = f"{threads} CPU threads" if threads else "CPU"
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    colour = {s["scene"]: colours[i % len(colours)] for i, s in enumerate(j["scenes"])}

    fig, ax = plt.subplots(figsize=(8, 5), dpi=120)
    for s in j["scenes"]:
        c = colour[s["scene"]]
        curve = s.get("curve") or []
        if curve:
            ax.plot([p["train_seconds"] for p in curve], [p["psnr"] for p in curve], "-o", ms=3, color=c,
                    label=f'{s["scene"]} ({s["width"]}x{s["height"]})')
        if s.get("psnr") is not None:
            ax.plot([s["train_seconds"]], [s["psnr"]], "*", ms=12, color=c, markeredgecolor="k",
                    label=None if curve else s["scene"])
            ax.annotate(f'{s["psnr"]:.2f} dB', (s["train_seconds"], s["psnr"]), textcoords="offset points",
                        xytext=(6, -4), fontsize=8)
    ax.set_xlabel(f"training time (s, {cores}; evaluation excluded)")
    curve_views = j.get("curve_views", "a few")
    ax.set_ylabel("PSNR (dB)")
    ax.set_title(f'Test PSNR vs training time ({j["iterations"]} iterations, default flags)\n'
                 f"lines: {curve_views} held-out views during training; stars: the whole test split at the end",
                 fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="center right")
    fig.tight_layout()
    out = os.path.join(d, "scenes_psnr_vs_time.png")
    fig.savefig(out)
    plt.close(fig)
    print(f"wrote {out}")

    sweep = [r for r in j.get("sweep", []) if r.get("psnr") is not None]
    if not j.get("capacity_sweep") or not sweep:
        return
    tol = j.get("pareto_tolerance_db", 0.2)
    fig, ax = plt.subplots(figsize=(8, 5), dpi=120)
    for name in dict.fromkeys(r["scene"] for r in sweep):
        rows = sorted((r for r in sweep if r["scene"] == name), key=lambda r: r["model_bytes"])
        c = colour.get(name, "k")
        xs = [r["model_bytes"] / 1e6 for r in rows]
        ys = [r["psnr"] for r in rows]
        ax.plot(xs, ys, "-o", color=c, label=name)
        for r, x, y in zip(rows, xs, ys):
            ax.annotate(f'$2^{{{r["log2_table_size"]}}}$', (x, y), textcoords="offset points", xytext=(4, 5), fontsize=7)
            if r.get("default"):
                ax.plot([x], [y], "o", ms=13, mfc="none", mec=c, mew=1.5)
            if r.get("smallest_within_tolerance"):
                ax.plot([x], [y], "*", ms=13, color=c, markeredgecolor="k")
    ax.plot([], [], "o", ms=11, mfc="none", mec="gray", mew=1.5, label="default (derived) table")
    ax.plot([], [], "*", ms=11, color="gray", markeredgecolor="k", label=f"smallest within {tol:g} dB of the best")
    ax.set_xscale("log")
    from matplotlib.ticker import FuncFormatter
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.xaxis.set_minor_formatter(FuncFormatter(lambda v, _: f"{v:g}" if str(f"{v:g}")[0] in "25" else ""))
    ax.set_xlabel("model bytes (parameters + occupancy, MB, log scale)")
    ax.set_ylabel("test PSNR (dB)")
    ax.set_title(f'PSNR vs model size: hash-table entries per level ({j["iterations"]} iterations each)', fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    out = os.path.join(d, "scenes_psnr_vs_bytes.png")
    fig.savefig(out)
    plt.close(fig)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
