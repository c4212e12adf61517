"""The nested-surface shear law (reading: docs/material-law.md, version 2), one material point
at a time, compiled with numba.

This module is the one copy of the law's rules. Every function is plain scalar Python on
floats and small arrays, so that ``NUMBA_DISABLE_JIT=1`` runs exactly the same code as Python
(for debugging, and in the test that compares the compiled kernel with the interpreted one).

Units: tau and the surfaces' centres and radii in N/mm (thickness-integrated stress), the
plastic shear angle gp in rad, angles in the state's gamma_max in deg.

A point's increment runs from its committed state to the current yarn-frame C:

1. elastic trial against the innermost surface (the latched Table-2 row, at the committed gp);
2. a trial that leaves it against the branch's direction starts a new branch (rule 1): split
   where tau reaches the innermost edge, latch the row of gamma_max there, resize and re-nest;
3. plastic flow is a march along gp in the branch's direction through *events* (rules 3-6):
   a passive surface reached by its parent's bound is carried, a carried surface whose parent
   slows down is released, the active surface is carried from behind by its parent or hands
   over to it when the leading edges meet. Between events every centre is a closed-form
   function of gp, and the increment ends at the root of
   phi(gp) = sigma (2 mu Ksh (C12 - sin gp) - c_k(gp)) - R_k(gp).

Events are found by sampling each event function on sub-intervals of at most SCAN_STEP (rad)
of gp, with a check of its minimum inside a sub-interval where its slope changes sign, then
located to round-off: a large increment finds the events that small ones cross at their ends.
"""

from __future__ import annotations

import math

import numpy as np

try:
    import numba
except ImportError as error:   # pragma: no cover - scripts/install.sh installs python3-numba
    raise ImportError("drape's law needs numba (Debian: python3-numba; scripts/install.sh "
                      "installs it)") from error

jit = numba.njit(cache=True)

EPS = 2.220446049250313e-16
#: bound on |gp| (rad): cos(gp) > 0 keeps tau(gp) monotone
GAMMA_P_LIMIT = 0.5 * math.pi * (1.0 - 1e-9)
#: widest sub-interval of gp (rad) on which an event function is sampled
SCAN_STEP = 1.0 / 256.0
#: a centre closer than TOUCH * EPS * (|c_j-1| + |c_j| + R_j-1) to its parent's bound touches it
#: (the round-off of a stored state re-evaluated)
TOUCH = 64.0
_MAX_ITERATIONS = 200
_MAX_EVENTS = 64
#: the response's active surface where the increment was elastic
ELASTIC = -1
#: the state's branch direction before anything has yielded
VIRGIN = 0


@jit
def series(coefficients, x):
    """p(x) = sum_i c_i x^(i+1) and p'(x) (coefficients c_1.. of a power series without a
    constant term), by Horner's rule."""
    m = coefficients.shape[0]
    value = coefficients[m - 1]
    slope = 0.0
    for i in range(m - 2, -1, -1):
        slope = slope * x + value
        value = value * x + coefficients[i]
    return value * x, value + slope * x


@jit
def table_row(bounds, gamma_max_deg):
    """Index of the Table-2 row whose range holds gamma_max_deg (bounds: lower bounds, first 0)."""
    row = 0
    for i in range(1, bounds.shape[0]):
        if gamma_max_deg >= bounds[i]:
            row = i
    return row


@jit
def shear_angle_deg(C11, C22, C12):
    """Angle lost between the deformed yarns, asin(C12 / sqrt(C11 C22)), in degrees."""
    ratio = C12 / math.sqrt(max(C11 * C22, 1e-300))
    return math.degrees(math.asin(min(1.0, max(-1.0, ratio))))


