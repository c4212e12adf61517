"""docs/blanks_mesh.png: the clipped yarn lattice of a disc and an octagon (run from the
repository root: .venv/bin/python scripts/plot_blank_meshes.py)."""
import math

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402

from drape.geometry.lattice import clipped_lattice  # noqa: E402
from drape.geometry.outline import polygon_outline  # noqa: E402

phi = 2 * np.pi * np.arange(360) / 360
disc = 100 * np.column_stack([np.cos(phi), np.sin(phi)])
octagon = polygon_outline([[108 * math.cos(math.radians(22.5 + 45 * k)),
                            108 * math.sin(math.radians(22.5 + 45 * k))] for k in range(8)])
cases = [("disc R 100, yarns 0/90, h 7", clipped_lattice(disc, 0.0, 7.0, circle=100.0)),
         ("octagon, yarns 30/120, h 7", clipped_lattice(octagon, 30.0, 7.0))]
fig, axes = plt.subplots(1, 2, figsize=(10, 5))
for ax, (title, (nodes, cells, edge, strip)) in zip(axes, cases):
    colours = np.where(strip, "orange", "lightsteelblue")
    ax.add_collection(PolyCollection(nodes[cells], facecolors=colours, edgecolors="k",
                                     linewidths=0.3))
    ax.autoscale_view()
    ax.set_aspect("equal")
    ax.set_title(f"{title}: {len(cells)} cells, {strip.sum()} in the strip (orange)", fontsize=9)
fig.tight_layout()
fig.savefig("docs/blanks_mesh.png", dpi=70)
