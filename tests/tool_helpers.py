"""Independent references for the tool and contact tests: meshes built without gmsh, brute force
closest points over every triangle, and the chord-error bound of a triangulation."""

import numpy as np

from drape.forming.surfaces import TriangleSurface, closest_point_on_triangles


def icosphere(radius=10.0, centre=(0.0, 0.0, 0.0), refinements=3) -> TriangleSurface:
    """A triangulated sphere with nodes on the sphere and exact outward vertex normals."""
    t = (1.0 + 5 ** 0.5) / 2.0
    verts = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t),
             (0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
             (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
             (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    v = [np.array(p, dtype=float) / np.linalg.norm(p) for p in verts]
    f = list(faces)
    for _ in range(refinements):
        cache = {}

        def mid(i, j):
            key = (min(i, j), max(i, j))
            if key not in cache:
                m = v[i] + v[j]
                v.append(m / np.linalg.norm(m))
                cache[key] = len(v) - 1
            return cache[key]

        f = [g for a, b, c in f for g in
             ((a, mid(a, b), mid(c, a)), (b, mid(b, c), mid(a, b)), (c, mid(c, a), mid(b, c)),
              (mid(a, b), mid(b, c), mid(c, a)))]
    unit = np.array(v)
    return TriangleSurface("sphere", np.asarray(centre) + radius * unit, np.array(f), unit)


def wavy_sheet(n=24, size=40.0, amplitude=3.0, seed=0) -> TriangleSurface:
    """An open, curved sheet z = A sin(x/6) cos(y/9) over a square, with randomly jittered
    nodes (irregular triangles of mixed sizes) and normals of the exact height field."""
    rng = np.random.default_rng(seed)
    s = np.linspace(-size / 2, size / 2, n + 1)
    x, y = np.meshgrid(s, s, indexing="ij")
    h = size / n
    x = x + rng.uniform(-0.3, 0.3, x.shape) * h
    y = y + rng.uniform(-0.3, 0.3, y.shape) * h
    z = amplitude * np.sin(x / 6.0) * np.cos(y / 9.0)
    nodes = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    zx = amplitude / 6.0 * np.cos(x / 6.0) * np.cos(y / 9.0)
    zy = -amplitude / 9.0 * np.sin(x / 6.0) * np.sin(y / 9.0)
    normals = np.stack([-zx.ravel(), -zy.ravel(), np.ones(zx.size)], axis=1)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    tri = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return TriangleSurface("sheet", nodes, tri, normals)


def brute_force(surface: TriangleSurface, points, pairs=200_000):
    """Distance and closest point over every triangle (no spatial index): every point against
    every triangle, a block of points (about ``pairs`` point-triangle pairs) at a time."""
    tri = surface.triangles
    a, b, c = (surface.nodes[tri[:, k]] for k in range(3))
    points = np.asarray(points, dtype=float)
    best = np.full(len(points), np.inf)
    closest = np.zeros((len(points), 3))
    block = max(1, pairs // len(tri))
    for start in range(0, len(points), block):
        p = points[start:start + block]
        n = len(p)
        cp, _, d2 = closest_point_on_triangles(np.repeat(p, len(tri), axis=0), np.tile(a, (n, 1)),
                                               np.tile(b, (n, 1)), np.tile(c, (n, 1)))
        d2, cp = d2.reshape(n, len(tri)), cp.reshape(n, len(tri), 3)
        j = np.argmin(d2, axis=1)
        rows = np.arange(n)
        best[start:start + n], closest[start:start + n] = d2[rows, j], cp[rows, j]
    return np.sqrt(best), closest


def chord_bound(surface: TriangleSurface, curvature_at) -> float:
    """Largest distance between a triangle and the smooth surface through its vertices: per
    triangle the sagitta R - sqrt(R^2 - rho^2) of its smallest enclosing circle (radius rho:
    the circumradius, or half the longest edge for an obtuse triangle) on a sphere of radius
    R = 1/kappa, kappa the largest principal curvature where the triangle's centroid projects
    (``curvature_at(points) -> (N,)``). Exact for a sphere; for other surfaces the osculating
    sphere of the largest curvature bounds the deviation to leading order."""
    tri = surface.triangles
    a, b, c = (surface.nodes[tri[:, k]] for k in range(3))
    la, lb, lc = (np.linalg.norm(b - c, axis=1), np.linalg.norm(c - a, axis=1),
                  np.linalg.norm(a - b, axis=1))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    rho = la * lb * lc / (4.0 * np.maximum(area, 1e-300))
    sides = np.sort(np.stack([la, lb, lc], axis=1), axis=1)
    obtuse = sides[:, 2] ** 2 > sides[:, 0] ** 2 + sides[:, 1] ** 2
    rho = np.where(obtuse, 0.5 * sides[:, 2], rho)
    kappa = curvature_at((a + b + c) / 3.0)
    radius = 1.0 / np.maximum(kappa, 1e-12)
    sagitta = radius - np.sqrt(np.maximum(radius ** 2 - rho ** 2, 0.0))
    return float(np.max(np.where(rho < radius, sagitta, np.inf)))
