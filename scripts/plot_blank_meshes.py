"""docs/blanks_mesh.png: the clipped yarn lattice of a disc and an octagon (run from the repository root)."""
import math, numpy as np, matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.collections import PolyCollection
from drape.geometry.blank import clipped_lattice, polygon_outline
phi = 2 * np.pi * np.arange(360) / 360
fig, axes = plt.subplots(1, 2, figsize=(10, 5))
cases = [("disc R 100, yarns 0/90, h 7", clipped_lattice(100 * np.column_stack([np.cos(phi), np.sin(phi)]), 0.0, 7.0, circle=100.0)),
         ("octagon, yarns 30/120, h 7", clipped_lattice(polygon_outline([[108 * math.cos(math.radians(22.5 + 45 * k)), 108 * math.sin(math.radians(22.5 + 45 * k))] for k in range(8)]), 30.0, 7.0))]
for ax, (title, (nodes, cells, edge, strip)) in zip(axes, cases):
    ax.add_collection(PolyCollection(nodes[cells], facecolors=np.where(strip, "orange", "lightsteelblue"), edgecolors="k", linewidths=0.3))
    ax.autoscale_view(); ax.set_aspect("equal"); ax.set_title(f"{title}: {len(cells)} cells, {strip.sum()} in the strip (orange)", fontsize=9)
fig.tight_layout(); fig.savefig("docs/blanks_mesh.png", dpi=70)
