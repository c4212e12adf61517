"""The exact double-dome tools (drape.forming.double_dome,
geometry.tools.analytic_double_dome_tools).

Against independent expectations: the closed form of the construction (double_dome_height,
also for the core eroded by the edge radius), points built at a known distance from the
rolling-ball fillets' spines, a brute-force closest point on the core, the gmsh/OpenCASCADE
tools (nodes on the surfaces, gaps within the mesh's chord error), finite differences of the
gap (the normal is its gradient), continuity across every switch of the method, and the
clearance between punch and die at full stroke.
"""

import dataclasses

import numpy as np
import pytest

from drape.geometry.tools import (DoubleDomeTools, ToolMeshing, analytic_double_dome_tools,
                                  build_tools, double_dome_height)
from drape.forming.surfaces import MeshedSurface, TriangleSurface
from tool_helpers import chord_bound

# no MPI in these tests: under mpirun each rank would do the same (tests/conftest.py)
pytestmark = pytest.mark.serial

CFG = DoubleDomeTools(gap=0.5)     # a nonzero gap: every height depends on it
COARSE = ToolMeshing(chord_tolerance=0.2, max_size=20.0, elements_per_radius=2.0)
#: largest distance measured between OpenCASCADE's fillet surfaces (approximations) and the
#: exact rolling-ball fillets: 4.1e-3 mm near x = +-a, 3e-4 where the blend meets the spheres,
#: about 1e-5 elsewhere
OCC_FILLET = 5e-3
A = CFG.dome_offset
RK, RE, C, G = CFG.punch_edge_radius, CFG.die_entry_radius, CFG.clearance, CFG.gap
W_CORE = 0.5 * CFG.punch_width - RK
STROKE = CFG.full_stroke
#: the punch eroded by its edge radius: the same construction with R - rk and Rs + rk
ERODED = dataclasses.replace(CFG, dome_radius=CFG.dome_radius - RK,
                             saddle_radius=CFG.saddle_radius + RK, gap=G + RK)
X_BLEND = A * CFG.saddle_radius / (CFG.dome_radius + CFG.saddle_radius)        # on the punch
X_BLEND_CORE = A * ERODED.saddle_radius / (ERODED.dome_radius + ERODED.saddle_radius)


@pytest.fixture(scope="module")
def exact():
    return analytic_double_dome_tools(CFG)


@pytest.fixture(scope="module")
def meshed():
    return build_tools(CFG, COARSE)


def unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def face_normal(height, x, y, h=1e-5):
    """Unit normal (pointing down) of the height field z = height(x, y)."""
    hx = (height(x + h, y) - height(x - h, y)) / (2 * h)
    hy = (height(x, y + h) - height(x, y - h)) / (2 * h)
    return unit(np.stack([hx, hy, -np.ones_like(hx)], axis=-1))


def core_height(x, y):
    return double_dome_height(ERODED, x, y)


def core_edge(x=None, phi=None, side=1.0, end=1.0):
    """Points of the punch core's edge (lower face meets the wall at half-width w' = W/2 - rk)
    from the closed form, with the wall's and the lower face's outward normals and the
    edge's tangent: on a straight side (x, side) or on an end half-circle (phi, end)."""
    if x is not None:
        x = np.asarray(x, dtype=float)
        X, Y = x, np.full_like(x, side * W_CORE)
        wall = np.stack([0 * x, np.full_like(x, side), 0 * x], axis=1)
    else:
        phi = np.asarray(phi, dtype=float)
        X, Y = end * (A + W_CORE * np.cos(phi)), W_CORE * np.sin(phi)
        wall = np.stack([end * np.cos(phi), np.sin(phi), 0 * phi], axis=1)
    e = np.stack([X, Y, core_height(X, Y)], axis=1)
    face = face_normal(core_height, X, Y)
    return e, wall, face, unit(np.cross(wall, face))


def stadium_boundary(half_width, s):
    """Points x, y of a stadium's boundary (half-length a) at arc-length s (any real: it
    wraps around), from (a, half_width) towards -x, and the outward normal (nx, ny)."""
    straight, arc = 2 * A, np.pi * half_width
    s = np.mod(s, 2 * (straight + arc))
    side = np.where(s < straight + arc, 1.0, -1.0)
    s = np.where(side > 0, s, s - straight - arc)
    phi = 0.5 * np.pi + np.clip((s - straight) / half_width, 0.0, np.pi)
    on_straight = s < straight
    nx = np.where(on_straight, 0.0, side * np.cos(phi))
    ny = np.where(on_straight, side, side * np.sin(phi))
    x = np.where(on_straight, side * (A - s), -side * A + half_width * nx)
    y = np.where(on_straight, side * half_width, half_width * ny)
    return x, y, nx, ny


