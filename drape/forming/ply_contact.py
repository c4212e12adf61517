"""Ply-ply contact: node-to-surface penalty contact with friction between adjacent plies.

Every interface (plies i below, j = i + 1 above) is searched in both directions: the nodes of
ply i against the mid-surface of ply j, and those of ply j against ply i's. The master surface
is the ply's deformed mid-surface, its quadrilaterals split into two flat triangles. For a
slave node x_s and its closest master triangle (a, b, c):

    n = sigma (x_b - x_a) x (x_c - x_a) / |...|    (sigma = -1 if the master lies above)
    g = (x_s - x_a) . n - (t_i + t_j) / 2           (mid-surfaces less the half thicknesses)
    lambda = barycentric coordinates of x_s's projection on the triangle's plane
    ds = du_s - sum_k lambda_k du_k + m             (relative slip since the last converged
                                                     step plus the elastic slip m held then)

The traction t(g, n, ds) is the tools' law (:func:`drape.forming.contact.traction`: smoothed
penalty, regularised Coulomb friction with stick memory); the slave node receives w t and the
master's nodes -lambda_k w t, w half the slave's reference nodal area (each direction carries
half, so two coincident plies under a pressure p carry p over their area). The friction
coefficient may depend on p and on the slip rate v = |(I - n n)(ds - m)| / dt
(:class:`FrictionLaw`).

The Jacobian is exact: the geometry (n, g, lambda, ds) is differentiated with respect to the
12 coordinates of the slave and master nodes (forward mode, :mod:`drape.forming.ply_pair`),
and the law's partial derivatives with respect to g, n, ds and mu are read off its tangent
(:func:`~drape.forming.ply_pair.law_partials`), so nothing of the law is written twice. The
master triangles and the plies' outlines: :mod:`drape.forming.ply_surfaces`.

Candidate pairs come from scipy's cKDTree on the master triangles' centroids, once per load
step (:meth:`PlyContact.search`), within the contact reach plus a margin; nodes that move
more than the margin relative to each other since the search trigger a new one, so the
closest triangle is always among the candidates. Plain numpy on global node numbers: the FE layer
(:mod:`drape.fe.stack_problem`) gathers the displacements and assembles.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from drape.forming.contact import SEPARATED, elastic_slip, normal_pressure, traction
from drape.forming.layup import interface_directions
from drape.forming.ply_pair import barycentric, edge_ramp, law_partials, pair_geometry
from drape.forming.ply_surfaces import StackNodes, reference_order, triangle_outline
from drape.forming.surfaces import closest_point_on_triangles

#: a slave node whose projection falls outside its closest master triangle (beyond a ply's
#: edge) loses its contact smoothly: its weight falls from 1 at the triangle's edge to 0 at
#: this far outside it, in barycentric coordinates (a C1 ramp, so that Newton sees no jump)
EDGE_RAMP = 0.1
#: a slave keeps its master triangle from one Newton iteration to the next while its
#: projection lies within this far outside it (barycentric coordinates) across an inner edge
#: (:meth:`PlyContact.repair`): the closest triangle of a node over a shared vertex or edge
#: (identical plies put every node over a vertex) changes with the slightest sliding, the
#: triangles' normals differ, and a residual jumping with the choice stalls Newton on a
#: frictionless interface, where nothing holds the node in place
PAIRING_HYSTERESIS = 1e-3
#: default search margin (mm): how far nodes may move between searches
DEFAULT_MARGIN = 0.5
#: master triangles whose distance to a slave node is within this of the closest one's (mm)
#: are a tie, decided by the triangles' reference centroids, not by round-off: a slave over a
#: master vertex (every node of two plies meshed alike) is as close to all the triangles
#: around it, whose normals differ once the ply bends, so the last bits of u (MUMPS' order
#: of summation, the ranks) would otherwise pick the normal and the force
TIE_TOLERANCE = 1e-6


class PairForces(NamedTuple):
    """The contact forces of P active pairs: nodes (P, 4) (slave, then the master triangle's
    three), forces on them (P, 4, 3) in N, and their derivatives with respect to the nodes'
    displacements (P, 4, 3, 4, 3) in N/mm."""

    nodes: np.ndarray
    force: np.ndarray
    jacobian: np.ndarray


class PlyContact:
    """The contact of every interface of a stack, both directions, for the slave nodes this
    rank owns (``owned``, a boolean mask over the global nodes)."""

    def __init__(self, nodes: StackNodes, thicknesses, laws, penalty: float,
                 smoothing: float, regularisation: float, owned=None,
                 margin: float = DEFAULT_MARGIN):
        self.nodes = nodes
        self.penalty, self.smoothing = float(penalty), float(smoothing)
        self.regularisation, self.margin = float(regularisation), float(margin)
        n = len(nodes.reference)
        self.owned = np.ones(n, dtype=bool) if owned is None else np.asarray(owned, dtype=bool)
        self.directions = interface_directions(nodes, thicknesses, laws)
        self.step_duration = None
        #: per direction, the elastic slip (N, 3) each slave node held at the last converged
        #: step (friction's memory, as the tools' :class:`~drape.forming.press.ToolContact`)
        self.memory = [np.zeros((n, 3)) for _ in self.directions]
        #: per direction, each slave node's accumulated tangential slip over the committed
        #: steps (mm), and per interface the friction work done on them (N mm, this rank's
        #: slaves: sum over the ranks)
        self.accumulated_slip = [np.zeros(n) for _ in self.directions]
        self.friction_work = np.zeros(len(laws))
        self._trial = [None] * len(self.directions)
        self.candidates = [None] * len(self.directions)
        self._tie_rank = reference_order(nodes)
        self._reachable = [None] * len(self.directions)
        #: per master triangle, which of its edges (the one opposite each vertex) and which
        #: of its vertices lie on its ply's outline: only past those does a slave lose
        #: contact (the edge ramp)
        self.outline_edges, self.outline_vertices = triangle_outline(nodes.triangles,
                                                                     nodes.triangle_ply)
        #: per ply, the width (mm) over which a slave past its outline loses contact:
        #: EDGE_RAMP times its element size, sqrt(2 x its triangles' mean reference area)
        corners = nodes.reference[nodes.triangles][:, :, :2]
        e1, e2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
        area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
        plies = int(nodes.ply.max(initial=0)) + 1
        mean = np.bincount(nodes.triangle_ply, area, plies) / np.maximum(
            np.bincount(nodes.triangle_ply, minlength=plies), 1)
        self.ramp_width = EDGE_RAMP * np.sqrt(2.0 * mean)
        #: per direction, each slave's master triangle (-1: none yet), kept through the
        #: residuals of a Newton iteration (its line search too) and changed only by
        #: :meth:`repair`, so that the residual Newton sees within an iteration is smooth;
        #: forgotten at commit, so that a step's attempt pairs from its start
        self.paired = [np.full(n, -1, dtype=np.int64) for _ in self.directions]
        self.searched_at = None
        self.counts = {"searches": 0, "pairs": 0}

    def set_step_duration(self, seconds: float) -> None:
        """dt (s) of the load step, for the slip rate of a rate-dependent friction law."""
        self.step_duration = float(seconds)

    # --- candidate pairs ------------------------------------------------------------------------
    def search(self, u: np.ndarray) -> None:
        """Candidate (slave, triangle) pairs at displacements u (N, 3): of the master triangles
        whose centroid lies within its radius plus the contact reach plus the margin of a slave
        node this rank owns, those that can be its closest until the next search (below). Of
        these, :meth:`coupled_nodes` are the pairs that can carry a force until then.

        Until the next search no two nodes move more than the margin m relative to each other
        (:meth:`_ensure_candidates`), so a slave's distance to a triangle changes by at most m:
        the triangle closest then is at most 2 m farther now than the closest now. The gap of
        a pair whose projection stays near its triangle changes by about m too (1.4 m at the
        edge ramp's end), so a pair more than the penalty's smoothing g0 plus 2 m apart now
        cannot be pressed before the next search."""
        x = self.nodes.reference + u
        for i, direction in enumerate(self.directions):
            slaves = self.owned & (self.nodes.ply == direction.slave)
            if direction.slaves is not None:
                slaves &= direction.slaves
            slaves = np.nonzero(slaves)[0]
            masters = np.nonzero(self.nodes.triangle_ply == direction.master)[0]
            if not len(slaves) or not len(masters):
                empty = np.zeros(0, dtype=np.int64)
                self.candidates[i], self._reachable[i] = (empty, empty), np.zeros(0, dtype=bool)
                continue
            corners = x[self.nodes.triangles[masters]]
            centroids = corners.mean(axis=1)
            # the triangles' radii now: shear changes their shape
            radius = np.linalg.norm(corners - centroids[:, None], axis=2).max()
            reach = radius + direction.offset + self.smoothing + 2.0 * self.margin
            found = cKDTree(centroids).query_ball_point(x[slaves], reach)
            counts = np.fromiter((len(f) for f in found), dtype=np.int64, count=len(found))
            pair_slaves = np.repeat(slaves, counts)
            pair_triangles = masters[np.concatenate(found).astype(np.int64)] if counts.sum() \
                else np.zeros(0, dtype=np.int64)
            near, reachable = self._can_touch(direction, x, pair_slaves, pair_triangles)
            self.candidates[i] = (pair_slaves[near], pair_triangles[near])
            self._reachable[i] = reachable[near]
        self.searched_at = np.array(u, copy=True)
        self.counts["searches"] += 1

    def _can_touch(self, direction, x, slaves, triangles):
        """Of the pairs (slaves sorted), which can be the slave's closest before the next
        search, and which can be pressed then (:meth:`search`): two masks."""
        if not len(slaves):
            return np.zeros(0, dtype=bool), np.zeros(0, dtype=bool)
        a, b, c = (x[self.nodes.triangles[triangles, k]] for k in range(3))
        _, _, squared = closest_point_on_triangles(x[slaves], a, b, c)
        distance = np.sqrt(squared)
        starts = np.flatnonzero(np.r_[True, slaves[1:] != slaves[:-1]])
        nearest = np.repeat(np.minimum.reduceat(distance, starts),
                            np.diff(np.r_[starts, len(slaves)]))
        # the bound, widened by round-off, so that ties with the closest are kept
        near = distance <= nearest + 2.0 * self.margin * (1.0 + 1e-9) + 1e-12
        normal = np.cross(b - a, c - a)
        with np.errstate(invalid="ignore", divide="ignore"):
            normal *= direction.sign / np.linalg.norm(normal, axis=1)[:, None]
            gap = np.sum((x[slaves] - a) * normal, axis=1) - direction.offset
        return near, gap <= self.smoothing + 2.0 * self.margin

    def _ensure_candidates(self, u) -> None:
        """Search again once two nodes may have moved more than the margin relative to each
        other since the last search (their motions differ from the middle of all motions by
        at most half the margin each): a common translation needs no new search."""
        if self.searched_at is not None and len(u):
            motion = u - self.searched_at
            middle = 0.5 * (motion.max(axis=0) + motion.min(axis=0))
            if np.max(np.linalg.norm(motion - middle, axis=1)) <= 0.5 * self.margin:
                return
        self.search(u)

    def coupled_nodes(self) -> list[np.ndarray]:
        """Per direction, the candidate pairs that can be pressed before the next search
        (:meth:`search`) as (P, 4) node numbers (slave, triangle): what the Jacobian's
        sparsity pattern must hold."""
        out = []
        for (slaves, triangles), reachable in zip(self.candidates, self._reachable):
            out.append(np.column_stack([slaves[reachable],
                                        self.nodes.triangles[triangles[reachable]]]))
        return out

    # --- forces -----------------------------------------------------------------------------
    def evaluate(self, u: np.ndarray, u_committed: np.ndarray) -> PairForces:
        """The forces of every active pair at displacements u (N, 3), slips measured from
        u_committed (N, 3), and their exact derivatives."""
        self._ensure_candidates(u)
        x = self.nodes.reference + u
        parts = []
        for i, direction in enumerate(self.directions):
            parts.append(self._direction_forces(i, direction, x, u - u_committed))
        parts.append(PairForces(np.zeros((0, 4), dtype=np.int64), np.zeros((0, 4, 3)),
                                np.zeros((0, 4, 3, 4, 3))))
        nodes = np.concatenate([p.nodes for p in parts])
        self.counts["pairs"] = len(nodes)
        return PairForces(nodes, np.concatenate([p.force for p in parts]),
                          np.concatenate([p.jacobian for p in parts]))

    def _closest(self, i, x):
        """Per slave with candidates, its closest candidate triangle: (slaves, triangles).
        Triangles within TIE_TOLERANCE of the closest are a tie, won by the first in the
        reference order of their centroids, whatever the ranks and the node numbers."""
        slaves, triangles = self.candidates[i]
        if not len(slaves):
            return slaves, triangles
        corners = x[self.nodes.triangles[triangles]]
        _, _, squared = closest_point_on_triangles(x[slaves], corners[:, 0], corners[:, 1],
                                                   corners[:, 2])
        distance = np.sqrt(squared)
        each, which = np.unique(slaves, return_inverse=True)
        nearest = np.full(len(each), np.inf)
        np.minimum.at(nearest, which, distance)
        tied = distance <= nearest[which] + TIE_TOLERANCE
        rank = self._tie_rank[triangles] + np.where(tied, 0, len(self._tie_rank))
        order = np.lexsort((rank, slaves))
        first = np.ones(len(order), dtype=bool)
        first[1:] = slaves[order][1:] != slaves[order][:-1]
        chosen = order[first]
        return slaves[chosen], triangles[chosen]

    def _paired(self, i, x):
        """Per slave with candidates, its master triangle: the one it is paired with while it
        is a candidate, else (and paired so from now on) the closest."""
        slaves, closest = self._closest(i, x)
        paired = self.paired[i][slaves]
        keep = (paired >= 0) & self._is_candidate(i, slaves, paired)
        chosen = np.where(keep, paired, closest)
        self.paired[i][slaves] = chosen
        return slaves, chosen

    def _is_candidate(self, i, slaves, triangles) -> np.ndarray:
        """Whether each (slave, triangle) is among direction i's candidate pairs."""
        pair_slaves, pair_triangles = self.candidates[i]
        if not len(pair_slaves):
            return np.zeros(len(slaves), dtype=bool)
        width = np.int64(len(self.nodes.triangles) + 1)
        known = np.sort(pair_slaves * width + pair_triangles)
        wanted = slaves * width + np.maximum(triangles, 0)
        at = np.minimum(np.searchsorted(known, wanted), len(known) - 1)
        return known[at] == wanted

    def repair(self, u: np.ndarray) -> bool:
        """Between Newton iterations (at displacements u (N, 3)): pair a slave with its
        closest triangle where its projection has left its triangle by more than
        PAIRING_HYSTERESIS across an inner edge (past the outline the edge ramp takes it out
        of contact); whether any pair changed (this rank's slaves)."""
        self._ensure_candidates(u)
        x = self.nodes.reference + u
        self._before_repair = [paired.copy() for paired in self.paired]
        changed = False
        for i in range(len(self.directions)):
            slaves, closest = self._closest(i, x)
            paired = self.paired[i][slaves]
            known = np.flatnonzero(paired >= 0)
            tri = self.nodes.triangles[paired[known]]
            lam = barycentric(x[slaves[known]], x[tri[:, 0]], x[tri[:, 1]], x[tri[:, 2]])
            left = np.any((lam < -PAIRING_HYSTERESIS) & ~self.outline_edges[paired[known]],
                          axis=1)
            move = np.zeros(len(slaves), dtype=bool)
            move[known[left]] = True
            move &= closest != paired
            changed |= bool(move.any())
            self.paired[i][slaves[move]] = closest[move]
        return changed

    def undo_repair(self) -> None:
        """The pairs as they were before the last :meth:`repair`."""
        self.paired = [paired.copy() for paired in self._before_repair]

    def reset_pairing(self) -> None:
        """Forget the pairs' triangles: the next evaluation pairs every slave with its closest
        (after a commit, and when an attempt is given up)."""
        for paired in self.paired:
            paired[:] = -1

    def _direction_forces(self, i, direction, x, du) -> PairForces:
        slaves, triangles = self._paired(i, x)
        nodes = np.column_stack([slaves, self.nodes.triangles[triangles]]).astype(np.int64)
        memory = self.memory[i][slaves]
        geometry = pair_geometry(x[nodes], du[nodes], direction.sign, direction.offset, memory)
        g, dg, n, dn, lam, dlam, ds, dds = geometry
        ramp, d_ramp = edge_ramp(x[nodes], n, dn, self.outline_edges[triangles],
                                  self.outline_vertices[triangles],
                                  self.ramp_width[direction.master])
        active = ramp > 0.0
        p, stiffness = normal_pressure(g, self.penalty, self.smoothing)
        # the slip rate v = |(I - n n)(ds - m)| / dt and its derivative
        increment = ds - memory
        tangential = increment - np.sum(n * increment, axis=1)[:, None] * n
        d_increment = dds
        d_tangential = (d_increment
                        - n[:, :, None] * (np.einsum("pi,pik->pk", n, d_increment)
                                           + np.einsum("pi,pik->pk", increment, dn))[:, None, :]
                        - np.sum(n * increment, axis=1)[:, None, None] * dn)
        if direction.law.rate_dependent:
            if self.step_duration is None:
                raise ValueError("a rate-dependent friction law needs set_step_duration(dt)")
            length = np.linalg.norm(tangential, axis=1)
            unit = tangential / np.where(length > 0.0, length, 1.0)[:, None]
            rate = length / self.step_duration
            d_rate = np.einsum("pi,pik->pk", unit, d_tangential) / self.step_duration
        else:
            rate, d_rate = np.zeros(len(g)), np.zeros_like(dg)
        mu, dmu_dp, dmu_dv = direction.law(p, rate)
        dmu = dmu_dp[:, None] * (-stiffness[:, None] * dg) + dmu_dv[:, None] * d_rate
        response = traction(g, n, ds, self.penalty, mu, self.regularisation,
                            touching_is_active=True, smoothing=self.smoothing)
        dt_dg, dt_dn, dt_dds, dt_dmu = law_partials(response, n, ds, mu)
        t = response.traction
        dt = (dt_dg[:, :, None] * dg[:, None, :] + np.einsum("pij,pjk->pik", dt_dn, dn)
              + np.einsum("pij,pjk->pik", dt_dds, dds) + dt_dmu[:, :, None] * dmu[:, None, :])
        half_area = 0.5 * self.nodes.area[slaves]
        weight, d_weight = half_area * ramp, half_area[:, None] * d_ramp
        share = np.column_stack([-np.ones(len(slaves)), lam])          # slave: +1, master: -l
        force = -(weight[:, None, None] * share[:, :, None] * t[:, None, :])
        dshare = np.concatenate([np.zeros((len(slaves), 1, 12)), dlam], axis=1)
        jacobian = -(weight[:, None, None, None]
                     * (share[:, :, None, None] * dt[:, None, :, :]
                        + t[:, None, :, None] * dshare[:, :, None, :])
                     + (share[:, :, None] * t[:, None, :])[:, :, :, None]
                     * d_weight[:, None, None, :])
        self._trial[i] = {"slaves": slaves, "slip": ds, "normal": n, "gap": g,
                          "pressure": np.where(active, response.pressure, 0.0),
                          "weight": weight, "state": np.where(active, response.state, SEPARATED),
                          "traction": t, "slip_increment": tangential}
        keep = active & ((response.pressure > 0.0) | (np.abs(dt).max(axis=(1, 2)) > 0.0))
        return PairForces(nodes[keep], force[keep],
                          jacobian[keep].reshape(-1, 4, 3, 4, 3))

    def commit(self) -> None:
        """The converged step becomes the reference of the next: each slave keeps the part of
        its slip within the stick zone (:func:`drape.forming.contact.elastic_slip`)."""
        for i, trial in enumerate(self._trial):
            memory = np.zeros_like(self.memory[i])
            if trial is not None:
                # the step's tangential relative motion, and the work friction did against it
                increment = trial["slip_increment"]
                normal = trial["normal"]
                t = trial["traction"]
                friction = t - np.sum(t * normal, axis=1)[:, None] * normal
                self.friction_work[self.directions[i].interface] -= float(np.sum(
                    trial["weight"] * np.sum(friction * increment, axis=1)))
                self.accumulated_slip[i][trial["slaves"]] += np.linalg.norm(increment, axis=1)
                memory[trial["slaves"]] = elastic_slip(trial["slip"], trial["normal"],
                                                       trial["pressure"], self.regularisation)
            self.memory[i] = memory
        self.reset_pairing()

    def state(self) -> dict:
        """Friction's memory (the elastic slip per direction, (N, 3) each) for a checkpoint."""
        return {f"elastic_slip_{i}": memory for i, memory in enumerate(self.memory)}

    def load_state(self, state: dict) -> None:
        """Take back what :meth:`state` returned (resume from a checkpoint)."""
        self.memory = [np.array(state[f"elastic_slip_{i}"], copy=True)
                       for i in range(len(self.directions))]

    def states(self) -> np.ndarray:
        """Of the last evaluation, the state of every pair (0 separated, 1 stick, 2 slip)."""
        return self.last("state").astype(int)

    def last(self, name: str, direction: int | None = None) -> np.ndarray:
        """Of the last evaluation, one quantity of every pair this rank evaluated, of all
        directions or of ``direction`` (an index into :attr:`directions`): "slaves", "gap"
        (mm), "pressure" (N/mm²), "weight" (the reference area the pair carries, mm²),
        "state", "slip", "slip_increment" (the step's tangential relative motion) and "normal"
        ((P, 3))."""
        trials = self._trial if direction is None else [self._trial[direction]]
        parts = [trial[name] for trial in trials if trial is not None]
        return np.concatenate(parts) if parts else np.zeros(0)

    def report(self) -> dict:
        """Of the last evaluation, per interface (this rank's slave nodes): the largest
        penetration (mm, >= 0), the nodes in contact, the area they carry (mm², half per
        direction) and the normal force (N); the friction work up to the last commit (N mm)."""
        out = {}
        for direction, trial in zip(self.directions, self._trial):
            entry = out.setdefault(direction.interface, {
                "max_penetration": 0.0, "nodes_in_contact": 0, "contact_area": 0.0,
                "normal_force": 0.0,
                "friction_work": float(self.friction_work[direction.interface])})
            if trial is None:
                continue
            carrying = trial["pressure"] > 0.0
            entry["contact_area"] += float(np.sum(trial["weight"][carrying]))
            entry["normal_force"] += float(np.sum(trial["weight"] * trial["pressure"]))
            touching = (trial["weight"] > 0.0) & (trial["gap"] < 0.0)
            if touching.any():
                entry["max_penetration"] = max(entry["max_penetration"],
                                               float(-trial["gap"][touching].min()))
            entry["nodes_in_contact"] += int(np.count_nonzero(trial["pressure"] > 0.0))
        return out
