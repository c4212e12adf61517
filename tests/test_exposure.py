"""Which points of a stack each tool touches (drape.forming.exposure): on flat plies against
the outlines' closed form, on plies moved past each other's edges, and on plies wrapped round
a cylinder (the cover is taken along the surface's normal, so the wrap changes nothing)."""

import numpy as np
import pytest

from drape.forming.exposure import StackExposure
from drape.forming.ply_surfaces import StackNodes, split_cells

THICKNESS = 0.3


def grid(length, width, size, z):
    """A structured quad mesh of a length x width rectangle centred on the axis, at height z:
    nodes (N, 3) and counter-clockwise quads (M, 4)."""
    nx, ny = int(round(length / size)), int(round(width / size))
    x, y = np.meshgrid(np.linspace(-length / 2, length / 2, nx + 1),
                       np.linspace(-width / 2, width / 2, ny + 1), indexing="ij")
    nodes = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])
    index = np.arange(x.size).reshape(nx + 1, ny + 1)
    quads = np.column_stack([index[:-1, :-1].ravel(), index[1:, :-1].ravel(),
                             index[1:, 1:].ravel(), index[:-1, 1:].ravel()])
    return nodes, quads


def stack(*plies):
    """StackNodes of plies given as (length, width), bottom first, 5 mm quads, 0.3 mm apart;
    and per ply the centres of its quads (the points a tool would see), with their plies."""
    reference, triangles, triangle_ply, ply, points, point_plies = [], [], [], [], [], []
    count = 0
    for k, (length, width) in enumerate(plies):
        nodes, quads = grid(length, width, 5.0, k * THICKNESS)
        tri, _ = split_cells(quads, nodes[:, :2], dolfinx_quads=False)
        reference.append(nodes)
        triangles.append(tri + count)
        triangle_ply.append(np.full(len(tri), k))
        ply.append(np.full(len(nodes), k))
        points.append(nodes[quads].mean(axis=1))
        point_plies.append(np.full(len(quads), k))
        count += len(nodes)
    reference = np.vstack(reference)
    nodes = StackNodes(reference, np.concatenate(ply), np.ones(len(reference)),
                       np.vstack(triangles), np.concatenate(triangle_ply))
    return nodes, np.vstack(points), np.concatenate(point_plies)


def inside(points, length, width, shift=0.0):
    return (np.abs(points[:, 0] - shift) < length / 2) & (np.abs(points[:, 1]) < width / 2)


def test_flat_plies_expose_what_the_outlines_leave_uncovered():
    """A 100 x 100 ply under a 60 x 140 one: from above, the bottom ply's points outside
    |x| < 30 (the top ply's extent) are exposed; from below, the top ply's points past
    |y| < 50 (the bottom ply's); every ply's own side is exposed."""
    nodes, points, plies = stack((100.0, 100.0), (60.0, 140.0))
    above, below = StackExposure(nodes).masks(nodes.reference, plies, points)
    bottom, top = plies == 0, plies == 1
    assert np.array_equal(above[bottom], ~inside(points[bottom], 60.0, 140.0))
    assert above[top].all() and below[bottom].all()
    assert np.array_equal(below[top], ~inside(points[top], 100.0, 100.0))
    assert 0 < above[bottom].sum() < bottom.sum() and 0 < below[top].sum() < top.sum()


def test_plies_moved_past_each_others_edges_expose_other_points():
    """The top ply moved 16 mm along x (its nodes and its points): the bottom ply's points
    it uncovers are exposed from above, those it now covers are not, as the moved outline
    says (three columns of 20 points each way); the top ply's points now past the bottom
    ply's edge are exposed from below."""
    nodes, points, plies = stack((100.0, 100.0), (60.0, 140.0))
    shift = np.array([16.0, 0.0, 0.0])
    x_nodes = nodes.reference + np.where((nodes.ply == 1)[:, None], shift, 0.0)
    moved = points + np.where((plies == 1)[:, None], shift, 0.0)
    above, below = StackExposure(nodes).masks(x_nodes, plies, moved)
    bottom, top = plies == 0, plies == 1
    assert np.array_equal(above[bottom], ~inside(moved[bottom], 60.0, 140.0, shift=16.0))
    assert np.array_equal(below[top], ~inside(moved[top], 100.0, 100.0))
    before, _ = StackExposure(nodes).masks(nodes.reference, plies, points)
    assert (above[bottom] != before[bottom]).sum() == 2 * 3 * 20


@pytest.mark.parametrize("radius", [40.0, 400.0])
def test_plies_wrapped_round_a_cylinder_are_covered_as_flat_ones(radius):
    """The flat stack of the first test wrapped round a cylinder of axis y (ply k at radius
    R + z_k, a point at x at the angle x / R: each ply keeps its cover along the normal):
    the masks are the flat ones, the points nearest an outline 2.5 mm from it."""
    nodes, points, plies = stack((100.0, 100.0), (60.0, 140.0))

    def wrap(p):
        angle, r = p[:, 0] / radius, radius + p[:, 2]
        return np.column_stack([r * np.sin(angle), p[:, 1], r * np.cos(angle) - radius])

    flat = StackExposure(nodes).masks(nodes.reference, plies, points)
    wrapped = StackExposure(nodes).masks(wrap(nodes.reference), plies, wrap(points))
    assert np.array_equal(flat[0], wrapped[0]) and np.array_equal(flat[1], wrapped[1])


