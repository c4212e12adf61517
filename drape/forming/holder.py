"""The blank holder of a forming job: where it pinches the blank, and how its height is set
for a force (force control) as a press's cushion does.

A membrane has no thickness, so the rigid holder pinches the flange against the die, both in
smoothed penalty contact (:func:`drape.forming.contact.normal_pressure`); its height is set
so that the pinched flange carries the pressure F / A (A the blank's reference area under the
holder's flat face: :func:`holder_region` for the built-in tools, :func:`pinch_region` for
STEP tools). A converged step whose measured holder force is off F by more than
:data:`HOLDER_TOLERANCE` is solved again with the holder moved
(:func:`hold_force`, with a :class:`Bracket`), and after every converged step the height is
corrected by the measured force (:class:`HolderControl`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from drape.errors import InputError
from drape.forming.checks import tool_set
from drape.forming.contact import gap_for_pressure

#: fabric counted as under the holder only when it lies on the die's top face (within this, mm)
ON_DIE_TOLERANCE = 1.0
#: a converged step's holder force must be within this fraction of process.holder_force, else
#: the step is solved again with the holder moved (hold_force), at
#: most HOLDER_CORRECTIONS times: corrections between steps alone let the force drift where the
#: fabric under the holder thickens, as in the locking stage (docs/forming.md, "Blank holder").
#: Room for several moves: where the holder comes down from the wrinkles at its rim onto the
#: flat flange the force bends sharply, and closing in on F inside the bracket can take more
#: than the one or two moves most steps need; so can a stack's first step, where the holder
#: reaches plies of different heights one after the other (a response convex in the target),
#: and a move that failed and is made again half as far
HOLDER_TOLERANCE = 0.01
HOLDER_CORRECTIONS = 10
#: until the force has been seen on both sides of F, the re-solves after the first move the
#: target by the error over the secant's slope of the measured force against the target, at
#: least this: where the fabric pushes the holder at its rim the force answers a lift by a
#: small fraction of it (double dome: 0.01-0.1)
HOLDER_LEAST_SLOPE = 0.005
#: and at most this: where the holder's rim presses the fabric drawn over the die's fillet the
#: force grows faster than the target, and a slope bounded by 1 would make the moves overshoot
#: by about as much as they correct, back and forth
HOLDER_MOST_SLOPE = 10.0
#: a step's first attempt starts the holder's target on the polynomial through the last this
#: many converged steps' targets (HolderControl.predict)
TREND_STEPS = 3
#: a converged step whose measured holder force is off process.holder_force by more than this
#: fraction is a warning in the log (with the step and both forces) and is counted in
#: summary.json: the log and the summary never state a force that was not applied
HOLDER_WARNING = 0.05
#: STEP tools: a point of the flat blank is under the holder's flat face when the holder's and
#: the die's normals there are within 1 degree of the press axis (cos 1 deg) and the opening
#: between the two faces is within PINCH_TOLERANCE (mm) of the smallest (:func:`pinch_region`)
FLAT_COSINE = math.cos(math.radians(1.0))
PINCH_TOLERANCE = 0.05


def pinch_region(holder, die, points, comm, reach: float = ON_DIE_TOLERANCE):
    """STEP tools, whatever their shape: the points (P, 3) of the flat blank that lie between a
    flat face of the holder and one of the die (both normals within 1 degree of the press axis,
    both faces within ``reach`` of the point), where the opening between the faces (the sum of
    the two gaps) is within PINCH_TOLERANCE of its smallest value; and that smallest opening
    (mm), which the holder closes before it pinches (collective). On the built-in hemisphere's
    tools this is the ring r >= holder_inner_radius + holder_fillet_radius of holder_region."""
    from mpi4py import MPI
    above, below = holder.query(points, cutoff=reach), die.query(points, cutoff=reach)
    facing = ((above.normal[:, 2] <= -FLAT_COSINE) & (below.normal[:, 2] >= FLAT_COSINE)
              & (np.abs(above.gap) <= reach) & (np.abs(below.gap) <= reach))
    opening = above.gap + below.gap
    least = comm.allreduce(float(opening[facing].min()) if facing.any() else math.inf,
                           op=MPI.MIN)
    # no flat pinch anywhere: an empty region (HolderControl says so), opening 0
    return facing & (opening <= least + PINCH_TOLERANCE), least if math.isfinite(least) else 0.0


def holder_region(config):
    """A function (P, 3) positions -> mask of the points under the holder's flat face, or None
    (STEP tools: :func:`pinch_region` finds it on the tools)."""
    tools, dims = tool_set(config)
    if tools.kind == "hemisphere":
        inner = dims.holder_inner_radius + dims.holder_fillet_radius
        outer = dims.holder_outer_radius

        def region(x):
            r = np.hypot(x[:, 0], x[:, 1])
            return (r >= inner) & (r <= outer) & (x[:, 2] > -dims.gap - ON_DIE_TOLERANCE)
        return region
    if tools.kind == "double_dome":
        a = dims.dome_offset
        opening = dims.holder_opening_radius + dims.holder_edge_radius

        def region(x):
            d = np.hypot(x[:, 0] - np.clip(x[:, 0], -a, a), x[:, 1])
            return ((d >= opening) & (np.abs(x[:, 0]) <= dims.die_length / 2)
                    & (np.abs(x[:, 1]) <= dims.die_width / 2)
                    & (x[:, 2] > -dims.gap - ON_DIE_TOLERANCE))
        return region
    return None


class HolderControl:
    """Force control of the rigid holder: its height for a total force F (N).

    The flange of reference area A (under the holder's flat face) pinched between the die
    (top at z = 0) and the holder (bottom at z = -d) settles midway, at a gap -d/2 from each,
    where both push with the pressure p(-d/2) of the smoothed penalty; so d = -2 g(F' / A) with
    g the inverse of the penalty law (:func:`drape.forming.contact.gap_for_pressure`). F' starts at
    F
    and after every converged step moves by half the difference between F and the measured
    holder force (fabric thicker than flat where it wrinkles or bunches, the flange leaving the
    flat face), which brings the measured force to F within a few steps. Where the fabric
    pushes the holder elsewhere too (at its rim, or wrinkles rising under it), F' goes below
    F, and below F_min = 1e-3 F the holder keeps lifting, by 2 (F_min - F') / (eps_N A), the
    slope of the plain penalty's branch: a press's cushion lifts as far as the force needs.
    Without the lift the holder would stop 2 g0 above the die, where the smoothed penalty's
    pressure falls to zero, and could not rise far enough to bring the force down to F.

    A stack whose highest ply under the holder is ply k (``contacts`` = k + 2 penalty contacts
    in series: holder on ply k, the k interfaces below it, the bottom ply on the die, each at
    the same pressure) closes k + 2 gaps instead of 2, and ply k's mid-surface lies z_k above
    the die (``opening`` less z_k: the holder's face starts there)."""

    GAIN = 0.5

    def __init__(self, force: float, area: float, penalty: float, smoothing: float,
                 opening: float = 0.0, contacts: int = 2, trend: bool = False):
        if area <= 0.0:
            raise InputError("no blank under the blank holder", key="process.holder_force",
                             value=force, expected="a blank reaching under the holder's flat "
                             "face (STEP tools: a flat face of the holder facing one of the "
                             "die, within 1 mm of the blank's plane z = 0), or holder_force = 0")
        self.force, self.area, self.penalty, self.smoothing = force, area, penalty, smoothing
        #: how far the holder travels before its face reaches the die's (STEP tools: the
        #: opening between them where the blank lies in it, :func:`pinch_region`; 0 built-in)
        self.opening = float(opening)
        #: penalty contacts in series between the holder and the die (2: one ply)
        self.contacts = float(contacts)
        self.target = force
        #: the target the next attempt starts from, before the trend: F' after the last
        #: converged step's correction
        self.committed = force
        #: process.holder_prediction = "trend": predict() extrapolates, and a step's first
        #: re-solve uses the slope measured before
        self.follows_trend = trend
        #: (load factor, F') of the last TREND_STEPS converged steps, oldest first
        self.settled: list[tuple[float, float]] = []
        #: d measured / d F' where the last step's re-solves measured it (1: the flat flange)
        self.slope = 1.0

    def lowering(self) -> float:
        """d (mm): how far below the die's top face the holder's face is (negative: above);
        continuous and increasing in the target force F'."""
        least = 1e-3 * self.force
        d = -self.contacts * gap_for_pressure(max(self.target, least) / self.area, self.penalty,
                                              self.smoothing)
        return (self.opening + d
                - self.contacts * max(least - self.target, 0.0) / (self.penalty * self.area))

    def update(self, measured: float, t: float) -> None:
        """After the step converged at load factor t with the holder at F' (``target``)
        measuring ``measured``: keep (t, F') for the trend, and correct F' by GAIN times the
        error."""
        self.settled = [*self.settled, (t, self.target)][-TREND_STEPS:]
        self.target += self.GAIN * (self.force - measured)
        self.committed = self.target

    def predict(self, t: float) -> None:
        """The target for an attempt at load factor t: the committed one carried on along the
        polynomial through the last converged steps' targets (quadratic from the third step
        on). The target the holder needs drifts as the flange draws in and thickens, faster
        and faster where the holder lifts off wrinkles at its rim; a step that started from
        the last target missed it by more than the tolerance, and took two or three holder
        re-solves."""
        if not self.follows_trend or len(self.settled) < 2:
            self.target = self.committed
            return
        from scipy.interpolate import BarycentricInterpolator
        times, targets = zip(*self.settled)
        ahead = float(BarycentricInterpolator(times, targets)(t))
        self.target = self.committed + ahead - targets[-1]

    def first_slope(self) -> float:
        """d measured / d F' for a step's first re-solve: the last one measured (following the
        trend), else 1."""
        return self.slope if self.follows_trend else 1.0

    def state(self) -> dict:
        """What a checkpoint keeps of the control (:meth:`load_state` restores it): 0-d
        arrays, none missing (NaN for steps not yet seen)."""
        state = {"holder_target": np.array(self.committed), "holder_slope": np.array(self.slope)}
        for k in range(TREND_STEPS):
            t, target = self.settled[k] if k < len(self.settled) else (np.nan, np.nan)
            state[f"holder_settled_t{k}"] = np.array(t)
            state[f"holder_settled_target{k}"] = np.array(target)
        return state

    def load_state(self, state: dict) -> None:
        self.committed = self.target = float(state["holder_target"])
        if "holder_slope" in state:         # absent in a checkpoint of before the trend
            self.slope = float(state["holder_slope"])
            self.settled = [(float(state[f"holder_settled_t{k}"]),
                             float(state[f"holder_settled_target{k}"]))
                            for k in range(TREND_STEPS)
                            if not np.isnan(state[f"holder_settled_t{k}"])]


class Bracket:
    """The holder targets F' whose measured force came closest to F from below (error F -
    measured > 0) and from above (< 0), for the regula falsi of
    :func:`hold_force`."""

    def __init__(self):
        self.below = self.above = None      # [target, error]
        self.kept = None                    # which end the last new point did not replace

    def add(self, target: float, error: float) -> None:
        side = "below" if error > 0.0 else "above"
        end = getattr(self, side)
        if end is None or abs(error) < abs(end[1]) or self.closed:
            setattr(self, side, [target, error])
        other = "above" if side == "below" else "below"
        if self.closed:
            if self.kept == other:          # the other end kept twice running: halve its error
                getattr(self, other)[1] *= 0.5
            self.kept = other

    @property
    def closed(self) -> bool:
        return self.below is not None and self.above is not None

    def inside(self) -> float:
        """The target where the line through the two ends meets F."""
        (t0, e0), (t1, e1) = self.below, self.above
        return t0 + e0 * (t1 - t0) / (e0 - e1)


def hold_force(forming, t: float, solve, result):
    """After an attempt of ``forming`` (drape.forming.press.Forming: its holder, tool_force,
    set_load and problem) at load factor t (``result``, a SolveResult): while it converged and
    the holder's force is off process.holder_force F by more than HOLDER_TOLERANCE F, move
    the holder and ``solve()`` again from there, at most HOLDER_CORRECTIONS times
    (collective). The first move changes the target force by the difference (the flat
    flange carries the target, plus what wrinkles or the flange's edge add, which changes
    little when it moves), or with process.holder_prediction = "trend" by the difference
    over the slope d measured / d target the last secant measured (where the fabric holds
    the holder up at its rim, 0.05-0.1), the next ones by a secant step, until the force
    has been measured both below and above F. From then on the target stays inside that bracket
    (the force grows with the target, so the bracket holds the answer), at its regula
    falsi point (Illinois: the end kept twice running has its error halved, so that a
    curved response does not stall it). Returns the last result with the iterations and
    seconds of all. A re-solve that fails moved the holder too far in one go (a stack's
    plies of different heights answer a move as the holder reaches the next one: 4 N, then
    541 N for 200 N): the state of the last converged solve comes back and the next move
    goes half as far. When all the moves are spent, the solve closest to F is kept: where
    the holder comes down from resting on the wrinkles at its rim onto the flat flange the
    force bends sharply, and the last move may land farther off than an earlier one; but
    where a re-solve failed and the kept one is off F by more than HOLDER_WARNING, the
    attempt fails (a smaller step may do), the target back to what it was."""
    holder = forming.holder
    if holder is None or not result.converged:
        return result
    start, iterations, seconds = holder.target, result.iterations, result.seconds
    last = None                     # (target, measured) of the solve before
    closest = None                  # (|error|, target, displacement, result) of the best solve
    bracket = Bracket()
    halfway = None                  # after a failed re-solve, the next target
    failure = None                  # the last re-solve that failed
    for _ in range(HOLDER_CORRECTIONS):
        if halfway is None:
            measured = forming.tool_force("holder")
            error = holder.force - measured
            if abs(error) <= HOLDER_TOLERANCE * holder.force:
                break
            converged = (abs(error), holder.target, forming.problem.u.x.array.copy(), result)
            if closest is None or abs(error) < closest[0]:
                closest = converged
            bracket.add(holder.target, error)
            if bracket.closed:
                target = bracket.inside()
            else:
                slope = holder.first_slope()    # d measured / d target
                if last is not None and holder.target != last[0]:
                    slope = (measured - last[1]) / (holder.target - last[0])
                    slope = holder.slope = min(max(slope, HOLDER_LEAST_SLOPE),
                                               HOLDER_MOST_SLOPE)
                target = holder.target + error / slope
            last = (holder.target, measured)
        else:
            target, halfway = halfway, None
        holder.target = target
        forming.set_load(t)
        result = solve()
        iterations, seconds = iterations + result.iterations, seconds + result.seconds
        if not result.converged:    # back to the last converged solve, half the move
            failure = result
            halfway = 0.5 * (converged[1] + target)
            take_solve(forming, t, converged)
            result = converged[3]
    else:
        if abs(holder.force - forming.tool_force("holder")) > closest[0]:
            take_solve(forming, t, closest)
            result = closest[3]
    if failure is not None and abs(holder.force - forming.tool_force("holder")) > (
            HOLDER_WARNING * holder.force):
        holder.target = start
        forming.set_load(t)
        result = failure
    return dataclasses.replace(result, iterations=iterations, seconds=seconds)


def take_solve(forming, t: float, solve) -> None:
    """Back to a converged solve (|error|, holder target, displacement, result) of
    :func:`hold_force`: its holder target and tools at load factor t, its
    displacement, and the law's and the tools' state there."""
    _, forming.holder.target, displacement, _ = solve
    forming.set_load(t)
    forming.problem.u.x.array[:] = displacement
    forming.problem.evaluate()