@jit
def chain(x, k, mode, anchor, x_anchor, a, h, row, sy, Q, A, c, dc, R, dR):
    """Centres c_0..c_k, radii R_0..R_k and their slopes d/dgp at gp = x, for surfaces 0..k
    in their current modes: 0 free (a passive surface stays at its anchor, the active k moves
    by its own law anchor + h_k (x - x_anchor)), -1 / +1 carried at the lower / upper bound
    c_{j-1} -/+ (R_{j-1} - R_j) of its parent."""
    q, dq = series(Q, x)
    alpha, dalpha = series(A, x)
    c[0], dc[0] = q, dq
    R[0], dR[0] = sy[0] + alpha, dalpha
    for j in range(1, k + 1):
        R[j] = sy[j] + a[row, j] * alpha
        dR[j] = a[row, j] * dalpha
        gap, dgap = R[j - 1] - R[j], dR[j - 1] - dR[j]
        if mode[j] == 0:
            if j == k:
                c[j], dc[j] = anchor[j] + h[row, j] * (x - x_anchor), h[row, j]
            else:
                c[j], dc[j] = anchor[j], 0.0
        elif mode[j] < 0:
            c[j], dc[j] = c[j - 1] - gap, dc[j - 1] - dgap
        else:
            c[j], dc[j] = c[j - 1] + gap, dc[j - 1] + dgap
    return alpha


@jit
def event_function(index, k, sigma, mode, h, row, c, dc, R, dR):
    """Event function ``index`` (2 j: surface j's lower bound or its release, 2 j + 1: its
    upper bound) from an evaluated chain: positive while nothing happens. Returns the value
    and its slope along the march (d/ds, s = sigma (gp - start)); the slope is NaN for release
    functions, which are slopes already."""
    j = index // 2
    upper = index % 2 == 1
    gap, dgap = R[j - 1] - R[j], dR[j - 1] - dR[j]
    speed = h[row, j] if j == k else 0.0       # the free motion's d c_j / d gp
    # (written so that a negated history gives exactly the mirrored values)
    if mode[j] == 0:
        if upper:
            return (c[j - 1] - c[j]) + gap, sigma * ((dc[j - 1] - dc[j]) + dgap)
        return (c[j] - c[j - 1]) + gap, sigma * ((dc[j] - dc[j - 1]) + dgap)
    if upper:
        return math.inf, math.nan
    if mode[j] < 0:    # carried at the lower bound while it pushes harder than the free motion
        return sigma * ((dc[j - 1] - dgap) - speed), math.nan
    return sigma * (speed - (dc[j - 1] + dgap)), math.nan


@jit
def phi(x, k, sigma, C12, two_mu_ksh, c, dc, R, dR):
    """phi(gp) = sigma (tau(gp) - c_k) - R_k, positive while the stress point is beyond the
    active surface's leading edge, and d phi / d gp."""
    value = sigma * (two_mu_ksh * (C12 - math.sin(x)) - c[k]) - R[k]
    slope = sigma * (-two_mu_ksh * math.cos(x) - dc[k]) - dR[k]
    return value, slope


@jit
def settle_modes(x, k, sigma, mode, anchor, x_anchor, a, h, row, sy, Q, A, two_mu_ksh,
                 c, dc, R, dR):
    """At gp = x, with every anchor at the surfaces' positions there, decide each surface's
    mode from the outside in: a free surface touching a bound that pushes it is carried (the
    active surface touching its parent's leading edge hands over instead, rule 6), a carried
    surface whose bound no longer pushes is released. Returns the active surface."""
    for _ in range(4 * (k + 2)):
        chain(x, k, mode, anchor, x_anchor, a, h, row, sy, Q, A, c, dc, R, dR)
        changed = False
        for j in range(1, k + 1):
            gap, dgap = R[j - 1] - R[j], dR[j - 1] - dR[j]
            speed = h[row, j] if j == k else 0.0
            push_low = sigma * ((dc[j - 1] - dgap) - speed) > 0.0
            push_high = sigma * (speed - (dc[j - 1] + dgap)) > 0.0
            if mode[j] == 0:
                touch = TOUCH * EPS * (abs(c[j - 1]) + abs(c[j]) + R[j - 1])
                low = push_low and (c[j] - c[j - 1]) + gap <= touch
                high = push_high and (c[j - 1] - c[j]) + gap <= touch
                if low or high:
                    if j == k and ((high and sigma > 0) or (low and sigma < 0)):
                        k -= 1                    # hand-over to the parent
                    else:
                        mode[j] = -1 if low else 1
                    changed = True
                    break
            elif (mode[j] < 0 and not push_low) or (mode[j] > 0 and not push_high):
                mode[j] = 0
                anchor[j] = c[j]
                changed = True
                break
        if not changed:
            break
        for j in range(1, k + 1):
            anchor[j] = c[j]
    return k


