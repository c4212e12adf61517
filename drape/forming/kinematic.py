"""Kinematic draping (the fishnet algorithm): the shear a ply needs to cover a mould when its
yarns keep their length and only shear, with no forces at all (numpy only; units mm, degrees).

It is the classic independent estimate of where a woven ply shears (Mack and Taylor, J. Text.
Inst. 47 (1956) T477; Van der Weeën, Int. J. Numer. Meth. Eng. 31 (1991) 1415; Krogh et al.,
Struct. Multidisc. Optim. 64 (2021) 457, the KinDrape code), and drape uses it as a second,
force-free implementation against which the finite-element shear maps are compared
(docs/forming.md). The mould is any tool of :mod:`drape.forming.surfaces` (or
:mod:`drape.forming.double_dome`):
its ``query`` gives the signed distance (gap) and its gradient (normal), so the mould surface
is the level set gap = 0, vertical walls included.

The ply is a grid of yarn crossings (i, j), a distance ``d`` apart along warp and weft. The
crossing (0, 0) is put on the mould at ``origin``; the warp and weft through it (the
generators) follow the mould straight ahead (each next crossing at distance d, in the
direction of the last segment turned into the tangent plane); every other crossing is the
point of the mould at distance d from its two neighbours (i -/+ 1, j) and (i, j -/+ 1) already
placed, found by Newton's method on [gap(x) = 0, |x - a|^2 = d^2, |x - b|^2 = d^2], one
anti-diagonal of each quadrant at a time. The shear angle of a cell is 90 deg minus the angle
between its warp and weft edges at the corner nearest the origin.
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass
class KinematicDrape:
    """Crossings (2n+1, 2n+1, 3) on the mould, indexed [n + i, n + j]; ``shear_deg`` (2n, 2n)
    per cell; ``flat`` (2n+1, 2n+1, 2) the crossings on the flat ply (mm); NaN where the
    construction failed (no point of the mould at distance d from both neighbours)."""

    nodes: np.ndarray
    shear_deg: np.ndarray
    flat: np.ndarray
    spacing: float

    def cell_centres_flat(self) -> np.ndarray:
        """(2n, 2n, 2): the cells' centres on the flat ply."""
        f = self.flat
        return 0.25 * (f[:-1, :-1] + f[1:, :-1] + f[:-1, 1:] + f[1:, 1:])

    def shear_at(self, points_flat) -> np.ndarray:
        """|shear angle| (deg) of the cells holding the flat-ply points (M, 2); NaN outside."""
        n = self.shear_deg.shape[0] // 2
        p = np.asarray(points_flat, dtype=float)
        e1, e2 = self._axes()
        i = np.floor(p @ e1 / self.spacing).astype(int) + n
        j = np.floor(p @ e2 / self.spacing).astype(int) + n
        inside = (i >= 0) & (j >= 0) & (i < 2 * n) & (j < 2 * n)
        out = np.full(len(p), np.nan)
        out[inside] = np.abs(self.shear_deg[i[inside], j[inside]])
        return out

    def _axes(self):
        f, n = self.flat, self.flat.shape[0] // 2
        e1 = (f[n + 1, n] - f[n, n]) / self.spacing
        e2 = (f[n, n + 1] - f[n, n]) / self.spacing
        return e1, e2


def _project(tool, x, iterations=3):
    """The closest points of the mould (gap = 0) to x (M, 3)."""
    for _ in range(iterations):
        q = tool.query(x)
        x = q.closest
    return x


def _generator(tool, start, direction, d, count):
    """``count`` crossings after ``start`` along the mould, chords of length d, going straight
    ahead: a discrete geodesic, whose turn at each crossing (the second difference) lies along
    the mould's normal there."""
    points = [start]
    previous = start - d * direction
    for _ in range(count):
        here = points[-1]
        normal = tool.query(here[None]).normal[0]
        ahead = here - previous
        if len(points) == 1:             # the ply's yarn direction, in the tangent plane
            ahead -= (ahead @ normal) * normal
        ahead /= np.linalg.norm(ahead)
        lam = 0.0
        for _ in range(30):          # x(lam) = here + d unit(ahead + lam n), on the mould
            v = ahead + lam * normal
            length = np.linalg.norm(v)
            x = here + d * v / length
            q = tool.query(x[None])
            dx = d * (normal - (v @ normal) * v / length ** 2) / length
            slope = q.normal[0] @ dx
            step = q.gap[0] / slope
            lam -= step
            if abs(q.gap[0]) < 1e-12 * d:
                break
        points.append(x)
        previous = here
    return np.array(points[1:])


