"""Rigid tool surfaces (drape.forming.surfaces) against exact geometry and brute force.

Analytic profiles against closed-form distances (sphere, cylinder, plane, torus); the meshed
search against a brute-force loop over every triangle; the meshed sphere against the exact
sphere within the chord error of the mesh; edge, vertex, far and offset cases.
"""

import math

import numpy as np
import pytest

from drape.forming.surfaces import (Arc, AxisymmetricSurface, MeshedSurface, Profile, Segment,
                         TriangleSurface, closest_point_on_triangles)
from tool_helpers import brute_force, chord_bound, icosphere, wavy_sheet

# no MPI in these tests: under mpirun each rank would do the same (tests/conftest.py)
pytestmark = pytest.mark.serial

RNG = np.random.default_rng(20240611)


def sphere_profile(radius, zc):
    return Profile([Arc((0.0, zc), radius, -0.5 * math.pi, 0.5 * math.pi)])


# --- analytic tools of revolution -------------------------------------------------------------

def test_analytic_sphere_is_exact():
    R, zc = 25.0, 40.0
    tool = AxisymmetricSurface(sphere_profile(R, zc), "ball")
    points = RNG.normal(size=(2000, 3)) * 30.0 + [0.0, 0.0, zc]
    gap, normal, closest = tool.query(points)
    rel = points - [0.0, 0.0, zc]
    dist = np.linalg.norm(rel, axis=1)
    np.testing.assert_allclose(gap, dist - R, atol=1e-12)
    np.testing.assert_allclose(normal, rel / dist[:, None], atol=1e-12)
    np.testing.assert_allclose(closest, [0.0, 0.0, zc] + R * rel / dist[:, None], atol=1e-11)
    assert np.any(gap < 0) and np.any(gap > 0)       # both sides were sampled


def test_analytic_punch_profile_against_closed_forms():
    """Hemisphere (radius 50, apex at z = 0) on a shank up to z = 110: below the equator the
    sphere's distance, beside the shank the cylinder's, above it the top plane's."""
    R, top = 50.0, 110.0
    punch = AxisymmetricSurface(Profile([Arc((0.0, R), R, -0.5 * math.pi, 0.0),
                                         Segment((R, R), (R, top)),
                                         Segment((R, top), (0.0, top))]), "punch")
    theta = RNG.uniform(0, 2 * np.pi, 600)
    # below the equator, anywhere around the sphere (inside and outside)
    phi = RNG.uniform(-0.5 * np.pi, -0.05, 600)
    rad = RNG.uniform(20.0, 80.0, 600)
    below = np.stack([rad * np.cos(phi) * np.cos(theta), rad * np.cos(phi) * np.sin(theta),
                      R + rad * np.sin(phi)], axis=1)
    gap, normal, _ = punch.query(below)
    np.testing.assert_allclose(gap, rad - R, atol=1e-11)
    np.testing.assert_allclose(normal[:, 2], np.sin(phi), atol=1e-12)
    # beside the shank, outside: distance to the cylinder
    r = RNG.uniform(R + 0.1, R + 30.0, 600)
    z = RNG.uniform(R + 1.0, top - 1.0, 600)
    side = np.stack([r * np.cos(theta), r * np.sin(theta), z], axis=1)
    gap, normal, closest = punch.query(side)
    np.testing.assert_allclose(gap, r - R, atol=1e-12)
    np.testing.assert_allclose(normal[:, :2], np.stack([np.cos(theta), np.sin(theta)], 1),
                               atol=1e-12)
    np.testing.assert_allclose(closest[:, 2], z, atol=1e-12)
    # straight above the top face
    above = np.stack([RNG.uniform(-30, 30, 50), RNG.uniform(-30, 30, 50),
                      RNG.uniform(top, top + 40, 50)], axis=1)
    gap, normal, _ = punch.query(above)
    np.testing.assert_allclose(gap, above[:, 2] - top, atol=1e-12)
    np.testing.assert_allclose(normal, np.tile([0.0, 0.0, 1.0], (50, 1)), atol=1e-12)


