"""Kinematic draping (drape.forming.kinematic, the fishnet): no shear on developable moulds (a
plane, a
cylinder, yarns along it or at 45 deg to it: they unroll without shear), the square's symmetry
and the diagonal lobes on a sphere, and the double dome's shear where the finite-element runs
put it (docs/forming.md compares them at full stroke)."""

import numpy as np
import pytest

from drape.forming.kinematic import drape_fishnet
from drape.forming.surfaces import ContactQuery

# no MPI in these tests: under mpirun each rank would do the same (tests/conftest.py)
pytestmark = pytest.mark.serial


class Cylinder:
    """The outside of a horizontal cylinder of radius R about the line y = 0, z = -R (its top
    line is the x axis): an exact mould for the tests."""

    def __init__(self, radius):
        self.R = radius

    def query(self, points, offset=None, cutoff=None):
        rel = np.asarray(points, dtype=float) - [0.0, 0.0, -self.R]
        rel[:, 0] = 0.0
        r = np.linalg.norm(rel, axis=1)
        normal = rel / r[:, None]
        closest = np.asarray(points, dtype=float) - (r - self.R)[:, None] * normal
        return ContactQuery(r - self.R, normal, closest)


class Sphere(Cylinder):
    def query(self, points, offset=None, cutoff=None):
        rel = np.asarray(points, dtype=float) - [0.0, 0.0, -self.R]
        r = np.linalg.norm(rel, axis=1)
        normal = rel / r[:, None]
        return ContactQuery(r - self.R, normal, np.asarray(points) - (r - self.R)[:, None] * normal)


class Plane(Cylinder):
    def query(self, points, offset=None, cutoff=None):
        p = np.asarray(points, dtype=float)
        normal = np.tile([0.0, 0.0, 1.0], (len(p), 1))
        return ContactQuery(p[:, 2], normal, p * [1.0, 1.0, 0.0])


def test_a_plane_takes_the_ply_as_it_is():
    drape = drape_fishnet(Plane(1.0), (0.0, 0.0, 3.0), 30.0, 2.5, 8)
    assert np.abs(drape.shear_deg).max() < 1e-9
    np.testing.assert_allclose(drape.nodes[..., :2], drape.flat, atol=1e-9)
    np.testing.assert_allclose(drape.nodes[..., 2], 0.0, atol=1e-12)


@pytest.mark.parametrize("angle", [0.0, 45.0, 30.0])
def test_a_cylinder_is_developable(angle):
    """Wrapped round a cylinder of radius 20 mm (crossings 1 mm apart, over about 60 degrees of
    its arc), the ply does not shear whatever its yarn angle: exactly with yarns along and
    around it; at other angles the fishnet's chords differ from the unrolled lengths by
    O((d/R)^2), and so does the shear (halving d divides it by 4)."""
    R = 20.0
    coarse = drape_fishnet(Cylinder(R), (0.0, 0.0, 1.0), angle, 1.0, 10)
    fine = drape_fishnet(Cylinder(R), (0.0, 0.0, 1.0), angle, 0.5, 20)
    if angle == 0.0:
        assert np.abs(coarse.shear_deg).max() < 1e-9
        nodes = coarse.nodes.reshape(-1, 3)
        flat = coarse.flat.reshape(-1, 2)
        turn = 2.0 * np.arcsin(0.5 / R)          # a chord of 1 mm round the cylinder
        np.testing.assert_allclose(np.arctan2(nodes[:, 1], nodes[:, 2] + R), flat[:, 1] * turn,
                                   atol=1e-9)
        np.testing.assert_allclose(nodes[:, 0], flat[:, 0], atol=1e-9)
    else:
        error, finer = np.abs(coarse.shear_deg).max(), np.abs(fine.shear_deg).max()
        assert error < 0.02 and finer == pytest.approx(error / 4, rel=0.1), (error, finer)


def test_a_sphere_shears_on_the_diagonals_with_the_squares_symmetry():
    R, d, n = 50.0, 2.0, 25
    drape = drape_fishnet(Sphere(R), (0.0, 0.0, 1.0), 0.0, d, n)
    s = drape.shear_deg
    assert not np.isnan(s).any()
    np.testing.assert_allclose(np.abs(s), np.abs(s[::-1, :]), atol=1e-6)   # mirror in x
    np.testing.assert_allclose(np.abs(s), np.abs(s[:, ::-1]), atol=1e-6)   # mirror in y
    np.testing.assert_allclose(s, s.T, atol=1e-6)                          # the diagonal
    # no shear next to the generators; the largest on the diagonals, growing outwards
    diagonal = np.abs(np.diagonal(s)[n:])
    assert np.abs(s[n, :]).max() < 0.1 * diagonal.max()
    assert np.abs(s[:, n]).max() < 0.1 * diagonal.max()
    i, j = np.unravel_index(np.argmax(np.abs(s)), s.shape)
    assert abs(abs(i - n + 0.5) - abs(j - n + 0.5)) < 1.5, (i, j)
    assert np.all(np.diff(diagonal) > 0) and diagonal[-1] > 20.0


def test_compare_peaks_finds_agreement_and_disagreement():
    """A map that is the kinematic one (plus noise) peaks where the drape shears most (rank
    correlation near 1); one peaking on the generators instead does not."""
    from drape.forming.kinematic import compare_peaks
    drape = drape_fishnet(Sphere(50.0), (0.0, 0.0, 1.0), 0.0, 2.0, 20)
    rng = np.random.default_rng(3)
    points = rng.uniform(-38.0, 38.0, (3000, 2))
    same = drape.shear_at(points) * (1.0 + 0.02 * rng.normal(size=len(points)))
    report = compare_peaks(points, same, drape)
    assert report["kinematic_percentile_at_fe_peak"] > 98.0
    assert report["rank_correlation"] > 0.95
    on_axes = 30.0 - np.minimum(np.abs(points[:, 0]), np.abs(points[:, 1]))
    report = compare_peaks(points, on_axes, drape)
    assert report["kinematic_percentile_at_fe_peak"] < 50.0
    assert report["rank_correlation"] < 0.0
