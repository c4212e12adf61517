"""Blank meshes (geometry/blank.py, drape/fe/mesh.py): areas, named boundaries, yarn alignment,
conformity of the +-45 deg diamond lattice, and clear errors for meshes that cannot be built."""

import math

import numpy as np
import pytest

from drape.errors import InputError
from drape.geometry.lattice import diamond_lattice, lattice_periods
from drape.job import BlankConfig, MeshConfig


# --- the diamond lattice (numpy only) ----------------------------------------------------------

def _edges(cells):
    edges = np.sort(np.stack([cells, np.roll(cells, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    return unique, counts


@pytest.mark.parametrize("length, width, size",
                         [(100.0, 50.0, 4.5), (150.0, 60.0, 7.0), (50.0, 50.0, 3.0)])
def test_diamond_lattice_is_conforming_and_fills_the_rectangle(length, width, size):
    nodes, cells, sides = diamond_lattice(length, width, size)
    x, y = nodes[cells, 0], nodes[cells, 1]
    area = 0.5 * np.sum(x * np.roll(y, -1, 1) - np.roll(x, -1, 1) * y, axis=1)
    assert np.all(area > 0) and area.sum() == pytest.approx(length * width, rel=1e-12)
    edges, counts = _edges(cells)
    assert set(counts) == {1, 2}                      # no hanging nodes, no overlaps
    boundary = edges[counts == 1]
    on_outline = lambda p: (np.isclose(p[:, 0], 0) | np.isclose(p[:, 0], length)  # noqa: E731
                            | np.isclose(p[:, 1], 0) | np.isclose(p[:, 1], width))
    assert np.all(on_outline(nodes[boundary[:, 0]]) & on_outline(nodes[boundary[:, 1]]))
    assert sum(len(s) for s in sides.values()) == len(boundary)


def test_diamond_lattice_follows_the_yarns_and_the_bias_extension_zones():
    length, width = 100.0, 50.0
    nodes, cells, _ = diamond_lattice(length, width, 4.5)
    d = nodes[np.roll(cells, -1, axis=1)] - nodes[cells]
    angle = np.degrees(np.arctan2(d[..., 1], d[..., 0])) % 90.0
    aligned = np.all(np.isclose(angle, 45.0, atol=1e-9), axis=1)
    # all but the cells of the row along the outline (3 per cut half-diamond)
    i, j = lattice_periods(length, width, 4.5)
    assert aligned.sum() == len(cells) - 3 * 2 * (2 * i + 2 * j) // 2
    # the yarn lines through the corners (the zone borders of the bias-extension test) are
    # mesh lines: no cell has vertices strictly on both sides of any of them
    for (x0, y0), sign in (((0, 0), 1), ((0, width), -1), ((length, 0), -1), ((length, width), 1)):
        side = (nodes[:, 1] - y0) - sign * (nodes[:, 0] - x0)
        s = side[cells]
        assert not np.any((s.max(axis=1) > 1e-9) & (s.min(axis=1) < -1e-9))


def test_lattice_needs_a_compatible_outline():
    assert lattice_periods(100.0, 50.0, 4.5) == (8, 4)
    with pytest.raises(InputError) as caught:
        lattice_periods(100.0 * math.sqrt(2.0), 50.0, 4.5)
    assert caught.value.key == "blank.length"


# --- distributed meshes ---------------------------------------------------------------------------

def _measure(blank_mesh, name=None):
    import ufl
    from dolfinx import fem
    msh = blank_mesh.mesh
    if name is None:
        form = 1.0 * ufl.dx(domain=msh)
    else:
        ds = ufl.ds(domain=msh, subdomain_data=blank_mesh.facet_tags)
        form = 1.0 * ds(blank_mesh.boundaries[name])
    return msh.comm.allreduce(fem.assemble_scalar(fem.form(form)))


@pytest.mark.parametrize("yarn_angle, cell", [(0.0, "quadrilateral"), (90.0, "triangle"),
                                               (45.0, "quadrilateral"), (-45.0, "triangle")])
def test_aligned_rectangles(comm, yarn_angle, cell):
    from drape.fe.mesh import create_blank_mesh
    blank = BlankConfig(length=100.0, width=50.0, yarn_angle=yarn_angle)
    bm = create_blank_mesh(comm, blank, MeshConfig(cell=cell, size=6.0))
    assert bm.mesh.topology.cell_type.name == cell
    assert _measure(bm) == pytest.approx(5000.0, rel=1e-12)
    for name, length in (("left", 50.0), ("right", 50.0), ("bottom", 100.0), ("top", 100.0)):
        assert _measure(bm, name) == pytest.approx(length, rel=1e-12)


def test_free_meshes_and_the_aligned_disc(comm):
    from drape.fe.mesh import create_blank_mesh
    bm = create_blank_mesh(comm, BlankConfig(length=80.0, width=30.0, yarn_angle=30.0),
                           MeshConfig(pattern="free", cell="quadrilateral", size=5.0))
    assert _measure(bm) == pytest.approx(2400.0, rel=1e-12)
    assert _measure(bm, "top") == pytest.approx(80.0, rel=1e-12)
    theta = 30.0
    bm = create_blank_mesh(comm, BlankConfig(shape="disc", radius=40.0, yarn_angle=theta),
                           MeshConfig(size=4.0))
    assert _measure(bm) == pytest.approx(math.pi * 40.0 ** 2, rel=0.01)
    assert _measure(bm, "edge") == pytest.approx(2 * math.pi * 40.0, rel=0.01)
    # the central square's cells have their edges along the yarns
    msh = bm.mesh
    n = msh.topology.index_map(2).size_local
    cells = msh.geometry.dofmap.array.reshape(-1, 4)[:n]
    x = msh.geometry.x[:, :2]
    central = cells[np.all(np.abs((x[cells] @ [math.cos(math.radians(theta + 45)),
                                                math.sin(math.radians(theta + 45))])) < 10.0,
                           axis=1)
                    & np.all(np.abs((x[cells] @ [math.cos(math.radians(theta - 45)),
                                                  math.sin(math.radians(theta - 45))])) < 10.0,
                             axis=1)]
    # dolfinx quadrilateral vertices 0 1 / 2 3 (tensor order): edges 0-1, 0-2, 1-3, 2-3
    edges = x[central[:, [1, 2, 3, 3]]] - x[central[:, [0, 0, 1, 2]]]
    angle = np.degrees(np.arctan2(edges[..., 1], edges[..., 0])) % 90.0
    assert comm.allreduce(len(central)) > 0
    assert np.allclose(np.minimum(abs(angle - theta), 90 - abs(angle - theta)), 0.0, atol=1e-6)


@pytest.mark.parametrize("blank, mesh, key", [
    (BlankConfig(length=100.0, width=50.0, yarn_angle=30.0), MeshConfig(), "blank.yarn_angle"),
    (BlankConfig(length=100.0 * math.sqrt(2), width=50.0, yarn_angle=45.0), MeshConfig(),
     "blank.length"),
    (BlankConfig(length=1000.0, width=1000.0), MeshConfig(size=0.1), "mesh.size"),
])
def test_meshes_that_cannot_be_built_are_input_errors_on_every_rank(comm, blank, mesh, key):
    from drape.fe.mesh import create_blank_mesh
    with pytest.raises(InputError) as caught:
        create_blank_mesh(comm, blank, mesh)
    assert caught.value.key == key
