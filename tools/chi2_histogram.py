#!/usr/bin/env python3
"""Histogram of the squared normalised errors that `tools/eval_rooms.py --calibration --keep DIR`
saved (chi2_ROOM_INPUT.npy), against the chi-square density with 2 degrees of freedom.

    python tools/chi2_histogram.py DIR docs/chi2.png

Needs numpy and matplotlib.
"""
import glob
import os
import sys

import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

src, out = sys.argv[1], sys.argv[2]
files = sorted(glob.glob(os.path.join(src, "chi2_*.npy")))
fig, axes = plt.subplots(2, len(files), figsize=(4 * len(files), 6.5), squeeze=False)
x = np.linspace(0, 16, 400)
density = 0.5 * np.exp(-x / 2)
for col, path in enumerate(files):
    name = os.path.basename(path)[5:-4].replace("_", ", ")
    ch = np.load(path)
    for row, (label, values) in enumerate((("direction", ch[:, 0]), ("position (midpoint)", ch[:, 1]))):
        ax = axes[row][col]
        clipped = np.clip(values, 0, 16)
        ax.hist(clipped, bins=32, range=(0, 16), density=True, color="#6a9fd4", label=f"{len(values)} segments")
        ax.plot(x, density, "k-", lw=1.5, label="χ², 2 dof")
        for q, style in ((5.991, "--"), (9.210, ":")):
            ax.axvline(q, color="#c0392b", ls=style, lw=1)
        ax.set_title(f"{name}: {label}\n{np.mean(values <= 5.991):.1%} ≤ q95, {np.mean(values <= 9.210):.1%} ≤ q99", fontsize=9)
        ax.set_xlabel("squared normalised error (values above 16 in the last bin)", fontsize=8)
        ax.set_ylabel("density", fontsize=8)
        ax.legend(fontsize=7)
fig.tight_layout()
fig.savefig(out, dpi=80)
print("wrote", out)
