"""The nested-surface elasto-plastic shear law, vectorised over material points (numpy only).

The reading implemented is ``docs/material-law.md``. Per material point, with the yarn-frame
components C11, C22, C12 of the right Cauchy-Green tensor:

* yarn tension is elastic: S11 = mu K1 E11, S22 = mu K2 E22 (E = (C - I)/2);
* the projected shear stress tau = 2 mu Ksh (C12 - sin gp) lives on nested intervals
  |tau - c_k| <= R_k(gp), k = 0 (outer, c_0 = q(gp)) .. n (innermost), R_k = Sy_k + a_k alpha(gp);
* an increment is elastic if the trial tau stays in the innermost surface; otherwise one scalar
  equation in the plastic shear angle gp is solved (bracketed Newton) for the active surface,
  which hands over to its parent where the stress point reaches the parent's leading edge.

:meth:`NestedSurfaceLaw.update` never changes the committed state it is given: it returns the
response (stress, consistent tangent) and the trial state; the caller commits it (or not, e.g.
inside a Newton iteration or a line search of the finite-element solver).

Arrays are one-dimensional over points; surfaces are a short Python list (n <= a few), so the
only Python loops are over surfaces, Newton iterations and the n hand-overs, never over points.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from drape.law.parameters import MaterialParameters

#: Bound on |gp| (rad) for the root search: cos(gp) > 0 keeps tau(gp) monotone.
GAMMA_P_LIMIT = 0.5 * np.pi * (1.0 - 1e-9)
ELASTIC = -1
_MAX_ITERATIONS = 200
_MAX_RESTARTS = 20
_EPS = np.finfo(float).eps


@dataclasses.dataclass
class LawState:
    """History variables of N material points.

    gamma_p: plastic shear angle (rad), shape (N,).
    centres: centres c_1..c_n of the inner surfaces (N/mm), shape (n, N).
    gamma_max_deg: largest |shear angle| reached so far (deg), shape (N,).
    """

    gamma_p: np.ndarray
    centres: np.ndarray
    gamma_max_deg: np.ndarray

    @classmethod
    def virgin(cls, n_points: int, n_inner: int) -> "LawState":
        return cls(np.zeros(n_points), np.zeros((n_inner, n_points)), np.zeros(n_points))

    def copy(self) -> "LawState":
        return LawState(self.gamma_p.copy(), self.centres.copy(), self.gamma_max_deg.copy())

    def assign(self, other: "LawState") -> None:
        """Overwrite in place (keeps array identities, e.g. views into FE functions)."""
        self.gamma_p[...] = other.gamma_p
        self.centres[...] = other.centres
        self.gamma_max_deg[...] = other.gamma_max_deg

    def __len__(self) -> int:
        return self.gamma_p.shape[0]


@dataclasses.dataclass
class LawResponse:
    """Result of one increment for N points (nothing committed).

    tau: projected shear stress S:(G1 G2 + G2 G1) (N/mm); the yarn-frame S12 is tau / 2.
    dtau_dC12: consistent tangent d tau / d C12 (N/mm).
    S11, S22: yarn-frame normal PK2 components mu K1 E11, mu K2 E22 (N/mm).
    gamma_t_deg: total shear angle asin(C12 / sqrt(C11 C22)) (deg).
    active_surface: -1 where the increment was elastic, else the surface active at its end.
    trial: the state the increment ends in.
    """

    tau: np.ndarray
    dtau_dC12: np.ndarray
    S11: np.ndarray
    S22: np.ndarray
    gamma_t_deg: np.ndarray
    active_surface: np.ndarray
    trial: LawState


def shear_angle_deg(C11, C22, C12) -> np.ndarray:
    """Angle lost between the deformed yarns, asin(C12 / sqrt(C11 C22)), in degrees."""
    ratio = np.asarray(C12, dtype=float) / np.sqrt(np.maximum(np.multiply(C11, C22), 1e-300))
    return np.degrees(np.arcsin(np.clip(ratio, -1.0, 1.0)))


def _power_series(coefficients, x, derivative=False):
    """p(x) = sum_{i>=1} c_i x^i (coefficients c_1..c_m) and, if asked, p'(x); Horner's rule."""
    value = np.full_like(x, coefficients[-1])
    slope = np.zeros_like(x) if derivative else None
    for c in coefficients[-2::-1]:
        if derivative:
            slope *= x
            slope += value
        value *= x
        value += c
    # value is now P(x) = sum c_i x^(i-1), slope P'(x); p = x P and p' = P + x P'.
    if derivative:
        slope *= x
        slope += value
    value *= x
    return value, slope


class _Chain:
    """Centres and radii of surfaces 0..top at plastic angles x, for a group of points.

    Surfaces 1..top are passive: each is where its parent carries it (Mroz's clamp, applied
    outside in). Lists are indexed by surface; entries are arrays over the group's points.
    """

    def __init__(self, law, polynomials, a, fixed, top):
        q, dq, alpha, dalpha = polynomials
        derivatives = dq is not None
        self.alpha, self.dalpha = alpha, dalpha
        self.c, self.r = [q], [law.sy[0] + alpha]
        self.dc, self.dr = [dq], [dalpha]
        for j in range(1, top + 1):
            self.append_radius(law, j, a[j - 1])
            lower, upper = self.bounds(j)
            cj = np.minimum(np.maximum(fixed[j - 1], lower), upper)
            self.c.append(cj)
            if derivatives:
                dgap = self.dr[j - 1] - self.dr[j]
                self.dc.append(np.where(fixed[j - 1] < lower, self.dc[j - 1] - dgap,
                                        np.where(fixed[j - 1] > upper, self.dc[j - 1] + dgap, 0.0)))

    def append_radius(self, law, j, a_j):
        self.r.append(law.sy[j] + a_j * self.alpha)
        if self.dalpha is not None:
            self.dr.append(a_j * self.dalpha)

    def bounds(self, j):
        gap = self.r[j - 1] - self.r[j]
        return self.c[j - 1] - gap, self.c[j - 1] + gap

    def trailing(self, j, sigma):
        """Where the parent of surface j, moving along sigma, carries j from behind."""
        gap = self.r[j - 1] - self.r[j]
        value = self.c[j - 1] - sigma * gap
        slope = None if self.dalpha is None else self.dc[j - 1] - sigma * (self.dr[j - 1] - self.dr[j])
        return value, slope


class NestedSurfaceLaw:
    """The law for one parameter set; :meth:`update` integrates one increment for N points."""

    def __init__(self, params: MaterialParameters):
        self.params = params
        self.n = params.n
        self.two_mu_ksh = 2.0 * params.mu * params.Ksh
        self.sy = np.asarray(params.Sy, dtype=float)
        self.q_coefficients = np.asarray(params.Q, dtype=float)
        self.alpha_coefficients = np.asarray(params.A, dtype=float)
        self.row_bounds_deg = np.asarray(params.surfaces.gamma_max_deg, dtype=float)
        self.a_columns = params.a_rows().T[1:].copy()   # (n, rows): a_1..a_n by Table-2 row
        self.h_columns = params.h_rows().T[1:].copy()
        self._committed_cache = None

    def polynomials(self, x, derivatives=True):
        """q(x), q'(x), alpha(x), alpha'(x) (the slopes None unless asked)."""
        q, dq = _power_series(self.q_coefficients, x, derivatives)
        alpha, dalpha = _power_series(self.alpha_coefficients, x, derivatives)
        return q, dq, alpha, dalpha

    def _at_committed(self, gp0):
        """q, alpha and sin at the committed plastic angles, remembered between calls: a
        finite-element solver evaluates many iterates of a load step from one committed state."""
        cached = self._committed_cache
        if cached is not None and cached[0].shape == gp0.shape and np.array_equal(cached[0], gp0):
            return cached[1], cached[2]
        polynomials, sin_gp0 = self.polynomials(gp0, derivatives=False), np.sin(gp0)
        self._committed_cache = (gp0.copy(), polynomials, sin_gp0)
        return polynomials, sin_gp0

    def _table(self, gamma_max_deg):
        """a_k and h_k (k = 1..n) of each point's Table-2 row, as lists of arrays."""
        if self.n == 0:
            return [], []
        bounds = self.row_bounds_deg
        if bounds.size > 100:
            row = np.searchsorted(bounds, gamma_max_deg, side="right") - 1
        else:   # counting the bounds passed is several times faster than a binary search
            row = np.zeros(gamma_max_deg.shape, dtype=np.int8)
            for bound in bounds[1:]:
                row += (gamma_max_deg >= bound).view(np.int8)
        return ([np.take(col, row) for col in self.a_columns],
                [np.take(col, row) for col in self.h_columns])

    # -- one increment -------------------------------------------------------------------------
    def update(self, state: LawState, C11, C22, C12) -> LawResponse:
        """Integrate one increment from the committed ``state`` to the current C (yarn frame).

        C11, C22, C12: arrays of shape (N,). ``state`` is not modified.
        """
        C11 = np.asarray(C11, dtype=float)
        C22 = np.asarray(C22, dtype=float)
        C12 = np.asarray(C12, dtype=float)
        n, k2 = self.n, self.two_mu_ksh
        gamma_t_deg = shear_angle_deg(C11, C22, C12)
        gamma_max = np.maximum(state.gamma_max_deg, np.abs(gamma_t_deg))
        a, h = self._table(gamma_max)
        gp0 = state.gamma_p

        # 1. carry the committed centres at gp0 (the radii may have changed with the row)
        polynomials, sin_gp0 = self._at_committed(gp0)
        chain = _Chain(self, polynomials, a, state.centres, n)
        # 2. elastic trial against the innermost surface, with a round-off allowance so that
        #    re-evaluating a converged state on a surface stays elastic
        tau = k2 * (C12 - sin_gp0)
        offset = tau - chain.c[n]
        slack = 8.0 * _EPS * (k2 * (np.abs(C12) + np.abs(sin_gp0)) + np.abs(chain.c[n]) + chain.r[n])
        plastic = np.abs(offset) > chain.r[n] + slack

        centres = np.array(chain.c[1:]) if n else np.empty((0, gp0.size))
        gamma_p = gp0.copy()
        tangent = np.full(gp0.shape, k2)
        active_surface = np.full(gp0.shape, ELASTIC)

        idx = np.nonzero(plastic)[0]
        if idx.size:
            group = _PlasticGroup(self, C12[idx], gp0[idx], np.sign(offset[idx]),
                                  [col[idx] for col in a], [col[idx] for col in h],
                                  [c[idx] for c in chain.c[1:]], chain.c[n][idx])
            gamma_p[idx] = group.x
            centres[:, idx] = group.centres
            tangent[idx] = group.tangent
            active_surface[idx] = group.active
            tau[idx] = k2 * (C12[idx] - np.sin(group.x))

        mu = self.params.mu
        return LawResponse(tau=tau, dtau_dC12=tangent,
                           S11=mu * self.params.K1 * 0.5 * (C11 - 1.0),
                           S22=mu * self.params.K2 * 0.5 * (C22 - 1.0),
                           gamma_t_deg=gamma_t_deg, active_surface=active_surface,
                           trial=LawState(gamma_p, centres, gamma_max))