def stadium_rim(half_width, fraction, z):
    """Points (N, 3) of a stadium curve at height z, at fractions of its length from
    (a, half_width), and the outward horizontal normals (N, 3)."""
    perimeter = 2 * (2 * A + np.pi * half_width)
    x, y, nx, ny = stadium_boundary(half_width, np.asarray(fraction) * perimeter)
    return (np.stack([x, y, np.full_like(x, z)], axis=1),
            np.stack([nx, ny, np.zeros_like(nx)], axis=1))


def cone(n1, n2, lam):
    return unit((1 - lam)[:, None] * n1 + lam[:, None] * n2)


def edge_fillet_points(rng, n):
    """Per tool: points at a known gap t in [-3, 3] from each rolling-ball fillet, built
    from its spine (where the ball's centre runs) and the normals at its two ends:
    (points, gaps). Punch: spine = the core's edge, distance rk + t. Die, in the cavity: the
    same spine moved down by the full stroke, gap t at distance rk + c - t from it; at the
    entry: the rim circle at -gap - re. Holder: the opening's circle at gap + rh."""
    x = rng.uniform(-A, A, n)
    e1, w1, f1, _ = core_edge(x=x, side=rng.choice([-1.0, 1.0], n))
    e2, w2, f2, _ = core_edge(phi=rng.uniform(-0.5 * np.pi, 0.5 * np.pi, n),
                              end=rng.choice([-1.0, 1.0], n))
    e, wall, face = np.concatenate([e1, e2]), np.concatenate([w1, w2]), np.concatenate([f1, f2])
    lam, t = rng.uniform(0, 1, 2 * n), rng.uniform(-3, 3, 2 * n)
    normal = cone(wall, face, lam)
    punch = e + (RK + t)[:, None] * normal
    cavity = e - (0, 0, STROKE) + (RK + C - t)[:, None] * normal
    rim, m = stadium_rim(0.5 * CFG.punch_width + C + RE, rng.uniform(0, 1, n), -G - RE)
    lam2, t2 = rng.uniform(0, 1, n), rng.uniform(-3, 3, n)
    entry = rim + (RE + t2)[:, None] * cone(np.array([0.0, 0.0, 1.0]), -m, lam2)
    rh = CFG.holder_edge_radius
    hole, mh = stadium_rim(CFG.holder_opening_radius + rh, rng.uniform(0, 1, n), G + rh)
    lam3, t3 = rng.uniform(0, 1, n), rng.uniform(-3, 3, n)
    holder = hole + (rh + t3)[:, None] * cone(np.array([0.0, 0.0, -1.0]), -mh, lam3)
    return {"punch": (punch, t), "die": (np.concatenate([cavity, entry]),
                                         np.concatenate([t, t2])), "holder": (holder, t3)}


def near_surface(tool, seeds, rng, spread=3.0):
    """Points within +-spread of the tool along its normal, from the closest points of seeds."""
    on = tool.query(seeds)
    return on.closest + on.normal * rng.uniform(-spread, spread, (len(seeds), 1))


def fd_gradient(tool, points, h=1e-5, offset=None):
    grad = np.zeros_like(points)
    for i in range(3):
        step = np.zeros(3)
        step[i] = h
        grad[:, i] = (tool.query(points + step, offset).gap
                      - tool.query(points - step, offset).gap) / (2 * h)
    return grad


# --- closed forms -------------------------------------------------------------------------------

def test_rolling_ball_fillets_are_at_the_built_distance(exact):
    """Points at distance t along the normal cone of each fillet's spine (edge of the core,
    rim circles): the gap is t, the normal the built direction, the closest point on the
    ball's sphere around the spine point."""
    rng = np.random.default_rng(1)
    for name, (points, t) in edge_fillet_points(rng, 300).items():
        q = exact[name].query(points)
        np.testing.assert_allclose(q.gap, t, atol=1e-9, err_msg=name)
        np.testing.assert_allclose(points - q.closest, q.gap[:, None] * q.normal, atol=1e-9)


