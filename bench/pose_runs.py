#!/usr/bin/env python3
"""Splits a transforms.json capture into the two runs `clnerf check-poses` found.

Usage: python3 bench/pose_runs.py DATA CHECK.json OUT
Writes OUT/disputed/ and OUT/agreeing/, each with transforms_train.json and
transforms_test.json holding only that run's frames (the images are linked,
not copied), so that each run can be trained and scored alone:
  clnerf train --data OUT/disputed --out first.clnerf --pose-check off
"""
import json
import os
import sys


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    data, check_path, out = sys.argv[1:]
    disputed = set(json.load(open(check_path))["disputed"])
    for run, keep in (("disputed", True), ("agreeing", False)):
        d = os.path.join(out, run)
        os.makedirs(d, exist_ok=True)
        for entry in os.listdir(data):
            src = os.path.join(os.path.abspath(data), entry)
            if os.path.isdir(src) and not os.path.exists(os.path.join(d, entry)):
                os.symlink(src, os.path.join(d, entry))
        for split in ("train", "test"):
            t = json.load(open(os.path.join(data, "transforms_%s.json" % split)))
            t["frames"] = [f for f in t["frames"] if (f["file_path"] in disputed) == keep]
            json.dump(t, open(os.path.join(d, "transforms_%s.json" % split), "w"), indent=1)
            print("%s %s: %d frames" % (run, split, len(t["frames"])))


if __name__ == "__main__":
    main()