class _PlasticGroup:
    """Return mapping (steps 3-6 of the reading) of the points that left the innermost surface.

    Surfaces are processed from the innermost outwards: the points whose active surface is k
    are solved together; those whose stress point reaches surface k-1's leading edge hand over
    to it and are solved again with k-1. A point whose active surface k would, a moment later,
    be left behind by a slower inner surface (the hand-over reversed: "detachment") restarts the
    rest of its increment from there, as a sequence of small increments would. Results: x (gp),
    active, centres (n, m), tangent.
    """

    def __init__(self, law, C12, gp0, sigma, a, h, fixed, innermost_centre):
        self.law, self.C12, self.sigma, self.a, self.h = law, C12, sigma, a, h
        n, m = law.n, gp0.shape[0]
        self.fixed = np.array(fixed).reshape(n, m)
        self.x = gp0.copy()
        self.x_start = gp0.copy()
        self.own_start = innermost_centre.copy()
        self.active = np.full(m, n)
        self.centres = np.empty((n, m))
        self.tangent = np.empty(m)
        self.done = np.zeros(m, dtype=bool)
        self._cache = []
        for _ in range(_MAX_RESTARTS):
            for k in range(n, -1, -1):
                points = np.nonzero((self.active == k) & ~self.done)[0]
                if points.size:
                    self._solve_surface(k, points)
            if self.done.all():
                break
        else:  # pragma: no cover - a safeguard against endless restarts, never seen
            for k in range(n + 1):
                points = np.nonzero((self.active == k) & ~self.done)[0]
                self._finish(k, points, self.x_start[points])

    # -- surfaces of a group of points ---------------------------------------------------------
    def _polynomials(self, points, x, derivatives):
        """The law's polynomials at x for these points, remembered: the same angles are visited
        several times (start of an increment, its solution) by different checks."""
        for cached_points, cached_x, values in self._cache:
            if (cached_x.shape == x.shape and (values[1] is not None or not derivatives)
                    and np.array_equal(cached_x, x) and np.array_equal(cached_points, points)):
                return values
        values = self.law.polynomials(x, derivatives)
        self._cache = [(points, x, values)] + self._cache[:3]
        return values

    def _chain(self, k, points, x, derivatives=True, fixed=None):
        """Surfaces 0..k-1 where they are carried, and surface k's radius, at gp = x."""
        a = [col[points] for col in self.a]
        fixed = self.fixed[:, points] if fixed is None else fixed
        chain = _Chain(self.law, self._polynomials(points, x, derivatives), a, fixed, k - 1)
        if k >= 1:
            chain.append_radius(self.law, k, a[k - 1])
        return chain

    def _centre(self, k, points, chain, x, own_start=None, x_start=None):
        """Centre of surface k >= 1 moving on its own (linear in gp from where it started)
        unless its parent carries it from behind, and its slope d c_k / d gp."""
        own_start = self.own_start[points] if own_start is None else own_start
        x_start = self.x_start[points] if x_start is None else x_start
        sigma, hk = self.sigma[points], self.h[k - 1][points]
        own = own_start + hk * (x - x_start)
        trailing, trailing_slope = chain.trailing(k, sigma)
        use_own = sigma * (own - trailing) >= 0.0
        slope = None if trailing_slope is None else np.where(use_own, hk, trailing_slope)
        return np.where(use_own, own, trailing), slope

    def _edge_gap(self, k, points, chain, x, **start):
        """sigma-distance from surface k's leading edge to its parent's, and its rate of change
        as gp moves along sigma (negative: the edges approach)."""
        sigma = self.sigma[points]
        centre, dcentre = self._centre(k, points, chain, x, **start)
        gap = sigma * (chain.c[k - 1] - centre) + chain.r[k - 1] - chain.r[k]
        # edges that coincide to the accuracy of tau (e.g. after an increment on the parent,
        # tau ~ 2 mu Ksh (C12 - sin gp) carries about 2 mu Ksh * eps of round-off) touch
        scale = self.law.two_mu_ksh + np.abs(chain.c[k - 1]) + np.abs(centre) + chain.r[k - 1]
        gap = np.where(np.abs(gap) <= 16.0 * _EPS * scale, 0.0, gap)
        if dcentre is None:
            return gap, None
        slope = sigma * (chain.dc[k - 1] - dcentre) + chain.dr[k - 1] - chain.dr[k]
        return gap, sigma * slope

    def _state_at(self, k, points, x):
        """Step 5 at gp = x with surface k active: centres (n, m), with the inner surfaces tangent
        at the stress point (on surface k's leading edge), and D = d(c_k + sigma R_k)/d gp."""
        n, sigma = self.law.n, self.sigma[points]
        chain = self._chain(k, points, x)
        centres = np.empty((n, points.size))
        for j in range(1, k):
            centres[j - 1] = chain.c[j]
        if k == 0:
            centre, slope = chain.c[0], chain.dc[0] + sigma * chain.dr[0]
        else:
            centre, dcentre = self._centre(k, points, chain, x)
            centres[k - 1] = centre
            slope = dcentre + sigma * chain.dr[k]
        stress_point = centre + sigma * chain.r[k]
        for j in range(k + 1, n + 1):
            centres[j - 1] = stress_point - sigma * (self.law.sy[j] + self.a[j - 1][points] * chain.alpha)
        return centres, slope

    # -- the increment -------------------------------------------------------------------------
    def _solve_surface(self, k, points):
        law, k2 = self.law, self.law.two_mu_ksh
        x_start = self.x_start[points]

        if k >= 1:
            # the stress point may already sit on the parent's leading edge, with surface k
            # moving faster than it: then the parent takes over at once
            gap, rate = self._edge_gap(k, points, self._chain(k, points, x_start), x_start)
            hand_over = (gap <= 0.0) & (rate < 0.0)
            if np.any(hand_over):
                self._hand_over(k, points[hand_over], x_start[hand_over])
                points, x_start = points[~hand_over], x_start[~hand_over]
                if points.size == 0:
                    return

        # 3. the root of tau(gp) = c_k(gp) + sigma R_k(gp), first on surface k's own branch
        #    (k >= 1: linear centre; k = 0: centre q), which needs no parent chain
        def own_branch(i, x):
            p = points[i]
            C12, sigma = self.C12[p], self.sigma[p]
            alpha, dalpha = _power_series(law.alpha_coefficients, x, True)
            if k == 0:
                centre, dcentre = _power_series(law.q_coefficients, x, True)
                a_k = 1.0
            else:
                dcentre = self.h[k - 1][p]
                centre = self.own_start[p] + dcentre * (x - self.x_start[p])
                a_k = self.a[k - 1][p]
            phi = sigma * (k2 * (C12 - np.sin(x)) - centre) - law.sy[k] - a_k * alpha
            slope = -sigma * (k2 * np.cos(x) + dcentre) - a_k * dalpha
            return phi, slope

        x = _bracketed_newton(own_branch, x_start.copy(), self.sigma[points] * GAMMA_P_LIMIT)

        if k >= 1:
            # where the parent carries surface k from behind, the root lies before x on that branch
            chain = self._chain(k, points, x, derivatives=False)
            own = self.own_start[points] + self.h[k - 1][points] * (x - x_start)
            trailing, _ = chain.trailing(k, self.sigma[points])
            carried = np.nonzero(self.sigma[points] * (own - trailing) < 0.0)[0]
            if carried.size:
                sub = points[carried]

                def full_branch(i, y):
                    p = sub[i]
                    ch = self._chain(k, p, y)
                    centre, dcentre = self._centre(k, p, ch, y)
                    sg = self.sigma[p]
                    phi = sg * (k2 * (self.C12[p] - np.sin(y)) - centre) - ch.r[k]
                    return phi, -sg * (k2 * np.cos(y) + dcentre) - ch.dr[k]

                x[carried] = _bracketed_newton(full_branch, x_start[carried].copy(), x[carried].copy())

            # 4. did the stress point reach the parent's leading edge inside the increment?
            passed = self._reaches_parent(k, points, x_start, x)
            points, x_start, x = points[~passed], x_start[~passed], x[~passed]

        if k < law.n and points.size:
            # would an inner surface, slower than surface k, take over inside the increment?
            detached = self._attachment(k, points, x) <= 0.0
            if np.any(detached):
                self._restart(k, points[detached], x_start[detached], x[detached])
                points, x = points[~detached], x[~detached]
        self._finish(k, points, x)

    def _reaches_parent(self, k, points, x_start, x):
        """Hand over to surface k-1 where surface k's leading edge reaches the parent's between
        x_start and x. The gap between the edges may close and reopen inside the increment (the
        parent accelerates): then its minimum is checked too. Returns the mask of points handed."""
        gap_end, rate_end = self._edge_gap(k, points, self._chain(k, points, x), x)
        gap_start, rate_start = self._edge_gap(k, points, self._chain(k, points, x_start), x_start)
        passed = gap_end < 0.0
        search_end = x.copy()
        dip = np.nonzero(~passed & (rate_start < 0.0) & (rate_end > 0.0))[0]
        if dip.size:
            sub = points[dip]
            # where the gap stops closing: its rate along sigma reaches 0
            x_min = _first_nonpositive(
                lambda i, y: -self._edge_gap(k, sub[i], self._chain(k, sub[i], y), y)[1],
                x_start[dip], x[dip])
            gap_min, _ = self._edge_gap(k, sub, self._chain(k, sub, x_min, derivatives=False), x_min)
            dipped = gap_min < 0.0
            passed[dip[dipped]] = True
            search_end[dip[dipped]] = x_min[dipped]
        if np.any(passed):
            sub = points[passed]
            meet = x_start[passed].copy()
            later = np.nonzero(gap_start[passed] > 0.0)[0]
            if later.size:
                def edge(i, y):
                    p = sub[later[i]]
                    gap, rate = self._edge_gap(k, p, self._chain(k, p, y), y)
                    return gap, self.sigma[p] * rate   # d gap / d gp

                meet[later] = _bracketed_newton(edge, meet[later], search_end[passed][later])
            self._hand_over(k, sub, meet)
        return passed

    def _hand_over(self, k, points, meet):
        """Surface k-1 becomes active at gp = meet, starting from where it is carried there."""
        if k - 1 >= 1:
            chain = self._chain(k, points, meet, derivatives=False)
            self.own_start[points] = chain.c[k - 1]
        self.active[points] = k - 1
        self.x_start[points] = meet

    def _attachment(self, k, points, x):
        """At gp = x with surface k active and the inner ones tangent at the stress point, the
        least speed (along sigma) at which an inner surface's own leading edge would run ahead of
        its parent's. Positive: the innermost-first choice of step 3 hands over up to k. Zero or
        negative: an inner surface, slower than its parent, would take over ("detachment")."""
        centres, _ = self._state_at(k, points, x)
        margin = np.full(points.size, np.inf)
        for child in range(k + 1, self.law.n + 1):
            chain = self._chain(child, points, x, fixed=centres)
            _, rate = self._edge_gap(child, points, chain, x, own_start=centres[child - 1], x_start=x)
            margin = np.minimum(margin, -rate)
        return margin

    def _restart(self, k, points, x_start, x):
        """Continue the increment of points as a new one from where surface k detaches."""
        x_detach = _first_nonpositive(lambda i, y: self._attachment(k, points[i], y), x_start, x)
        centres, _ = self._state_at(k, points, x_detach)
        self.fixed[:, points] = centres
        self.own_start[points] = centres[-1]
        self.x_start[points] = x_detach
        self.active[points] = self.law.n

    def _finish(self, k, points, x):
        """5.-6. Final centres and the consistent tangent."""
        if points.size == 0:
            return
        k2 = self.law.two_mu_ksh
        centres, slope = self._state_at(k, points, x)
        self.centres[:, points] = centres
        self.x[points] = x
        self.active[points] = k
        self.tangent[points] = k2 * slope / (k2 * np.cos(x) + slope)
        self.done[points] = True