def test_lower_faces_follow_the_closed_form(exact):
    """Below the punch's domes and saddle, away from the edge fillet, the punch is the
    height field double_dome_height: points built at distance t along its normal have gap t
    and closest point the foot; the cavity's bottom likewise (which='cavity', normal up).
    Queried from any point, the closest point's z is the closed form at its (x, y)."""
    rng = np.random.default_rng(2)
    n = 2000
    for name, which, sign, edge in (("punch", "punch", 1.0, RK), ("die", "cavity", -1.0, RK + C)):
        rim = 0.5 * CFG.punch_width + (0.0 if name == "punch" else C)
        x = rng.uniform(-A - rim, A + rim, 3 * n)
        y = rng.uniform(-rim, rim, 3 * n)
        height = lambda u, v: double_dome_height(CFG, u, v, which)
        foot = np.stack([x, y, height(x, y)], axis=1)
        normal = sign * face_normal(height, x, y)
        # the face ends where the edge fillet starts: where the ball of the edge radius
        # touching it from inside has its centre on the core's wall
        centre = foot - sign * edge * normal
        inset = W_CORE - np.hypot(np.maximum(np.abs(centre[:, 0]) - A, 0.0), centre[:, 1])
        face = inset > 1e-6
        x, y, foot, normal = x[face], y[face], foot[face], normal[face]
        assert np.count_nonzero(np.abs(x) < X_BLEND) > 50          # the saddle is sampled
        assert np.count_nonzero(inset[face] < 0.5) > 20          # and the fillet's start
        t = rng.uniform(-3.0, 3.0, len(x))
        q = exact[name].query(foot + t[:, None] * normal)
        np.testing.assert_allclose(q.gap, t, atol=1e-8, err_msg=name)
        np.testing.assert_allclose(q.closest, foot, atol=1e-6, err_msg=name)
        assert np.min(np.sum(q.normal * normal, axis=1)) > 1 - 1e-9
        # from points straight below / above, whose closest points are on the face
        away = inset[face] > 3.0
        p = (foot - sign * rng.uniform(0.0, 5.0, (len(x), 1)) * np.array([0.0, 0.0, 1.0]))[away]
        q = exact[name].query(p)
        np.testing.assert_allclose(q.closest[:, 2], height(q.closest[:, 0], q.closest[:, 1]),
                                   atol=1e-9)
        np.testing.assert_allclose(q.gap, np.sum((p - q.closest) * q.normal, axis=1),
                                   atol=1e-12)
    # the tips: gap at the blank plane, normals straight down / up
    tips = exact["punch"].query(np.array([[A, 0.0, 0.0], [-A, 0.0, -1.0]]))
    np.testing.assert_allclose(tips.gap, [G, G + 1.0], atol=1e-12)
    np.testing.assert_allclose(tips.normal, [[0, 0, -1], [0, 0, -1]], atol=1e-12)
    bottom = exact["die"].query(np.array([[A, 0.0, 0.0]]))
    np.testing.assert_allclose(bottom.gap, G + CFG.depth, atol=1e-12)
    np.testing.assert_allclose(bottom.closest, [[A, 0.0, -G - CFG.depth]], atol=1e-12)


def test_planes_and_walls_up_to_the_fillets(exact):
    """The flat and vertical faces next to each fillet, right up to where it starts: points
    built at distance t from them have gap t (punch wall above the core's edge; cavity wall
    between the core's edge and the entry fillet; die top face outside the entry fillet;
    holder's lower face and opening wall)."""
    rng = np.random.default_rng(9)
    n = 400
    t = rng.uniform(-3.0, 3.0, (n, 1))
    up = np.array([0.0, 0.0, 1.0])
    rh, ho = CFG.holder_edge_radius, CFG.holder_opening_radius

    def wall(half_width, edge, shift, top):
        """Points of the stadium wall of a half-width, from the height of the core's edge
        (seen through the edge's radius; moved by shift) up to top, and the outward
        normals."""
        rim, m = stadium_rim(half_width, rng.uniform(0, 1, n), 0.0)
        core = rim - edge * m
        lowest = core_height(core[:, 0], core[:, 1]) + shift
        assert np.all(lowest < top)
        rim[:, 2] = lowest + rng.uniform(0.0, 1.0, n) * (top - lowest)
        return rim, m

    points, m = wall(0.5 * CFG.punch_width, RK, 0.0, G + CFG.punch_height - 5.0)
    cases = [("punch", points + t * m)]
    points, m = wall(0.5 * CFG.punch_width + C, RK + C, -STROKE, -G - RE)
    cases.append(("die", points - t * m))
    rim, m = stadium_rim(0.5 * CFG.punch_width + C + RE, rng.uniform(0, 1, n), -G)
    cases.append(("die", rim + rng.uniform(0.0, 3.0, (n, 1)) * m + t * up))
    rim, m = stadium_rim(ho + rh, rng.uniform(0, 1, n), G)
    cases.append(("holder", rim + rng.uniform(0.0, 3.0, (n, 1)) * m - t * up))
    rim, m = stadium_rim(ho, rng.uniform(0, 1, n), G + rh)
    cases.append(("holder", rim + rng.uniform(0.0, 5.0, (n, 1)) * up - t * m))
    for name, points in cases:
        np.testing.assert_allclose(exact[name].query(points).gap, t[:, 0], atol=1e-9,
                                   err_msg=name)


