"""Draws docs/attack/time_error.png: P@0.5 and "person" success against training iterations and
time, from the measurements listed below (docs/attack.md says how each was made). Needs matplotlib:
python3 docs/attack/time_error.py"""
import os
import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt

# iterations: (train seconds logged, NanoDet FV P, RV P, FV person, RV person, CenterNet FV P, RV P)
# Evaluation: cac eval, 50 views per level and set, seed 7 (development views), 512², 4 spp.
ORIGINAL = (0.77, 0.78, 0.0, 0.0, 0.75, 0.68)
RUNS = {
    "overlap, 1 level (shipped)": {
        150: (594, 0.61, 0.46, 0.04, 0.13, 0.51, 0.37),
        300: (889, 0.23, 0.09, 0.46, 0.48, 0.30, 0.15),
        600: (2008, 0.10, 0.04, 0.60, 0.65, 0.13, 0.06),
        900: (2528, 0.04, 0.03, 0.64, 0.68, 0.07, 0.04),
        1200: (3053, 0.03, 0.02, 0.70, 0.72, 0.06, 0.03),
    },
    "overlap, 4 levels": {
        300: (1010, 0.08, 0.07, 0.51, 0.58, 0.11, 0.10),
        600: (1410, 0.12, 0.02, 0.58, 0.70, 0.11, 0.09),
        900: (1986, 0.08, 0.02, 0.68, 0.68, 0.11, 0.06),
        1200: (2546, 0.09, 0.04, 0.63, 0.66, 0.13, 0.09),
    },
    "top-n after NMS (paper's rule)": {
        600: (None, 0.67, 0.62, 0.05, 0.06, 0.53, 0.45),
    },
}

fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
for name, pts in RUNS.items():
    its = sorted(pts)
    for ax, (k, label) in zip(axes, [(1, "NanoDet P@0.5 (FV)"), (3, "NanoDet person (FV)")]):
        ax.plot([0] + its, [ORIGINAL[k - 1]] + [pts[i][k] for i in its], marker="o", label=name)
for ax, title in zip(axes, ["NanoDet P@0.5, free viewpoints (lower is stronger)",
                            "NanoDet \"person\" success, free viewpoints"]):
    ax.set_xlabel("training iterations (batch 2, 320², ~0.37 s each on an idle 2-core machine)")
    ax.set_title(title, fontsize=10)
    ax.set_ylim(-0.02, 1.0)
    ax.grid(alpha=0.3)
axes[0].legend(fontsize=8)
fig.tight_layout()
fig.savefig(os.path.join(os.path.dirname(__file__), "time_error.png"), dpi=90)
