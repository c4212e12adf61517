"""docs/blanks_mesh.png: the clipped yarn lattice of a disc, an octagon and a five-sided patch
with corner cells (run from the repository root: .venv/bin/python scripts/plot_blank_meshes.py)."""
import math

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402

from drape.geometry.clipped_lattice import clipped_lattice  # noqa: E402
from drape.geometry.outline import polygon_outline  # noqa: E402

phi = 2 * np.pi * np.arange(360) / 360
disc = 100 * np.column_stack([np.cos(phi), np.sin(phi)])
octagon = polygon_outline([[108 * math.cos(math.radians(22.5 + 45 * k)),
                            108 * math.sin(math.radians(22.5 + 45 * k))] for k in range(8)])
cases = [("disc R 100, yarns 0/90, h 7", clipped_lattice(disc, 0.0, 7.0, circle=100.0)),
         ("octagon, yarns 30/120, h 7", clipped_lattice(octagon, 30.0, 7.0)),
         ("patch, yarns 30/120, h 3.9", clipped_lattice(polygon_outline(
             [[-70, -40], [50, -50], [60, 30], [-20, 60], [-65, 20]]), 30.0, 3.9))]
fig, axes = plt.subplots(1, 3, figsize=(15, 5))
for ax, (title, (nodes, cells, edge, strip)) in zip(axes, cases):
    on_outline = np.zeros(len(nodes), dtype=bool)
    on_outline[edge.ravel()] = True
    corner = strip & (on_outline[cells].sum(axis=1) == 3)
    colours = np.where(corner, "crimson", np.where(strip, "orange", "lightsteelblue"))
    ax.add_collection(PolyCollection(nodes[cells], facecolors=colours, edgecolors="k",
                                     linewidths=0.3))
    ax.autoscale_view()
    ax.set_aspect("equal")
    ax.set_title(f"{title}\n{len(cells)} cells, {strip.sum()} in the strip (orange; "
                 f"corner cells red: {corner.sum()})", fontsize=9)
fig.tight_layout()
fig.savefig("docs/blanks_mesh.png", dpi=70)