def _brute_core_distance(p):
    """Distance from p (outside the core) to the punch core, by refined grid search over its
    lower face (double_dome_height of the eroded construction, inside the footprint) and its
    wall (vertical lines over the footprint's boundary, above the lower face)."""
    best, where = np.inf, p[:2].copy()
    span = 15.0
    for _ in range(5):                                   # the lower face
        s = np.linspace(-span, span, 61)
        X, Y = np.meshgrid(where[0] + s, where[1] + s, indexing="ij")
        X, Y = X.ravel(), Y.ravel()
        inside = np.hypot(np.maximum(np.abs(X) - A, 0.0), Y) <= W_CORE
        if np.any(inside):
            pts = np.stack([X, Y, core_height(X, Y)], axis=1)[inside]
            d = np.linalg.norm(pts - p, axis=1)
            k = np.argmin(d)
            if d[k] < best:
                best, where = d[k], pts[k, :2]
        span /= 20.0
    perimeter = 2 * (2 * A + np.pi * W_CORE)
    centre, span = 0.0, 0.5 * perimeter
    for _ in range(6):                                   # the wall, its lower end the edge
        s = centre + np.linspace(-span, span, 4001)
        x, y, _, _ = stadium_boundary(W_CORE, s)
        z = np.maximum(p[2], core_height(x, y))
        d = np.sqrt((x - p[0]) ** 2 + (y - p[1]) ** 2 + (z - p[2]) ** 2)
        k = np.argmin(d)
        best = min(best, d[k])
        centre, span = s[k], span / 200.0
    return best


def test_punch_core_against_brute_force(exact):
    """Near the punch's edge fillet (dome, saddle and straight parts) the gap plus rk is the
    distance to the core found by brute force on its closed form."""
    rng = np.random.default_rng(3)
    x = np.concatenate([rng.uniform(-X_BLEND_CORE, X_BLEND_CORE, 8),
                        rng.uniform(X_BLEND_CORE, A, 6), rng.uniform(A, A + 60.0, 6)])
    y = np.concatenate([rng.uniform(W_CORE - 6.0, W_CORE + 8.0, 14),
                        rng.uniform(-W_CORE, W_CORE, 6)])
    z = core_height(np.minimum(x, A), np.minimum(y, W_CORE)) + rng.uniform(-12.0, 8.0, 20)
    points = np.stack([x * rng.choice([-1, 1], 20), y * rng.choice([-1, 1], 20), z], axis=1)
    gap = exact["punch"].query(points).gap
    for p, g in zip(points, gap):
        if g + RK > 0.5:                                 # outside the core
            assert g + RK == pytest.approx(_brute_core_distance(p), abs=1e-7), p


# --- the gradient and continuity --------------------------------------------------------------