def die_profile(Ro=55.0, rf=5.0, Rout=150.0, T=50.0, top=0.0):
    return Profile([Segment((Ro, top - T), (Rout, top - T)), Segment((Rout, top - T), (Rout, top)),
                    Segment((Rout, top), (Ro + rf, top)),
                    Arc((Ro + rf, top - rf), rf, 0.5 * math.pi, math.pi),
                    Segment((Ro, top - rf), (Ro, top - T))])


def test_analytic_cutoff_is_exact_within_it_and_a_bound_beyond():
    """With a cutoff, an analytic tool answers exactly for every point within it of the tool
    (the same numbers as without), and a farther point gets a point of the tool's surface and
    the distance to it: at least the true distance and more than the cutoff, positive."""
    R, top = 50.0, 110.0
    punch = AxisymmetricSurface(Profile([Arc((0.0, R), R, -0.5 * math.pi, 0.0),
                                         Segment((R, R), (R, top)),
                                         Segment((R, top), (0.0, top))]), "punch")
    ring = AxisymmetricSurface(Profile([Segment((150.0, 0.0), (60.0, 0.0)),
                                        Arc((60.0, -5.0), 5.0, 0.5 * math.pi, math.pi),
                                        Segment((55.0, -5.0), (55.0, -20.0)),
                                        Segment((55.0, -20.0), (150.0, -20.0)),
                                        Segment((150.0, -20.0), (150.0, 0.0))]), "die")
    points = np.column_stack([RNG.uniform(-170, 170, 40000), RNG.uniform(-170, 170, 40000),
                              RNG.uniform(-60, 130, 40000)])
    offset = np.array([0.0, 0.0, -30.0])
    for tool, shift in ((punch, offset), (ring, None)):
        exact = tool.query(points, shift)
        cut = tool.query(points, shift, cutoff=3.0)
        near = exact.gap <= 3.0
        assert 500 < near.sum() < 39000                    # both kinds were sampled
        for got, want in zip(cut, exact):
            np.testing.assert_array_equal(got[near], want[near])
        beyond = ~np.all(cut.closest == exact.closest, axis=1)
        assert beyond.sum() > 1000 and not np.any(beyond & near)
        assert np.all(cut.gap[beyond] >= exact.gap[beyond]) and np.all(cut.gap[beyond] > 3.0)
        np.testing.assert_allclose(cut.gap[beyond],
                                   np.linalg.norm(points[beyond] - cut.closest[beyond], axis=1),
                                   rtol=1e-12)
        on_surface = tool.query(cut.closest[beyond], shift).gap
        np.testing.assert_allclose(on_surface, 0.0, atol=1e-9)
        np.testing.assert_allclose(np.linalg.norm(cut.normal, axis=1), 1.0, rtol=1e-12)


def test_analytic_die_fillet_is_a_torus():
    """In the fillet's sector the distance is that to the torus' generating circle, minus rf;
    above the top face the height; inside the opening the radial distance to the wall."""
    Ro, rf = 55.0, 5.0
    die = AxisymmetricSurface(die_profile(Ro, rf), "die")
    theta = RNG.uniform(0, 2 * np.pi, 500)
    alpha = RNG.uniform(0.5 * np.pi + 0.01, np.pi - 0.01, 500)
    rad = RNG.uniform(0.5, 20.0, 500)            # from the fillet's centre circle
    r = Ro + rf + rad * np.cos(alpha)
    z = -rf + rad * np.sin(alpha)
    pts = np.stack([r * np.cos(theta), r * np.sin(theta), z], axis=1)
    gap, normal, closest = die.query(pts)
    np.testing.assert_allclose(gap, rad - rf, atol=1e-11)
    np.testing.assert_allclose(np.hypot(closest[:, 0], closest[:, 1]), Ro + rf + rf * np.cos(alpha),
                               atol=1e-11)
    np.testing.assert_allclose(normal[:, 2], np.sin(alpha), atol=1e-12)
    # in the opening, below the fillet: wall distance, normal towards the axis
    r = RNG.uniform(0.0, Ro - 1.0, 300)
    z = RNG.uniform(-45.0, -rf - 0.5, 300)
    th = RNG.uniform(0, 2 * np.pi, 300)
    pts = np.stack([r * np.cos(th), r * np.sin(th), z], axis=1)
    gap, normal, _ = die.query(pts)
    np.testing.assert_allclose(gap, np.minimum(Ro - r, np.hypot(Ro - r, z + 50.0)), atol=1e-11)
    inside_wall = z > -50.0 + (Ro - r)
    np.testing.assert_allclose(normal[inside_wall, :2] * r[inside_wall, None],
                               -pts[inside_wall, :2], atol=1e-9)