def _third_point(tool, a, b, guess, d, iterations=30):
    """Points x (M, 3) of the mould with |x - a| = |x - b| = d, by Newton's method from guess."""
    x = guess.copy()
    for _ in range(iterations):
        q = tool.query(x)
        r = np.stack([q.gap, 0.5 * (np.sum((x - a) ** 2, axis=1) - d * d),
                      0.5 * (np.sum((x - b) ** 2, axis=1) - d * d)], axis=1)
        J = np.stack([q.normal, x - a, x - b], axis=1)
        ok = np.abs(np.linalg.det(J)) > 1e-12 * d ** 2
        step = np.zeros_like(x)
        step[ok] = np.linalg.solve(J[ok], r[ok][:, :, None])[:, :, 0]
        x = x - step
        if np.abs(r).max() < 1e-10 * d * d:
            break
    q = tool.query(x)
    bad = (np.abs(q.gap) > 1e-6 * d) | (np.abs(np.linalg.norm(x - a, axis=1) - d) > 1e-6 * d) \
        | (np.abs(np.linalg.norm(x - b, axis=1) - d) > 1e-6 * d)
    x[bad] = np.nan
    return x


def drape_fishnet(tool, origin, yarn_angle_deg: float, spacing: float, count: int
                  ) -> KinematicDrape:
    """Drape a ply with yarns at ``yarn_angle_deg`` (warp from the x axis) over the mould
    ``tool``, crossing (0, 0) at the mould's point nearest ``origin``, ``count`` crossings of
    ``spacing`` mm each way from it."""
    theta = np.radians(yarn_angle_deg)
    e1 = np.array([np.cos(theta), np.sin(theta), 0.0])
    e2 = np.array([-np.sin(theta), np.cos(theta), 0.0])
    n, d = int(count), float(spacing)
    nodes = np.full((2 * n + 1, 2 * n + 1, 3), np.nan)
    o = _project(tool, np.asarray(origin, dtype=float)[None])[0]
    nodes[n, n] = o
    for axis, sign in ((0, 1), (0, -1), (1, 1), (1, -1)):
        direction = sign * (e1 if axis == 0 else e2)
        line = _generator(tool, o, direction, d, n)
        k = n + sign * np.arange(1, n + 1)
        if axis == 0:
            nodes[k, n] = line
        else:
            nodes[n, k] = line
    for si in (1, -1):
        for sj in (1, -1):
            for s in range(2, 2 * n + 1):       # anti-diagonal i + j = s of the quadrant
                i = np.arange(max(1, s - n), min(n, s - 1) + 1)
                j = s - i
                I, J = n + si * i, n + sj * j
                a, b = nodes[I - si, J], nodes[I, J - sj]
                c = nodes[I - si, J - sj]
                nodes[I, J] = _third_point(tool, a, b, a + b - c, d)
    # shear per cell at its corner nearest the origin
    ii, jj = np.meshgrid(np.arange(2 * n), np.arange(2 * n), indexing="ij")
    ci = np.where(ii >= n, ii, ii + 1)
    cj = np.where(jj >= n, jj, jj + 1)
    ai = np.where(ii >= n, ii + 1, ii)
    bj = np.where(jj >= n, jj + 1, jj)
    corner = nodes[ci, cj]
    warp = nodes[ai, cj] - corner
    weft = nodes[ci, bj] - corner
    warp *= np.where(ii >= n, 1.0, -1.0)[..., None]
    weft *= np.where(jj >= n, 1.0, -1.0)[..., None]
    cos = np.sum(warp * weft, axis=-1) / (np.linalg.norm(warp, axis=-1)
                                          * np.linalg.norm(weft, axis=-1))
    shear = np.degrees(np.arcsin(np.clip(cos, -1.0, 1.0)))
    grid = np.arange(-n, n + 1) * d
    flat = grid[:, None, None] * e1[:2] + grid[None, :, None] * e2[:2]
    return KinematicDrape(nodes, shear, flat, d)


def compare_peaks(points_flat, shear_deg, drape: KinematicDrape, top: float = 0.02) -> dict:
    """Where a finite-element shear map (|shear| at flat-blank points (M, 2)) has its peak,
    against a kinematic drape of the same ply: the kinematic shear's percentile (among the
    given points) at the FE's largest shear and, over the FE's top ``top`` fraction of points,
    its median percentile; the rank correlation of the two maps. A percentile near 100 means
    the FE peak lies where the kinematic drape shears most."""
    from scipy.stats import spearmanr
    gamma = np.abs(np.asarray(shear_deg, dtype=float))
    kin = drape.shear_at(points_flat)
    ok = np.isfinite(kin)
    gamma, kin, points = gamma[ok], kin[ok], np.asarray(points_flat)[ok]
    percentile = 100.0 * (np.argsort(np.argsort(kin)) + 0.5) / kin.size
    peak = int(np.argmax(gamma))
    best = gamma >= np.quantile(gamma, 1.0 - top)
    return {"fe_peak_xy_mm": points[peak].tolist(), "fe_peak_deg": float(gamma[peak]),
            "kinematic_percentile_at_fe_peak": float(percentile[peak]),
            "kinematic_percentile_over_fe_top": float(np.median(percentile[best])),
            "kinematic_peak_xy_mm": points[int(np.argmax(kin))].tolist(),
            "rank_correlation": float(spearmanr(gamma, kin).correlation)}
