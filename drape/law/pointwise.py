"""The same law as :mod:`drape.law.nested_surface`, one material point at a time in plain Python.

A straightforward transcription of ``docs/material-law.md`` with scalars and ``math``: the
baseline of the law benchmark and a second implementation the vectorised one is tested against.
It is not meant to be fast.
"""

from __future__ import annotations

import bisect
import math

from drape.law.parameters import MaterialParameters


class PointwiseLaw:
    def __init__(self, params: MaterialParameters):
        self.p = params
        self.n = params.n
        self.k2 = 2.0 * params.mu * params.Ksh
        self.bounds = list(params.surfaces.gamma_max_deg)
        self.a_rows = params.a_rows().tolist()
        self.h_rows = params.h_rows().tolist()

    def poly(self, coefficients, x):
        value = sum(c * x ** (i + 1) for i, c in enumerate(coefficients))
        slope = sum((i + 1) * c * x ** i for i, c in enumerate(coefficients))
        return value, slope

    def chain(self, x, a, h, fixed, active, sigma, own_start, x_start):
        """Centres, radii and their slopes of surfaces 0..n at plastic angle x."""
        q, dq = self.poly(self.p.Q, x)
        al, dal = self.poly(self.p.A, x)
        r = [self.p.Sy[j] + a[j] * al for j in range(self.n + 1)]
        dr = [a[j] * dal for j in range(self.n + 1)]
        c, dc = [q], [dq]
        for j in range(1, self.n + 1):
            gap, dgap = r[j - 1] - r[j], dr[j - 1] - dr[j]
            lower, upper = c[j - 1] - gap, c[j - 1] + gap
            if j == active:
                own = own_start + h[j] * (x - x_start)
                trailing = c[j - 1] - sigma * gap
                if sigma * (own - trailing) >= 0:
                    c.append(own); dc.append(h[j])
                else:
                    c.append(trailing); dc.append(dc[j - 1] - sigma * dgap)
            elif fixed[j - 1] < lower:
                c.append(lower); dc.append(dc[j - 1] - dgap)
            elif fixed[j - 1] > upper:
                c.append(upper); dc.append(dc[j - 1] + dgap)
            else:
                c.append(fixed[j - 1]); dc.append(0.0)
        return c, r, dc, dr

    @staticmethod
    def root(f, low, high):
        """Root of f between low (f > 0) and high (f <= 0 or a bound): Newton with bisection."""
        x = low
        for _ in range(200):
            value, slope = f(x)
            if value == 0.0:
                return x
            if value > 0:
                low = x
            else:
                high = x
            new = x - value / slope if slope != 0 else math.nan
            if not (min(low, high) < new < max(low, high)):
                new = 0.5 * (low + high)
            if abs(new - x) <= 2e-16 * max(1.0, abs(x)):
                return new
            x = new
        return x

    def update(self, gamma_p, centres, gamma_max_deg, C11, C22, C12):
        """One increment of one point. Returns (tau, dtau_dC12, gamma_p, centres, gamma_max, k)."""
        n, k2 = self.n, self.k2
        gamma_t = math.degrees(math.asin(max(-1.0, min(1.0, C12 / math.sqrt(C11 * C22)))))
        gamma_max = max(gamma_max_deg, abs(gamma_t))
        row = bisect.bisect_right(self.bounds, gamma_max) - 1
        a, h = self.a_rows[row], self.h_rows[row]
        c, r, _, _ = self.chain(gamma_p, a, h, centres, n + 1, 0.0, 0.0, 0.0)
        tau = k2 * (C12 - math.sin(gamma_p))
        slack = 8 * 2.220446049250313e-16 * (k2 * (abs(C12) + abs(math.sin(gamma_p))) + abs(c[n]) + r[n])
        if abs(tau - c[n]) <= r[n] + slack:
            return tau, k2, gamma_p, c[1:], gamma_max, -1
        sigma = 1.0 if tau > c[n] else -1.0
        limit = sigma * 0.5 * math.pi * (1.0 - 1e-9)
        eps = 2.220446049250313e-16

        def chain(x, fixed, k, own_start, x_start):
            return self.chain(x, a, h, fixed, k, sigma, own_start, x_start)

        def edge_gap(y, fixed, k, own_start, x_start):
            """Distance from surface k's leading edge to its parent's, and its rate along sigma."""
            cc, rr, dcc, drr = chain(y, fixed, k, own_start, x_start)
            gap = sigma * (cc[k - 1] - cc[k]) + rr[k - 1] - rr[k]
            if abs(gap) <= 16 * eps * (k2 + abs(cc[k - 1]) + abs(cc[k]) + rr[k - 1]):
                gap = 0.0
            return gap, dcc[k - 1] - dcc[k] + sigma * (drr[k - 1] - drr[k])

        def state_at(y, fixed, k, own_start, x_start):
            """Centres at gp = y with surface k active and the inner ones tangent at the stress point."""
            cc, rr, dcc, drr = chain(y, fixed, k, own_start, x_start)
            point = cc[k] + sigma * rr[k]
            return [cc[j] if j <= k else point - sigma * rr[j] for j in range(1, n + 1)]

        def detached(y, fixed, k, own_start, x_start):
            """Would an inner surface, slower than the active k, take over at gp = y?"""
            centres_y = state_at(y, fixed, k, own_start, x_start)
            return any(edge_gap(y, centres_y, child, centres_y[child - 1], y)[1] >= 0
                       for child in range(k + 1, n + 1))

        def split(test, lo, hi):
            """Adjacent floats (lo, hi) where test turns from True (at lo) to False (at hi)."""
            for _ in range(200):
                mid = 0.5 * (lo + hi)
                if mid in (lo, hi):
                    break
                lo, hi = (mid, hi) if test(mid) else (lo, mid)
            return lo, hi

        fixed = c[1:]
        k, x_start, own_start = n, gamma_p, c[n]
        for _restart in range(20):
            while True:
                def g(x):
                    cc, rr, dcc, drr = chain(x, fixed, k, own_start, x_start)
                    value = k2 * (C12 - math.sin(x)) - cc[k] - sigma * rr[k]
                    slope = -(k2 * math.cos(x) + dcc[k] + sigma * drr[k])
                    return sigma * value, sigma * slope

                if k == 0:
                    x = self.root(g, x_start, limit)
                    break
                gap_start, rate_start = edge_gap(x_start, fixed, k, own_start, x_start)
                if gap_start <= 0 and rate_start < 0:
                    x = meet = x_start
                else:
                    x = self.root(g, x_start, limit)
                    gap_end, rate_end = edge_gap(x, fixed, k, own_start, x_start)
                    end = x
                    if gap_end >= 0 and rate_start < 0 < rate_end:
                        # the gap may close and reopen inside the increment: check its minimum
                        lowest, _ = split(lambda y: edge_gap(y, fixed, k, own_start, x_start)[1] < 0,
                                           x_start, x)
                        if edge_gap(lowest, fixed, k, own_start, x_start)[0] < 0:
                            gap_end, end = -1.0, lowest
                    if gap_end >= 0:
                        break

                    def gap_and_slope(y):
                        gap, rate = edge_gap(y, fixed, k, own_start, x_start)
                        return gap, sigma * rate

                    meet = x_start if gap_start <= 0 else self.root(gap_and_slope, x_start, end)
                cc, _, _, _ = chain(meet, fixed, k, own_start, x_start)
                k, x_start, own_start = k - 1, meet, cc[k - 1]
            if k == n or not detached(x, fixed, k, own_start, x_start):
                break
            # restart the rest of the increment where a slower inner surface takes over
            _, x_detach = split(lambda y: not detached(y, fixed, k, own_start, x_start), x_start, x)
            fixed = state_at(x_detach, fixed, k, own_start, x_start)
            k, x_start, own_start = n, x_detach, fixed[n - 1]
        cc, rr, dcc, drr = chain(x, fixed, k, own_start, x_start)
        tau = k2 * (C12 - math.sin(x))
        slope = dcc[k] + sigma * drr[k]
        return (tau, k2 * slope / (k2 * math.cos(x) + slope), x, state_at(x, fixed, k, own_start, x_start),
                gamma_max, k)