def test_analytic_sharp_corner_normal_points_at_the_point():
    """Outside a sharp convex corner (the die's outer top edge) the closest point is the
    corner, the gap the distance to it and the normal the direction to the point; inside, the
    nearer face decides."""
    die = AxisymmetricSurface(die_profile(), "die")
    angle = RNG.uniform(0.01, 0.5 * np.pi - 0.01, 200)
    d = RNG.uniform(0.1, 10.0, 200)
    pts = np.stack([150.0 + d * np.cos(angle), np.zeros(200), d * np.sin(angle)], axis=1)
    gap, normal, closest = die.query(pts)
    np.testing.assert_allclose(gap, d, atol=1e-12)
    np.testing.assert_allclose(closest, np.tile([150.0, 0.0, 0.0], (200, 1)), atol=1e-12)
    np.testing.assert_allclose(normal, np.stack([np.cos(angle), 0 * angle, np.sin(angle)], 1),
                               atol=1e-12)
    inside = np.array([[149.0, 0.0, -3.0], [147.0, 0.0, -1.0]])
    gap, normal, _ = die.query(inside)
    np.testing.assert_allclose(gap, [-1.0, -1.0], atol=1e-12)
    np.testing.assert_allclose(normal, [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], atol=1e-12)


def test_profile_checks():
    with pytest.raises(ValueError, match="do not join"):
        Profile([Segment((0, 0), (1, 0)), Segment((2, 0), (3, 0))])
    with pytest.raises(ValueError, match="axis"):
        Profile([Segment((1, 0), (2, 0)), Segment((2, 0), (2, 1))])
    with pytest.raises(ValueError, match="right angles"):
        Profile([Segment((0, 0), (2, 1)), Segment((2, 1), (0, 3))])


def test_offset_moves_the_tool():
    tool = AxisymmetricSurface(sphere_profile(10.0, 0.0), "ball")
    mesh = MeshedSurface(icosphere(10.0, refinements=2))
    pts = RNG.normal(size=(100, 3)) * 15.0
    offset = np.array([3.0, -2.0, -40.0])
    for surface in (tool, mesh):
        moved = surface.query(pts, offset)
        still = surface.query(pts - offset)
        np.testing.assert_allclose(moved.gap, still.gap, atol=1e-12)
        np.testing.assert_allclose(moved.normal, still.normal, atol=1e-12)
        np.testing.assert_allclose(moved.closest, still.closest + offset, atol=1e-12)


# --- point-triangle projection ----------------------------------------------------------------

def test_point_triangle_projection_is_optimal():
    """The returned point beats every point of a fine barycentric grid, lies in the triangle,
    and the residual is orthogonal to the triangle's plane when it projects inside."""
    m = 200
    a, b, c = RNG.normal(size=(3, m, 3))
    p = RNG.normal(size=(m, 3)) * 2.0
    closest, bary, d2 = closest_point_on_triangles(p, a, b, c)
    assert np.all(bary >= -1e-12) and np.allclose(bary.sum(axis=1), 1.0)
    n = 120
    i, j = np.mgrid[0:n + 1, 0:n + 1]
    keep = i + j <= n
    u, v = i[keep] / n, j[keep] / n
    grid = (u[None, :, None] * a[:, None] + v[None, :, None] * b[:, None]
            + (1 - u - v)[None, :, None] * c[:, None])
    grid_d2 = np.min(np.sum((grid - p[:, None]) ** 2, axis=2), axis=1)
    assert np.all(d2 <= grid_d2 + 1e-12)
    interior = np.all(bary > 1e-6, axis=1)
    normal = np.cross(b - a, c - a)
    residual = np.cross(p - closest, normal)
    assert np.all(np.linalg.norm(residual[interior], axis=1) <=
                  1e-9 * np.linalg.norm(normal[interior], axis=1) * (1 + np.sqrt(d2[interior])))