def test_normal_is_the_gradient_of_the_gap(exact):
    """Central differences of the gap equal the normal, at points near every tool: all over
    the working faces and at every fillet (punch edge over domes, saddle and straight sides,
    die cavity edge and entry, holder opening)."""
    rng = np.random.default_rng(4)
    built = edge_fillet_points(rng, 200)
    seeds = {"punch": rng.uniform([-200, -100, -10], [200, 100, 60], (600, 3)),
             "die": rng.uniform([-220, -130, -70], [220, 130, 10], (600, 3)),
             "holder": rng.uniform([-220, -130, -5], [220, 130, 15], (600, 3))}
    for name, tool in exact.items():
        points = np.concatenate([built[name][0], near_surface(tool, seeds[name], rng)])
        q = tool.query(points)
        np.testing.assert_allclose(np.linalg.norm(q.normal, axis=1), 1.0, atol=1e-12)
        np.testing.assert_allclose(fd_gradient(tool, points), q.normal, atol=1e-6,
                                   err_msg=name)
    # with an offset (the punch at some stroke)
    points = built["punch"][0][:100] - (0, 0, 25.0)
    q = exact["punch"].query(points, offset=(0, 0, -25.0))
    np.testing.assert_allclose(fd_gradient(exact["punch"], points, offset=(0, 0, -25.0)),
                               q.normal, atol=1e-6)


def assert_continuous(tool, points, directions):
    """Along segments through the points: the gap changes as the normal says (no jump) and
    the normal changes by no more than the curvature allows (no kink: the points are at
    least 2 mm from the cores' edges, so the gap's Hessian is below 1/mm). Two scales: steps of
    1e-7 mm over +-1e-5 (to round-off), steps of 1e-4 over +-1e-2 (to the trapezoidal rule's
    error where the curvature jumps, about h^2 / r)."""
    for half_span, steps, tolerance in ((1e-5, 200, 1e-12), (1e-2, 200, 1e-8)):
        s = np.linspace(-half_span, half_span, steps + 1)
        for p, d in zip(points, unit(directions)):
            q = tool.query(p + s[:, None] * d)
            change = np.diff(q.gap)
            predicted = 0.5 * (q.normal[1:] + q.normal[:-1]) @ d * (s[1] - s[0])
            assert np.abs(change - predicted).max() < tolerance, (tool.name, p, d)
            turn = np.linalg.norm(np.diff(q.normal, axis=0), axis=1).max()
            assert turn < 1.0 * (s[1] - s[0]), (tool.name, p, d)  # curvature < 1/mm


def test_gap_is_continuous_across_region_boundaries(exact):
    """Where the method switches: sphere/blend (|x| = x_b on the faces), straight side/end
    (|x| = a), blend/sphere along the core's edge (|x| = x_b of the core), and both starts
    of every fillet (face/edge, wall/edge), for the punch, the die (cavity and entry) and
    the holder."""
    rng = np.random.default_rng(5)
    t = rng.uniform(-3.0, 3.0, 4)
    # 1. sphere/blend switch under the faces: on the line through a sphere's centre and the
    #    blend circle's centre (meridian plane about y = 0, z = zc), crossed along the face
    R, Rs = CFG.dome_radius, CFG.saddle_radius
    M = np.sqrt((R + Rs) ** 2 - A ** 2)
    line = np.array([-A, M]) / (R + Rs)
    across = np.array([M, A]) / (R + Rs)
    for name, radius, zc in (("punch", R, G + R), ("die", R + C, G + R - STROKE)):
        for phi in (-0.3, 0.0, 0.2):
            for sx in (-1.0, 1.0):
                u, rho = (np.array([A, 0.0]) + (radius + t[:, None]) * line).T
                e_rho = np.array([0.0, np.sin(phi), -np.cos(phi)])
                p = np.stack([sx * u, rho * e_rho[1], zc + rho * e_rho[2]], axis=1)
                d = np.outer(np.full(4, sx * across[0]), [1, 0, 0]) + across[1] * e_rho
                assert_continuous(exact[name], p, d)
    # 2. along the punch core's edge: x = +-x_b (blend/sphere) and x = +-a (side/end), at
    #    random directions in the normal cone; 3. the fillet's starts on the face and wall
    for x0 in (X_BLEND_CORE, -X_BLEND_CORE, A, -A):
        for side in (1.0, -1.0):
            e, wall, face, tangent = core_edge(x=np.full(4, x0), side=side)
            lam = np.array([0.0, 0.3, 0.8, 1.0])
            normal = cone(wall, face, lam)
            assert_continuous(exact["punch"], e + (RK + t)[:, None] * normal, tangent)
            cavity = e - (0, 0, STROKE) + (RK + C - t)[:, None] * normal
            assert_continuous(exact["die"], cavity, tangent)
    x = rng.uniform(-A - 50, A + 50, 6)
    e, wall, face, _ = core_edge(x=np.clip(x, -A, A), side=1.0)
    for n_on, n_off in ((face, wall), (wall, face)):     # the fillet starts
        off = unit(n_off - np.sum(n_off * n_on, axis=1, keepdims=True) * n_on)
        tt = rng.uniform(-3.0, 3.0, (len(x), 1))
        assert_continuous(exact["punch"], e + (RK + tt) * n_on, off)
        assert_continuous(exact["die"], e - (0, 0, STROKE) + (RK + C - tt) * n_on, off)
    # die entry and holder fillets: starts on the plane and on the wall, and x = +-a
    rh = CFG.holder_edge_radius
    for name, half_width, z0, r, up in (
            ("die", 0.5 * CFG.punch_width + C + RE, -G - RE, RE, 1.0),
            ("holder", CFG.holder_opening_radius + rh, G + rh, rh, -1.0)):
        s = np.concatenate([rng.uniform(0, 1, 6), [0.0, 0.5]])  # 0 and 0.5: at x = +a, -a
        rim, m = stadium_rim(half_width, s, z0)
        vertical = np.array([0.0, 0.0, up])
        tt = rng.uniform(-3.0, 3.0, (len(s), 1))
        assert_continuous(exact[name], rim + (r + tt) * vertical, m)       # plane start
        assert_continuous(exact[name], rim - (r + tt) * m, np.tile(vertical, (len(s), 1)))
        tangent = np.cross(m, vertical)
        mid = rim + (r + tt) * cone(np.tile(vertical, (len(s), 1)), -m, np.full(len(s), 0.5))
        assert_continuous(exact[name], mid, tangent)