@jit
def root_of_phi(x_start, k, sigma, C12, mode, anchor, x_anchor, a, h, row, sy, Q, A, two_mu_ksh,
                c, dc, R, dR):
    """The gp along sigma from x_start (phi > 0 there) where phi = 0: Newton's method kept
    inside a bracket (bisection where a step leaves it), to round-off."""
    low, high = x_start, sigma * GAMMA_P_LIMIT
    x = x_start
    for _ in range(_MAX_ITERATIONS):
        chain(x, k, mode, anchor, x_anchor, a, h, row, sy, Q, A, c, dc, R, dR)
        value, slope = phi(x, k, sigma, C12, two_mu_ksh, c, dc, R, dR)
        if value == 0.0:
            return x
        if value > 0.0:
            low = x
        else:
            high = x
        step = x - value / slope if slope != 0.0 else math.nan
        if not (min(low, high) < step < max(low, high)):
            step = 0.5 * (low + high)
        # relative to gp itself: tau = 2 mu Ksh (C12 - sin gp) turns an error in gp into
        # 2 mu Ksh times as much in tau
        if abs(step - x) <= EPS * abs(step) or abs(high - low) <= EPS * abs(step):
            return step
        x = step
    return x


@jit
def crossing(index, low, high, k, sigma, mode, anchor, x_anchor, a, h, row, sy, Q, A,
             c, dc, R, dR, slope_of):
    """The first gp from low towards high where event function ``index`` (or, with slope_of,
    minus its slope: its minimum) turns non-positive, given that it is positive at low and
    not at high: the
    Illinois variant of regula falsi, to round-off. Returns the end on the event's side."""
    f_low = _event_value(low, index, k, sigma, mode, anchor, x_anchor, a, h, row, sy, Q, A,
                         c, dc, R, dR, slope_of)
    f_high = _event_value(high, index, k, sigma, mode, anchor, x_anchor, a, h, row, sy, Q, A,
                          c, dc, R, dR, slope_of)
    kept = 0
    for _ in range(_MAX_ITERATIONS):
        if abs(high - low) <= 2.0 * EPS * abs(low) or low == high:
            break
        x = (low * f_high - high * f_low) / (f_high - f_low) if f_high != f_low else math.nan
        if not (min(low, high) < x < max(low, high)):
            x = 0.5 * (low + high)
        fx = _event_value(x, index, k, sigma, mode, anchor, x_anchor, a, h, row, sy, Q, A,
                          c, dc, R, dR, slope_of)
        if fx > 0.0:
            low, f_low = x, fx
            if kept == 1:
                f_high *= 0.5
            kept = 1
        else:
            high, f_high = x, fx
            if kept == -1:
                f_low *= 0.5
            kept = -1
            if fx == 0.0:
                break
    return high


@jit
def _event_value(x, index, k, sigma, mode, anchor, x_anchor, a, h, row, sy, Q, A, c, dc, R, dR,
                 slope_of):
    chain(x, k, mode, anchor, x_anchor, a, h, row, sy, Q, A, c, dc, R, dR)
    value, slope = event_function(index, k, sigma, mode, h, row, c, dc, R, dR)
    return -slope if slope_of else value