def test_degenerate_triangle_falls_back_to_its_edges():
    a = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    b = np.array([[2.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    c = np.array([[4.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    p = np.array([[3.0, 1.0, 0.0], [1.0, 1.0, 1.0]])
    closest, _, d2 = closest_point_on_triangles(p, a, b, c)
    np.testing.assert_allclose(closest, [[3.0, 0.0, 0.0], [0.0, 0.0, 0.0]], atol=1e-12)
    np.testing.assert_allclose(d2, [1.0, 3.0], atol=1e-12)


# --- meshed surfaces --------------------------------------------------------------------------

@pytest.mark.parametrize("scale", [0.5, 5.0, 200.0], ids=["near", "mid", "far"])
def test_meshed_search_equals_brute_force(scale):
    """Random points near, around and far from an irregular open sheet: the indexed search finds
    the same distance and closest point as a loop over all triangles."""
    sheet = wavy_sheet()
    anchor = sheet.nodes[RNG.integers(0, len(sheet.nodes), 400)]
    points = anchor + RNG.normal(size=(400, 3)) * scale
    gap, _, closest = MeshedSurface(sheet).query(points)
    dist, ref_closest = brute_force(sheet, points)
    np.testing.assert_allclose(np.abs(gap), dist, rtol=0, atol=1e-10)
    unique = dist > 1e-6
    np.testing.assert_allclose(closest[unique], ref_closest[unique], atol=1e-7 * max(1, scale))


def test_a_large_triangle_behind_many_small_ones_is_found():
    """The k nearest centroids all belong to a fine patch 1.4 mm away, while the closest point
    is 0.6 mm away inside one large triangle whose centroid is 40 mm off: the size classes'
    bound must bring it in."""
    patch = wavy_sheet(n=10, size=6.0, amplitude=0.0)
    nodes = np.concatenate([[[-20.0, -20.0, 0.0], [100.0, -20.0, 0.0], [-20.0, 100.0, 0.0]],
                            patch.nodes + [5.0, 5.0, 2.0]])
    tri = np.concatenate([[[0, 1, 2]], patch.triangles + 3])
    normals = np.tile([0.0, 0.0, 1.0], (len(nodes), 1))
    surface = TriangleSurface("mixed", nodes, tri, normals)
    points = np.array([[5.0, 5.0, 0.6], [6.0, 4.0, 0.9], [3.0, 7.0, -0.5]])
    tool = MeshedSurface(surface)
    _, idx = tool._tree.query(points, k=tool.k)
    assert np.all(idx != 0)                        # the big triangle is not among the first
    gap, normal, closest = tool.query(points)
    np.testing.assert_allclose(gap, [0.6, 0.9, -0.5], atol=1e-12)
    np.testing.assert_allclose(closest, points * [1, 1, 0], atol=1e-12)
    dist, _ = brute_force(surface, points)
    np.testing.assert_allclose(np.abs(gap), dist, atol=1e-12)


def test_meshed_sphere_within_chord_error():
    """An icosphere (nodes on the sphere) against the exact sphere: gaps agree within the
    sagitta bound of its triangles, normals within the normal's turn over a triangle, and the
    sign is positive outside, negative inside."""
    R = 10.0
    sphere = icosphere(R, refinements=3)
    tool = MeshedSurface(sphere)
    bound = chord_bound(sphere, lambda x: np.full(len(x), 1.0 / R))
    assert 0.005 < bound < 0.05        # the test means something: a coarse, curved mesh
    direction = RNG.normal(size=(3000, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    radius = R + RNG.uniform(-4.0, 4.0, 3000)
    points = direction * radius[:, None]
    gap, normal, _ = tool.query(points)
    exact = radius - R
    error = np.abs(gap - exact)
    shell = np.abs(exact) < bound               # between sphere and mesh the sign may differ
    assert np.all(error[~shell] <= bound + 1e-12), error.max()
    assert np.all(error[shell] <= 2 * bound + 1e-12)
    assert error.max() > 0.3 * bound            # and the bound is not loose
    assert np.all(np.sign(gap[~shell]) == np.sign(exact[~shell]))
    edge = sphere.edge_lengths().max()
    assert np.all(np.linalg.norm(normal - direction, axis=1) <= edge / R)


def test_points_on_vertices_and_edges():
    """A node gives gap 0, itself as closest point and its own vertex normal; an edge's
    midpoint gives gap 0 and the normalised mean of the edge's vertex normals."""
    sheet = wavy_sheet()
    tool = MeshedSurface(sheet)
    nodes = RNG.choice(len(sheet.nodes), 50, replace=False)
    gap, normal, closest = tool.query(sheet.nodes[nodes])
    np.testing.assert_allclose(gap, 0.0, atol=1e-12)
    np.testing.assert_allclose(closest, sheet.nodes[nodes], atol=1e-12)
    np.testing.assert_allclose(normal, sheet.normals[nodes], atol=1e-9)
    tri = sheet.triangles[RNG.choice(len(sheet.triangles), 50, replace=False)]
    i, j = tri[:, 0], tri[:, 1]
    mid = 0.5 * (sheet.nodes[i] + sheet.nodes[j])
    gap, normal, closest = tool.query(mid)
    np.testing.assert_allclose(gap, 0.0, atol=1e-12)
    np.testing.assert_allclose(closest, mid, atol=1e-12)
    expected = sheet.normals[i] + sheet.normals[j]
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    np.testing.assert_allclose(normal, expected, atol=1e-9)


def test_normals_are_interpolated_smoothly():
    """Along a line crossing many triangles close to the sheet, the normal changes by no more
    than the vertex normals do over the step (continuous, not facet-wise constant)."""
    sheet = wavy_sheet(n=12)
    tool = MeshedSurface(sheet)
    s = np.linspace(-15.0, 15.0, 3001)
    line = np.stack([s, 0.3 * s, 3.0 * np.sin(s / 6.0) * np.cos(0.3 * s / 9.0) + 0.2], axis=1)
    _, normal, _ = tool.query(line)
    jumps = np.linalg.norm(np.diff(normal, axis=0), axis=1)
    assert jumps.max() < 0.01                     # facets here turn by ~0.3 rad
    facet = sheet.triangle_normals()
    assert np.max(np.linalg.norm(facet[:-1] - facet[1:], axis=1)) > 0.05


def test_far_points_and_cutoff():
    """Far from the sphere the distance is still exact; with a cutoff, points within it are
    exact and farther ones get an upper bound of their distance that exceeds the cutoff."""
    R = 10.0
    sphere = icosphere(R, refinements=3)
    direction = RNG.normal(size=(500, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    radius = np.concatenate([RNG.uniform(R - 2, R + 2, 250), RNG.uniform(1e2, 1e4, 250)])
    points = direction * radius[:, None]
    dist, _ = brute_force(sphere, points)
    gap = MeshedSurface(sphere).query(points).gap
    np.testing.assert_allclose(np.abs(gap), dist, atol=1e-9, rtol=1e-12)
    clear = np.abs(radius - R) > 0.05            # not between the sphere and its mesh
    assert np.all(np.sign(gap[clear]) == np.sign(radius - R)[clear])
    cut = MeshedSurface(sphere).query(points, cutoff=3.0).gap
    near = dist <= 3.0
    np.testing.assert_allclose(cut[near], gap[near], atol=1e-12)
    assert np.all(cut[~near] >= gap[~near] - 1e-12) and np.all(cut[~near] > 3.0)


def test_triangle_surface_checks():
    with pytest.raises(ValueError):
        TriangleSurface("bad", np.zeros((3, 3)), np.array([[0, 1, 3]]), np.zeros((3, 3)))
    with pytest.raises(ValueError):
        TriangleSurface("bad", np.zeros((3, 3)), np.array([[0, 1, 2]]), np.zeros((2, 3)))