# --- positions, offsets -------------------------------------------------------------------------

def test_points_on_the_surfaces_and_offsets(exact):
    """A point of a tool's surface has gap 0 and is its own closest point; translating the
    points and the tool together changes nothing but the closest point's translation."""
    rng = np.random.default_rng(6)
    seeds = rng.uniform([-230, -130, -70], [230, 130, 60], (3000, 3))
    offset = np.array([1.5, -2.0, -33.0])
    for name, tool in exact.items():
        on = tool.query(seeds).closest
        q = tool.query(on)
        np.testing.assert_allclose(q.gap, 0.0, atol=1e-10)
        np.testing.assert_allclose(q.closest, on, atol=1e-10)
        moved = tool.query(seeds + offset, offset=offset)
        ref = tool.query(seeds)
        np.testing.assert_allclose(moved.gap, ref.gap, atol=1e-10)
        np.testing.assert_allclose(moved.normal, ref.normal, atol=1e-10)
        np.testing.assert_allclose(moved.closest, ref.closest + offset, atol=1e-10)
    with pytest.raises(ValueError, match="shape"):
        exact["punch"].query(np.zeros((4, 2)))


def test_punch_at_full_stroke_is_the_clearance_from_the_die(exact):
    """The cavity is the punch's offset by the clearance: at full stroke every point of the
    punch's surface facing the cavity (below the entry fillet) is exactly c from the die,
    and no point of it is nearer."""
    rng = np.random.default_rng(7)
    seeds = rng.uniform([-200, -100, -5], [200, 100, 60], (4000, 3))
    surface = exact["punch"].query(seeds).closest
    surface = surface[surface[:, 2] < G + CFG.punch_height]
    down = np.array([0.0, 0.0, -STROKE])
    gap = exact["die"].query(surface + down).gap
    facing = surface[:, 2] - STROKE < -G - RE - 1e-6
    assert np.count_nonzero(facing) > 1000 and np.count_nonzero(~facing) > 10
    np.testing.assert_allclose(gap[facing], C, atol=1e-9)
    assert gap.min() >= C - 1e-9
    # the same through the offset argument (the punch moves, the points stay)
    points = surface + down
    q = exact["punch"].query(points, offset=down)
    np.testing.assert_allclose(q.gap, 0.0, atol=1e-10)
    # at half stroke the walls are already c from the cavity's, the tips c + stroke / 2 above
    # its bottom (on the spheres' common axes)
    half = exact["die"].query(surface + down / 2).gap
    assert half.min() >= C - 1e-9
    tips = exact["die"].query(np.array([[A, 0.0, G], [-A, 0.0, G]]) + down / 2).gap
    np.testing.assert_allclose(tips, C + STROKE / 2, atol=1e-12)


