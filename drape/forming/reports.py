"""What a forming job reports: the shear summary, edge draw-in, force-stroke table and plots,
and the shear-angle maps on the formed part and on the flat blank.

Functions taking ``problem`` are collective (every rank calls them; rank 0 gets the result);
the writers and plots run on rank 0 only.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from drape.io.writer import write_table

FORCE_STROKE_FILE = "force_stroke.csv"
FORCE_STROKE_COLUMNS = ("step", "t", "stroke", "punch_force", "die_force", "holder_force",
                        "punch_work", "max_penetration", "punch_contact_area",
                        "max_shear_angle_deg", "regularisation_share", "newton_iterations")
#: quadrilateral vertices in DOLFINx order (tensor product) -> around the cell
QUAD_OUTLINE = [0, 1, 3, 2]


def gather_cells(problem) -> dict | None:
    """Every cell's outline on the flat blank (X, Y) and on the formed part (x, y, z), and its
    mean shear angle (deg), gathered on rank 0."""
    V = problem.V
    n = problem.n_cells
    dofs = V.dofmap.list.array.reshape(-1, V.dofmap.dof_layout.num_dofs)[:n]
    if dofs.shape[1] == 4:
        dofs = dofs[:, QUAD_OUTLINE]
    X = V.tabulate_dof_coordinates()
    u = problem.u.x.array.reshape(-1, 3)
    reference = X[dofs][:, :, :2]
    formed = X[dofs] + u[dofs]
    shear = problem.cell_average(problem.response.gamma_t_deg)
    strain = problem.yarn_strains().reshape(n, -1).max(axis=1)
    strip = np.zeros(n, dtype=bool)
    local = problem.blank_mesh.strip_cells
    strip[local[local < n]] = True
    parts = problem.comm.gather((reference, formed, shear, strain, strip), root=0)
    if problem.comm.rank != 0:
        return None
    return {"reference": np.concatenate([p[0] for p in parts]),
            "formed": np.concatenate([p[1] for p in parts]),
            "shear": np.concatenate([p[2] for p in parts]),
            "yarn_strain": np.concatenate([p[3] for p in parts]),
            "strip": np.concatenate([p[4] for p in parts])}


def strip_summary(cells: dict, yarn_angle: float) -> dict:
    """summary.json's entries on the cells between a clipped yarn lattice and the outline
    (disc and polygon blanks, docs/blanks.md): how many, their share of the blank's area, how
    far their edges turn from the yarns (0 to 45 deg), and the largest yarn strain in them
    and in the yarn-aligned cells, the measure of their locking."""
    from drape.geometry.lattice import misalignment_deg
    strip = cells["strip"]
    if not strip.any():
        return {}
    outline = cells["reference"]
    x, y = outline[:, :, 0], outline[:, :, 1]
    area = 0.5 * np.abs(np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1))
    nodes = outline.reshape(-1, 2)
    quads = np.arange(len(nodes)).reshape(outline.shape[:2])
    off = misalignment_deg(nodes, quads, yarn_angle)[strip]
    strain = cells["yarn_strain"]
    return {"strip_cells": int(strip.sum()),
            "strip_area_fraction": float(area[strip].sum() / area.sum()),
            "strip_misalignment_deg": {"mean": float(off.mean()), "max": float(off.max())},
            "max_yarn_strain_strip": float(strain[strip].max()),
            "max_yarn_strain_aligned": float(strain[~strip].max()) if (~strip).any() else 0.0}


def shear_summary(problem, locking_angle: float, comm, cells=None) -> dict:
    """Largest |shear angle| at the law's points and where (flat blank X, Y and formed x, y, z
    of its cell's centre); the reference area above the locking angle. ``cells``: a boolean
    mask over the local cells to summarise (one ply of a stack), default all."""
    gamma = np.abs(problem.response.gamma_t_deg)
    areas = (problem._average_weights * problem.cell_areas[:, None]).ravel()
    if cells is not None:
        # points outside the mask: no area, and below any angle (-1 marks "none" below)
        points = np.repeat(np.asarray(cells, dtype=bool), problem.nq)
        gamma, areas = np.where(points, gamma, -1.0), np.where(points, areas, 0.0)
    locked = float(areas[gamma > locking_angle].sum())
    total = float(areas.sum())
    if gamma.size and (cells is None or gamma.max() >= 0.0):
        i = int(np.argmax(gamma))
        cell = i // problem.nq
        V = problem.V
        dofs = V.dofmap.list.array.reshape(-1, V.dofmap.dof_layout.num_dofs)[cell]
        centre = (V.tabulate_dof_coordinates()[dofs]
                  + problem.u.x.array.reshape(-1, 3)[dofs]).mean(axis=0)
        best = (float(gamma[i]), problem.point_coordinates[i].tolist(), centre.tolist())
    else:
        best = (-1.0, None, None)
    everyone = comm.gather(best, root=0)
    locked, total = comm.allreduce(locked), comm.allreduce(total)
    if comm.rank != 0:
        return {}
    value, flat, formed = max(everyone, key=lambda b: b[0])
    return {"max_shear_angle_deg": value, "max_shear_flat_xy_mm": flat,
            "max_shear_formed_xyz_mm": formed, "locking_angle_deg": locking_angle,
            "area_above_locking_mm2": locked, "blank_area_mm2": total,
            "fraction_above_locking": locked / total if total else 0.0}


def edge_points(blank) -> dict[str, tuple[float, float]]:
    """Reference points where draw-in is reported: mid-sides and corners of a (centred)
    rectangle, eight points 45 deg apart on a disc's edge, a polygon's vertices (counter-
    clockwise from the first given) and the middles of its edges."""
    if blank.shape == "rectangle":
        a, b = blank.length / 2.0, blank.width / 2.0
        return {"mid_right": (a, 0.0), "mid_top": (0.0, b), "mid_left": (-a, 0.0),
                "mid_bottom": (0.0, -b), "corner_top_right": (a, b), "corner_top_left": (-a, b),
                "corner_bottom_left": (-a, -b), "corner_bottom_right": (a, -b)}
    if blank.shape == "polygon":
        from drape.job import blank_outline
        outline = blank_outline(blank)
        middles = 0.5 * (outline + np.roll(outline, -1, axis=0))
        points = {f"vertex_{k}": tuple(p) for k, p in enumerate(outline.tolist())}
        points.update({f"mid_edge_{k}": tuple(p) for k, p in enumerate(middles.tolist())})
        return points
    r = blank.radius
    return {f"edge_{angle}deg": (r * np.cos(np.radians(angle)), r * np.sin(np.radians(angle)))
            for angle in range(0, 360, 45)}


def draw_in(problem, blank, comm) -> dict:
    """Draw-in (mm) of the blank's edge at :func:`edge_points` (see :func:`edge_draw_in`)."""
    X = problem.V.tabulate_dof_coordinates()[:, :2]
    owned = problem.V.dofmap.index_map.size_local
    u = problem.u.x.array.reshape(-1, 3)[:owned]
    return {"draw_in_mm": edge_draw_in(X[:owned], u, edge_points(blank), comm)}