# --- the stack as laid up (drape.forming.layup) ---------------------------------------------------

def test_laid_heights_step_down_past_a_partial_ply_and_match_whole_plies_to_the_bit():
    """Whole plies (100 mm squares, thicknesses 0.3, 0.2, 0.4): every node at
    plies.ply_heights, bit for bit, and k + 1 plies in ply k's columns (itself included). A
    40 mm patch between two squares: the bottom square at 0, the patch at (0.3 + 0.2)/2, the
    top square at 0.25 + (0.2 + 0.4)/2 over the patch and within one of its elements (5 mm quads'
    diagonal) of it, at (0.3 + 0.4)/2 on the bottom square farther out, with two plies in
    those columns. The ply past its neighbour each node touches (layup.bridged_ply): none
    for whole plies; with the patch, the other square for the squares' nodes outside the
    patch or over its last element inside its edge, none for the patch's own nodes."""
    from drape.forming.layup import bridged_ply, laid_heights
    from drape.forming.plies import ply_heights
    thicknesses = (0.3, 0.2, 0.4)
    for sizes, whole in ((((100.0, 100.0),) * 3, True),
                         (((100.0, 100.0), (40.0, 40.0), (100.0, 100.0)), False)):
        nodes, _, _ = stack(*sizes)
        xy, ply = nodes.reference[:, :2], nodes.ply
        args = (xy, nodes.triangles, nodes.triangle_ply)
        height, column = laid_heights(*args, thicknesses, xy, ply)
        under = bridged_ply(*args, 3, xy, ply, 1.0)
        over = bridged_ply(*args, 3, xy, ply, 1.0, above=True)
        if whole:
            assert np.array_equal(height, np.asarray(ply_heights(thicknesses))[ply])
            assert np.array_equal(column, ply + 1)
            assert (under == -1).all() and (over == -1).all()
            continue
        reach = 5.0 * np.sqrt(2.0)
        gap = np.linalg.norm(np.maximum(np.abs(xy) - 20.0, 0.0), axis=1)    # to the patch
        near = gap <= reach + 1e-9
        top, bottom = ply == 2, ply == 0
        assert (height[bottom] == 0.0).all() and np.allclose(height[ply == 1], 0.25)
        assert np.allclose(height[top & near], 0.55) and np.allclose(height[top & ~near], 0.35)
        assert (column[top & near] == 3).all() and (column[top & ~near] == 2).all()
        edge_band = 20.0 - np.abs(xy).max(axis=1) < reach                    # inside by < 1
        assert np.array_equal(under[top], np.where(edge_band[top], 0, -1))
        assert np.array_equal(over[bottom], np.where(edge_band[bottom], 2, -1))
        assert (under[~top] == -1).all() and (over[~bottom] == -1).all()


def test_the_ply_contact_bridges_plies_that_a_partial_ply_leaves_touching():
    """The same patch between two squares: besides the four directions of the two
    interfaces, two bridge the squares (top on bottom and bottom under top, counted to
    interface 1, with its law), their slaves the squares' nodes outside the patch's outline,
    the element past its edge included, where the top square steps down and leaves the patch's
    contact (the laid heights' test), and those over the patch's last element (5 mm quads'
    diagonal) inside its edge, which the patch uncovers if it slides that far; whole plies get
    no bridge."""
    from drape.forming.ply_contact import PlyContact
    from drape.forming.ply_pair import FrictionLaw
    laws = [FrictionLaw(0.2), FrictionLaw(0.3)]
    args = ((0.3, 0.2, 0.4), laws, 1.0, 0.1, 0.01)
    nodes, _, _ = stack((100.0, 100.0), (100.0, 100.0), (100.0, 100.0))
    assert len(PlyContact(nodes, *args).directions) == 4
    nodes, _, _ = stack((100.0, 100.0), (40.0, 40.0), (100.0, 100.0))
    bridges = PlyContact(nodes, *args).directions[4:]
    assert [(d.slave, d.master, d.sign, d.interface) for d in bridges] == [
        (0, 2, -1.0, 1), (2, 0, 1.0, 1)]
    assert all(d.law is laws[1] and d.offset == pytest.approx(0.35) for d in bridges)
    depth = 20.0 - np.abs(nodes.reference[:, :2]).max(axis=1)      # inside the patch's edge
    bridged = depth < 5.0 * np.sqrt(2.0)
    assert np.count_nonzero(bridged & (depth > 0.0) & (nodes.ply == 2)) == 7 * 7 - 5 * 5
    assert np.array_equal(bridges[0].slaves, (nodes.ply == 0) & bridged)
    assert np.array_equal(bridges[1].slaves, (nodes.ply == 2) & bridged)