def _first_nonpositive(f, low, high, max_iterations=_MAX_ITERATIONS):
    """For each point the first x from low towards high where the continuous f(i, x) reaches 0
    (f > 0 at low, f <= 0 at high), by the Illinois variant of regula falsi, to round-off."""
    low, high = low.copy(), high.copy()
    everyone = np.arange(low.shape[0])
    f_low, f_high = f(everyone, low), f(everyone, high)
    kept = np.zeros(low.shape[0], dtype=np.int8)     # +1: low kept last time, -1: high kept
    idx = everyone
    for _ in range(max_iterations):
        lo, hi, flo, fhi = low[idx], high[idx], f_low[idx], f_high[idx]
        with np.errstate(divide="ignore", invalid="ignore"):
            x = (lo * fhi - hi * flo) / (fhi - flo)
        x = np.where((x - lo) * (x - hi) < 0.0, x, 0.5 * (lo + hi))
        fx = f(idx, x)
        positive = fx > 0.0
        # Illinois: an end kept twice in a row has its value halved, so the secant moves on
        halve_high = positive & (kept[idx] == -1)
        halve_low = ~positive & (kept[idx] == 1)
        low[idx] = np.where(positive, x, lo)
        f_low[idx] = np.where(positive, fx, np.where(halve_low, 0.5 * flo, flo))
        high[idx] = np.where(positive, hi, x)
        f_high[idx] = np.where(positive, np.where(halve_high, 0.5 * fhi, fhi), fx)
        kept[idx] = np.where(positive, -1, 1)
        tolerance = 2.0 * _EPS * np.maximum(1.0, np.abs(x))
        done = (np.abs(high[idx] - low[idx]) <= tolerance) | (fx == 0.0)
        idx = idx[~done]
        if idx.size == 0:
            break
    return high