@jit
def first_event(x_start, x_end, k, sigma, mode, anchor, x_anchor, a, h, row, sy, Q, A, c, dc, R, dR,
                values, slopes, previous_values, previous_slopes):
    """The first event along sigma in (x_start, x_end] with the modes of the segment: returns
    (gp of the event, index of its function), or (x_end, -1) where there is none."""
    count = 2 * (k + 1)
    if k == 0:
        return x_end, -1
    chain(x_start, k, mode, anchor, x_anchor, a, h, row, sy, Q, A, c, dc, R, dR)
    for i in range(2, count):
        previous_values[i], previous_slopes[i] = event_function(i, k, sigma, mode, h, row, c,
                                                                dc, R, dR)
    pieces = max(1, int(math.ceil(abs(x_end - x_start) / SCAN_STEP)))
    left = x_start
    for piece in range(1, pieces + 1):
        right = x_end if piece == pieces else x_start + (x_end - x_start) * piece / pieces
        chain(right, k, mode, anchor, x_anchor, a, h, row, sy, Q, A, c, dc, R, dR)
        best, best_index = right, -1
        for i in range(2, count):
            value, slope = event_function(i, k, sigma, mode, h, row, c, dc, R, dR)
            values[i], slopes[i] = value, slope
            where = right
            if value < 0.0:
                where = crossing(i, left, right, k, sigma, mode, anchor, x_anchor, a, h, row, sy, Q,
                                 A, c, dc, R, dR, False)
            elif previous_values[i] > 0.0 and previous_slopes[i] < 0.0 and slope >= 0.0:
                # positive at both ends but falling then rising: look at its minimum
                lowest = crossing(i, left, right, k, sigma, mode, anchor, x_anchor, a, h, row, sy,
                                  Q, A, c, dc, R, dR, True)
                least = _event_value(lowest, i, k, sigma, mode, anchor, x_anchor, a, h, row, sy, Q,
                                     A, c, dc, R, dR, False)
                touch = TOUCH * EPS * (abs(c[k - 1]) + abs(c[k]) + R[k - 1])
                if least < 0.0:
                    where = crossing(i, left, lowest, k, sigma, mode, anchor, x_anchor, a, h, row,
                                     sy, Q, A, c, dc, R, dR, False)
                elif least <= touch and i // 2 == k and mode[k] == 0 \
                        and (i % 2 == 1) == (sigma > 0):
                    # the leading edges touch without crossing: they meet (rule 6). Typical
                    # when a branch retraces the line along which its surface was released.
                    where = lowest
                else:
                    continue
            else:
                continue
            if best_index < 0 or sigma * (where - best) < 0.0:
                best, best_index = where, i
        # the event functions' chain is overwritten by the searches: take them up again
        if best_index < 0:
            for i in range(2, count):
                previous_values[i], previous_slopes[i] = values[i], slopes[i]
        if best_index >= 0:
            return best, best_index
        left = right
    return x_end, -1


@jit
def start_branch(C11, C22, C12, C11_committed, C22_committed, C12_committed, x0, sigma,
                 gamma_max_deg, two_mu_ksh, sy, A, bounds, a, c, R, anchor):
    """Rule 1: a trial leaving the innermost surface against the branch's direction starts a
    new branch. Split the increment where tau reaches the innermost edge, latch the Table-2 row
    of gamma_max there (returned), resize the surfaces at the current gp x0 and re-nest them,
    outside in (R, anchor and c overwritten)."""
    n = sy.shape[0] - 1
    tau_split = c[n] + sigma * R[n]
    C12_split = math.sin(x0) + tau_split / two_mu_ksh
    change = C12 - C12_committed
    s = (C12_split - C12_committed) / change if change != 0.0 else 1.0
    s = min(1.0, max(0.0, s))
    angle = shear_angle_deg(C11_committed + s * (C11 - C11_committed),
                            C22_committed + s * (C22 - C22_committed), C12_split)
    row = table_row(bounds, max(gamma_max_deg, abs(angle)))
    alpha, _ = series(A, x0)
    for j in range(1, n + 1):
        R[j] = sy[j] + a[row, j] * alpha
        gap = R[j - 1] - R[j]
        anchor[j] = min(max(anchor[j], c[j - 1] - gap), c[j - 1] + gap)
        c[j] = anchor[j]
    return row


