#!/usr/bin/env python3
"""Summarises `clnerf bench continual` JSON files of one sweep directory.

Writes <dir>/continual.csv (one row per run), <dir>/continual.md (markdown
table) and, when matplotlib is available, <dir>/continual.png: final mean PSNR
against total update time, one line per method/init through its budgets.
Usage: summarize_continual.py DIR
"""
import csv
import glob
import json
import os
import sys

COLUMNS = ["label", "method", "init", "replay", "buffer", "embeddings", "iterations", "ub_budget", "ub_iterations",
           "status", "psnr", "ssim", "scan0_psnr", "first_scan_drop_db", "backward_transfer_db",
           "mean_update_seconds", "max_update_seconds", "total_seconds", "model_bytes", "replay_bytes",
           "replay_bytes_per_camera", "replay_cache_peak_bytes", "peak_rss_bytes", "failed_step"]
ORDER = ["ub", "clnerf", "clnerf-noer", "meil", "er", "ewc", "nt"]


def label_of(j):
    if j["method"] == "ub":
        # Runs before the equal-compute default trained ub for one update's
        # iterations: they have no ub_budget field.
        budget = j.get("ub_budget", "per-step")
        s = "ub (equal compute)" if budget == "total" else "ub (one update's budget)"
        return s + ("" if j.get("embeddings", True) else " no-embed")
    s = f'{j["method"]} ({j["init"]}'
    if j.get("replay") == "online" and j["method"] in ("clnerf", "clnerf-noer", "meil"):
        s += ", online"
    if not j.get("embeddings", True):
        s += ", no-embed"
    return s + ")"


def load(d):
    rows = []
    for path in sorted(glob.glob(os.path.join(d, "*.json"))):
        with open(path) as f:
            j = json.load(f)
        if "method" not in j or "iterations" not in j:
            continue
        r = {k: j.get(k) for k in COLUMNS}
        r["label"] = label_of(j)
        per = j.get("psnr_per_step") or []
        r["scan0_psnr"] = per[0] if per else None
        r["ub_budget"] = j.get("ub_budget", "per-step") if j["method"] == "ub" else None
        m = j.get("psnr_matrix") or []
        if j["method"] != "ub" and r["backward_transfer_db"] is None and len(m) > 1 and j.get("status") == "ok":
            # Runs from before the field existed: the same formula on their matrix.
            T = len(m)
            r["backward_transfer_db"] = sum(m[T - 1][k] - m[k][k] for k in range(T - 1)) / (T - 1)
        if j["method"] != "ub" and r["mean_update_seconds"] is None and j.get("total_seconds") and m:
            r["mean_update_seconds"] = j["total_seconds"] / len(m)
        rows.append(r)
    key = lambda r: (ORDER.index(r["method"]) if r["method"] in ORDER else 99, r["label"], r["iterations"])
    return sorted(rows, key=key)


def fmt(v, spec):
    return "-" if v is None else format(v, spec)


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    d = sys.argv[1]
    rows = load(d)
    if not rows:
        sys.exit(f"no bench JSON in {d}")
    with open(os.path.join(d, "continual.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows(rows)
    lines = ["| method | iters/step | PSNR | SSIM | scan-0 PSNR | scan-0 drop | BWT | time per update | total time | model "
             "| replay memory |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r["status"] != "ok":
            lines.append(f'| {r["label"]} | {r["iterations"]} | diverged at update {r["failed_step"] + 1} | | | | | | | | |')
            continue
        lines.append(
            f'| {r["label"]} | {r["iterations"]} | {fmt(r["psnr"], ".2f")} | {fmt(r["ssim"], ".4f")} | '
            f'{fmt(r["scan0_psnr"], ".2f")} | {fmt(r["first_scan_drop_db"], ".2f")} | '
            f'{fmt(r["backward_transfer_db"], "+.2f")} | '
            f'{fmt(r["mean_update_seconds"], ".1f") + " s" if r["mean_update_seconds"] is not None else "-"} | '
            f'{fmt(r["total_seconds"], ".0f")} s | {r["model_bytes"] / 1e6:.1f} MB | '
            f'{fmt(r["replay_bytes"] / 1e3 if r["replay_bytes"] else 0, ".1f")} kB |')
    table = "\n".join(lines)
    with open(os.path.join(d, "continual.md"), "w") as f:
        f.write(table + "\n")
    print(table)
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not installed (apt install python3-matplotlib); no chart written", file=sys.stderr)
        return
    fig, ax = plt.subplots(figsize=(10, 5), dpi=120)
    labels = []
    for r in rows:
        if r["label"] not in labels:
            labels.append(r["label"])
    for lab in labels:
        pts = sorted([r for r in rows if r["label"] == lab and r["status"] == "ok"], key=lambda r: r["iterations"])
        bad = [r for r in rows if r["label"] == lab and r["status"] != "ok"]
        name = lab + (f' (diverged at {", ".join(str(r["iterations"]) for r in bad)} it/step)' if bad else "")
        if not pts:
            ax.plot([], [], "x", label=name)
            continue
        xs = [r["total_seconds"] / 60 for r in pts]
        ys = [r["psnr"] for r in pts]
        style = "--" if lab.startswith("ub") else "-"
        ax.plot(xs, ys, style + "o", label=name)
        for r, x, y in zip(pts, xs, ys):
            ax.annotate(str(r["iterations"]), (x, y), textcoords="offset points", xytext=(4, -10), fontsize=7)
    scene = os.path.basename(os.path.normpath(d))
    ax.set_xlabel("total update time over all steps (minutes, 2 CPU cores)")
    ax.set_ylabel("final mean PSNR over all test images (dB)")
    ax.set_title(f"Continual NeRF: accuracy vs time ({scene}); labels = iterations per step")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, bbox_to_anchor=(1.02, 1), loc="upper left")
    fig.tight_layout()
    out = os.path.join(d, "continual.png")
    fig.savefig(out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