def edge_draw_in(X, u, targets: dict, comm, tie: float = 1e-6) -> dict[str, float]:
    """Draw-in (mm) at each target point of the edge: the in-plane displacement towards the
    blank's centre, -u . X/|X|, of the node there. Where the point lies midway between nodes
    (a mid-side when an edge has an even number of nodes), the mean over the nearest nodes
    (within ``tie`` mm): the edge's linear interpolation at the point, so that a mirror-symmetric
    field gives mirror-symmetric draw-ins. X (n, 2) and u (n, 3): this rank's owned nodes."""
    out = {}
    for name, target in targets.items():
        target = np.asarray(target, dtype=float)
        radial = target / np.linalg.norm(target)
        if len(X):
            d = np.linalg.norm(X - target, axis=1)
            near = d <= d.min() + tie
            candidate = (float(d.min()), float(np.sum(-(u[near, :2] @ radial))), int(near.sum()))
        else:
            candidate = (np.inf, 0.0, 0)
        everyone = comm.allgather(candidate)
        nearest = min(c[0] for c in everyone)
        picked = [c for c in everyone if c[0] <= nearest + tie]
        out[name] = sum(c[1] for c in picked) / sum(c[2] for c in picked)
    return out


# --- rank 0 writers -------------------------------------------------------------------------------