@jit
def march(x0, k, sigma, C12, mode, anchor, a, h, row, sy, Q, A, two_mu_ksh, c, dc, R, dR,
          values, slopes, previous_values, previous_slopes):
    """Rules 3-6: plastic flow along gp from x0 in the branch's direction sigma, event by event
    (a surface carried, released, or handing over), to the root of phi. Returns the end gp,
    the surface active there and the gp where the surfaces were last anchored."""
    x_anchor = x0
    k = settle_modes(x0, k, sigma, mode, anchor, x_anchor, a, h, row, sy, Q, A, two_mu_ksh,
                     c, dc, R, dR)
    x = x0
    for _ in range(_MAX_EVENTS):
        chain(x, k, mode, anchor, x_anchor, a, h, row, sy, Q, A, c, dc, R, dR)
        value, _ = phi(x, k, sigma, C12, two_mu_ksh, c, dc, R, dR)
        if value <= 0.0:
            break
        x_root = root_of_phi(x, k, sigma, C12, mode, anchor, x_anchor, a, h, row, sy, Q, A,
                             two_mu_ksh, c, dc, R, dR)
        x_event, index = first_event(x, x_root, k, sigma, mode, anchor, x_anchor, a, h, row, sy, Q,
                                     A, c, dc, R, dR, values, slopes, previous_values,
                                     previous_slopes)
        if index < 0:
            x = x_root
            break
        # re-anchor every surface where it is at the event, then switch the event's surface
        chain(x_event, k, mode, anchor, x_anchor, a, h, row, sy, Q, A, c, dc, R, dR)
        for j in range(1, k + 1):
            anchor[j] = c[j]
        x = x_anchor = x_event
        j = index // 2
        if mode[j] != 0:
            mode[j] = 0                           # released
        elif j == k and (index % 2 == 1) == (sigma > 0):
            k -= 1                                # the leading edges meet: hand-over
        else:
            mode[j] = 1 if index % 2 == 1 else -1  # reached by its parent's bound
        k = settle_modes(x, k, sigma, mode, anchor, x_anchor, a, h, row, sy, Q, A, two_mu_ksh,
                         c, dc, R, dR)
    return x, k, x_anchor


@jit
def update_point(C11, C22, C12, C11_committed, C22_committed, C12_committed, gamma_p, centres,
                 gamma_max_deg, active, direction, row, two_mu_ksh, sy, Q, A, bounds, a, h,
                 c, dc, R, dR, anchor, values, slopes, previous_values, previous_slopes, mode):
    """One increment of one point (rules 1-8 of docs/material-law.md).

    In: the current yarn-frame C; the committed state (the yarn-frame C of the committed
    state; centres c_1..c_n, overwritten with the new ones); the parameters (a, h: Table 2 as
    (rows, n + 1) arrays); scratch arrays of n + 1 (c .. anchor, mode) and 2 n + 2 (values ..
    previous_slopes) entries, so that nothing is allocated per point. Returns (tau, dtau/dC12,
    gp, gamma_max_deg, active, direction, row, flow), flow the surface active at the end of a
    plastic increment, ELASTIC (-1) where gp did not move."""
    n = sy.shape[0] - 1
    for j in range(n + 1):
        mode[j] = 0
    x0 = gamma_p
    gamma_max = max(gamma_max_deg, abs(shear_angle_deg(C11, C22, C12)))

    # 1. elastic trial against the innermost surface
    for j in range(1, n + 1):
        anchor[j] = centres[j - 1]
    chain(x0, n, mode, anchor, x0, a, h, row, sy, Q, A, c, dc, R, dR)
    sin0 = math.sin(x0)
    tau = two_mu_ksh * (C12 - sin0)
    offset = tau - c[n]
    slack = 8.0 * EPS * (two_mu_ksh * (abs(C12) + abs(sin0)) + abs(c[n]) + R[n])
    if abs(offset) <= R[n] + slack:
        return tau, two_mu_ksh, x0, gamma_max, active, direction, row, ELASTIC
    sigma = 1 if offset > 0.0 else -1

    k = active
    if sigma != direction:
        # 2. a new branch (rule 1)
        row = start_branch(C11, C22, C12, C11_committed, C22_committed, C12_committed, x0,
                           sigma, gamma_max_deg, two_mu_ksh, sy, A, bounds, a, c, R, anchor)
        k, direction = n, sigma

    # 3. the march along gp
    x, k, x_anchor = march(x0, k, sigma, C12, mode, anchor, a, h, row, sy, Q, A, two_mu_ksh,
                           c, dc, R, dR, values, slopes, previous_values, previous_slopes)

    # 4. the end: surfaces 1..k where the march left them, the inner ones tangent at the
    #    stress point (rule 5), and the consistent tangent (rule 8)
    alpha = chain(x, k, mode, anchor, x_anchor, a, h, row, sy, Q, A, c, dc, R, dR)
    tau = two_mu_ksh * (C12 - math.sin(x))
    for j in range(1, n + 1):
        centres[j - 1] = c[j] if j <= k else tau - sigma * (sy[j] + a[row, j] * alpha)
    if x == x0:
        return tau, two_mu_ksh, x, gamma_max, k, direction, row, ELASTIC
    slope = dc[k] + sigma * dR[k]
    tangent = two_mu_ksh * slope / (two_mu_ksh * math.cos(x) + slope)
    return tau, tangent, x, gamma_max, k, direction, row, k