def _bracketed_newton(phi_and_slope, low, high, max_iterations=_MAX_ITERATIONS):
    """Roots of phi (one per point) between low (phi > 0 there) and high (phi <= 0 or a bound).

    Newton steps that leave the bracket are replaced by bisection; iterates to round-off.
    ``phi_and_slope(i, x)`` evaluates phi and dphi/dx at x for the points i (indices into low).
    """
    x = low.copy()
    idx = np.arange(x.shape[0])
    for _ in range(max_iterations):
        xi = x[idx]
        phi, slope = phi_and_slope(idx, xi)
        positive = phi > 0.0
        lo = np.where(positive, xi, low[idx])
        hi = np.where(positive, high[idx], xi)
        low[idx], high[idx] = lo, hi
        with np.errstate(divide="ignore", invalid="ignore"):
            newton = xi - phi / slope
        tolerance = 2.0 * _EPS * np.maximum(1.0, np.abs(xi))
        converged = np.abs(newton - xi) <= tolerance
        inside = converged | ((newton - lo) * (newton - hi) < 0.0)
        x[idx] = np.where(phi == 0.0, xi, np.where(inside, newton, 0.5 * (lo + hi)))
        done = (phi == 0.0) | converged | (np.abs(hi - lo) <= tolerance)
        idx = idx[~done]
        if idx.size == 0:
            break
    return x