def write_force_stroke(folder: Path, rows: list) -> None:
    """force_stroke.csv: FORCE_STROKE_COLUMNS (those the job has) of steps.csv's ``rows``
    (drape.step_record.StepRecord.row), rank 0."""
    columns = [c for c in FORCE_STROKE_COLUMNS if c in rows[-1]]
    write_table(Path(folder) / FORCE_STROKE_FILE, columns, rows)


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_force_stroke(folder: Path, rows: list, title: str) -> None:
    plt = _pyplot()
    stroke = np.array([r["stroke"] for r in rows])
    fig, ax = plt.subplots(figsize=(7.5, 5.0), dpi=120)
    ax.plot(stroke, [r.get("punch_force", 0.0) for r in rows], color="tab:blue", lw=2.0,
            marker="o", ms=2.5, label="punch force (contact force summed over the blank)")
    if "holder_force" in rows[-1]:
        ax.plot(stroke, [r.get("holder_force", 0.0) for r in rows], color="tab:gray", lw=1.2,
                ls="--", label="blank-holder force (measured)")
    ax.set_xlabel("punch stroke (mm)")
    ax.set_ylabel("force (N)")
    ax.set_title(title or "punch force against stroke")
    ax.grid(True, alpha=0.3)
    ax.set_xlim(left=0.0)
    ax.set_ylim(bottom=0.0)
    ax.legend(loc="upper left", frameon=False)
    fig.tight_layout()
    fig.savefig(Path(folder) / "force_stroke.png")
    plt.close(fig)


def plot_shear_maps(folder: Path, cells: dict, locking_angle: float, title: str,
                    suffix: str = "") -> None:
    """shear_formed.png (the formed part seen from above and in perspective) and shear_flat.png
    (the flat blank: where the fabric will shear), |shear angle| per cell, the locking angle
    drawn as a contour; ``suffix`` goes before ".png" (one ply's maps: "_ply1")."""
    colours = _ShearColours(np.abs(cells["shear"]), locking_angle)
    _plot_shear_flat(Path(folder) / f"shear_flat{suffix}.png", cells["reference"], colours,
                     title)
    _plot_shear_formed(Path(folder) / f"shear_formed{suffix}.png", cells["formed"], colours,
                       title)


class _ShearColours:
    """One colour scale for both shear maps: |shear angle| (deg) from 0 to the largest (at
    least 1.05 x the locking angle), the locking angle marked on the bar and as a contour."""

    def __init__(self, shear: np.ndarray, locking_angle: float):
        self.plt = _pyplot()
        self.shear, self.locking_angle = shear, locking_angle
        top = max(float(shear.max()), locking_angle * 1.05)
        self.cmap = self.plt.get_cmap("turbo")
        self.norm = self.plt.Normalize(0.0, top)

    def contour(self, ax, polygons) -> None:
        """The locking angle's contour over the cells' centres (white under dashed black)."""
        shear, locking_angle = self.shear, self.locking_angle
        centres = polygons.mean(axis=1)
        if shear.max() > locking_angle and len(centres) > 3:
            ax.tricontour(centres[:, 0], centres[:, 1], shear, levels=[locking_angle],
                          colors="white", linewidths=1.6)
            ax.tricontour(centres[:, 0], centres[:, 1], shear, levels=[locking_angle],
                          colors="black", linewidths=0.8, linestyles="--")

    def colourbar(self, fig, ax, pad=0.05) -> None:
        bar = fig.colorbar(self.plt.cm.ScalarMappable(norm=self.norm, cmap=self.cmap), ax=ax,
                           shrink=0.85, pad=pad)
        bar.set_label(f"|shear angle| (deg); black line: locking angle, {self.locking_angle:g}")
        bar.ax.axhline(self.locking_angle, color="black", lw=1.5)