@jit
def update_points(C11, C22, C12, committed_C, gamma_p, centres, gamma_max_deg, active,
                  direction, row, two_mu_ksh, sy, Q, A, bounds, a, h, tau, tangent, flow):
    """:func:`update_point` for every point. The state arrays (committed_C (3, N), gamma_p,
    centres (n, N), gamma_max_deg, active, direction, row) are overwritten with the new state;
    tau, tangent and flow are written."""
    n = sy.shape[0] - 1
    scratch = np.zeros((5, n + 1))
    c, dc, R, dR, anchor = scratch[0], scratch[1], scratch[2], scratch[3], scratch[4]
    events = np.zeros((4, 2 * n + 2))
    values, slopes, previous_values, previous_slopes = events[0], events[1], events[2], events[3]
    mode = np.zeros(n + 1, dtype=np.int64)
    point_centres = np.empty(n)
    for i in range(C12.shape[0]):
        for j in range(n):
            point_centres[j] = centres[j, i]
        result = update_point(C11[i], C22[i], C12[i], committed_C[0, i], committed_C[1, i],
                              committed_C[2, i], gamma_p[i], point_centres, gamma_max_deg[i],
                              active[i], direction[i], row[i], two_mu_ksh, sy, Q, A, bounds,
                              a, h, c, dc, R, dR, anchor, values, slopes, previous_values,
                              previous_slopes, mode)
        tau[i], tangent[i], gamma_p[i], gamma_max_deg[i] = result[0], result[1], result[2], \
            result[3]
        active[i], direction[i], row[i], flow[i] = result[4], result[5], result[6], result[7]
        for j in range(n):
            centres[j, i] = point_centres[j]
        committed_C[0, i], committed_C[1, i], committed_C[2, i] = C11[i], C22[i], C12[i]


def warm_up() -> None:
    """Compile (or load from numba's cache) the kernel for the argument types drape uses: one
    plastic increment of one point with the paper's three surfaces."""
    n, rows = 2, 2
    state = [np.array([[1.0], [1.0], [0.0]]), np.zeros(1), np.zeros((n, 1)), np.zeros(1),
             np.full(1, n, dtype=np.int64), np.zeros(1, dtype=np.int64),
             np.zeros(1, dtype=np.int64)]
    table = np.ones((rows, n + 1))
    update_points(np.ones(1), np.ones(1), np.full(1, 0.1), *state, 284.0,
                  np.array([0.0081, 0.006, 0.0025]), np.full(8, 0.1), np.full(8, 0.1),
                  np.array([0.0, 19.0]), table, table, np.empty(1), np.empty(1),
                  np.empty(1, dtype=np.int64))