def test_impossible_dimensions_are_refused():
    """An entry fillet taller than the cavity's vertical wall: the die is no longer the
    opening of a vertical-walled cavity."""
    from drape.errors import InputError
    with pytest.raises(InputError, match="vertical wall"):
        analytic_double_dome_tools(DoubleDomeTools(die_entry_radius=20.0))


# --- against the gmsh tools ---------------------------------------------------------------------

def working(name, x, margin=10.0):
    """Points away from what the exact tools ignore: the punch's top face, the die block's
    outer faces and bottom, the holder's top and outer faces."""
    L, W = 0.5 * CFG.die_length - margin, 0.5 * CFG.die_width - margin
    if name == "punch":
        return x[:, 2] < G + CFG.punch_height - margin
    inside = (np.abs(x[:, 0]) < L) & (np.abs(x[:, 1]) < W)
    if name == "die":
        return inside & (x[:, 2] > -G - CFG.die_thickness + margin)
    return inside & (x[:, 2] < G + CFG.holder_thickness - margin)


def curvature(tool, h=1e-4):
    """Largest principal curvature where points project: the norm of the normal's
    derivative (the Hessian of the gap) at the closest point, by central differences."""
    def at(points):
        c = tool.query(points).closest
        J = np.zeros((len(points), 3, 3))
        for i in range(3):
            step = np.zeros(3)
            step[i] = h
            J[:, :, i] = (tool.query(c + step).normal - tool.query(c - step).normal) / (2 * h)
        return np.linalg.norm(J, ord=2, axis=(1, 2))
    return at


@pytest.mark.serial
def test_gmsh_nodes_lie_on_the_exact_surfaces(meshed, exact):
    """Every node of the meshed working faces is on the exact surface, with the exact
    normal: to round-off where OpenCASCADE's faces are exact (planes, cylinders, tori: the
    holder), within its fillet approximation elsewhere."""
    for name, surface in meshed.items():
        keep = working(name, surface.nodes)
        q = exact[name].query(surface.nodes[keep])
        tolerance = 1e-9 if name == "holder" else OCC_FILLET
        assert np.abs(q.gap).max() < tolerance, (name, np.abs(q.gap).max())
        assert np.abs(q.gap).max() > 1e-4 or name == "holder"    # the tolerance is needed
        agree = np.sum(q.normal * surface.normals[keep], axis=1)
        assert agree.min() > 1 - 1e-5, name


@pytest.mark.serial
def test_gaps_agree_with_the_meshed_tools(meshed, exact):
    """Points within 3 mm of each tool's working faces: the meshed gap is the exact one to
    within the mesh's chord bound (twice that in the shell between the two surfaces), plus
    OpenCASCADE's fillet approximation; the normals agree within the normal's turn over the
    triangle, kappa h."""
    rng = np.random.default_rng(8)
    for name, surface in meshed.items():
        tri_ok = np.all(working(name, surface.nodes)[surface.triangles], axis=1)
        faces = TriangleSurface(name, surface.nodes, surface.triangles[tri_ok], surface.normals)
        kappa = curvature(exact[name])
        bound = chord_bound(faces, kappa)
        assert 0.05 < bound < 0.5, (name, bound)
        seeds = surface.nodes[rng.integers(0, len(surface.nodes), 3000)]
        points = near_surface(exact[name], seeds + rng.normal(size=seeds.shape) * 2.0, rng)
        ref = exact[name].query(points)
        search = MeshedSurface(surface)
        got = search.query(points)
        tri, _, _ = search.closest_triangles(points)
        ok = working(name, points, 8.0) & working(name, ref.closest, 8.0) & tri_ok[tri]
        assert np.count_nonzero(ok) > 2000
        error = np.abs(got.gap - ref.gap)[ok]
        shell = np.abs(ref.gap[ok]) < bound
        assert np.all(error[~shell] <= bound + OCC_FILLET), (name, error.max(), bound)
        assert np.all(error[shell] <= 2 * bound + OCC_FILLET), name
        assert error.max() > 0.2 * bound                  # the bound is of the right size
        h = surface.edge_lengths()[tri[ok]].max(axis=1)
        k = np.maximum(kappa(surface.nodes[surface.triangles[tri[ok]]].mean(axis=1)),
                       kappa(ref.closest[ok]))
        turn = np.linalg.norm(got.normal - ref.normal, axis=1)[ok]
        assert np.all(turn <= k * h + 1e-6), (name, (turn / (k * h + 1e-6)).max())