def _plot_shear_flat(path: Path, reference: np.ndarray, colours: _ShearColours,
                     title: str) -> None:
    """The flat blank's cells (X, Y) coloured by |shear angle|, with the locking contour."""
    from matplotlib.collections import PolyCollection

    plt = colours.plt
    # a figure as wide as the blank's aspect wants (a 470 x 235 mm blank in a square figure
    # leaves its colour bar twice the plot's height)
    extent = np.ptp(reference.reshape(-1, 2), axis=0)
    aspect = float(extent[0] / extent[1]) if extent[1] > 0 else 1.0
    fig, ax = plt.subplots(figsize=(float(np.clip(2.5 + 4.5 * aspect, 7.0, 13.0)), 5.5),
                           dpi=120)
    ax.add_collection(PolyCollection(reference, array=colours.shear, cmap=colours.cmap,
                                     norm=colours.norm, edgecolors="face", linewidths=0.2))
    colours.contour(ax, reference)
    ax.autoscale_view()
    ax.set_aspect("equal")
    ax.set_xlabel("X on the flat blank (mm)")
    ax.set_ylabel("Y on the flat blank (mm)")
    ax.set_title((title + "\n" if title else "") + "shear angle at the end, on the flat blank "
                 "(dashed: locking angle)", fontsize=10)
    colours.colourbar(fig, ax)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _plot_shear_formed(path: Path, formed: np.ndarray, colours: _ShearColours,
                       title: str) -> None:
    """The formed part's cells (x, y, z) coloured by |shear angle|: from above, and in
    perspective."""
    from matplotlib.collections import PolyCollection
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    plt, shear, cmap, norm = colours.plt, colours.shear, colours.cmap, colours.norm
    fig = plt.figure(figsize=(13.0, 6.0), dpi=120)
    ax = fig.add_subplot(1, 2, 1)
    order = np.argsort(formed[:, :, 2].mean(axis=1))         # higher cells drawn last
    ax.add_collection(PolyCollection(formed[order][:, :, :2], array=shear[order], cmap=cmap,
                                     norm=norm, edgecolors="face", linewidths=0.2))
    ax.autoscale_view()
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title("formed part, from above", fontsize=10)
    ax3 = fig.add_subplot(1, 2, 2, projection="3d")
    ax3.add_collection3d(Poly3DCollection(formed, facecolors=cmap(norm(shear)), edgecolors="none"))
    span = np.ptp(formed.reshape(-1, 3), axis=0)
    low = formed.reshape(-1, 3).min(axis=0)
    ax3.set_xlim(low[0], low[0] + span[0])
    ax3.set_ylim(low[1], low[1] + span[1])
    ax3.set_zlim(low[2], low[2] + max(span[2], 1.0))
    ax3.set_box_aspect((span[0], span[1], max(span[2], 1.0)))
    ax3.view_init(elev=35, azim=-60)
    ax3.locator_params(axis="z", nbins=3)           # a shallow part's z axis is short
    ax3.set_xlabel("x (mm)")
    ax3.set_ylabel("y (mm)")
    ax3.set_zlabel("z (mm)")
    ax3.set_title("formed part", fontsize=10)
    colours.colourbar(fig, ax3, pad=0.12)      # room for the 3-d axes' z label
    fig.suptitle((title + ": " if title else "") + "shear angle at the end of the stroke")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
