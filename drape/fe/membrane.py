"""The total-Lagrangian membrane problem on the flat reference blank (DOLFINx 0.5).

Unknown: the displacement u (mm), three components, continuous piecewise linear (bilinear on
quadrilaterals) over the flat reference blank in the X-Y plane. With I32 the 3x2 embedding of
the plane,

    F = I32 + grad u   (3x2),   C = F^T F   (2x2),   E = (C - I)/2,

and in the yarn frame G1 = (cos theta, sin theta), G2 = (-sin theta, cos theta) the law gives the
thickness-integrated PK2 stress (N/mm)

    S = S11 G1 G1 + S22 G2 G2 + tau/2 (G1 G2 + G2 G1),   S11 = mu K1 E11, S22 = mu K2 E22.

The residual is the internal virtual work minus external point forces plus the regularisation
and, when the fabric's bending rigidity B (N mm) is set, the variation of the bending hinges'
energy W_b (:mod:`drape.fe.bending`):

    R(u; v) = int S : sym(F^T grad v) dA + int k (u_z - u_z,last) v_z dA - sum_c int f_c . v dA
              + d/du W_b(u; v).

On a stack of plies (:class:`~drape.fe.stack_mesh.StackMesh`) every ply may have its own yarn
angle theta and its own law: where the plies' values differ, cos theta, sin theta and
mu K1 / 2, mu K2 / 2 are DG0 functions (per cell, from its ply) instead of numbers, and the law
runs on each ply's points with that ply's parameters (drape/law/piecewise.py). Where the
plies share them the forms and the law are a single ply's, value for value.

S11 and S22 are written in UFL (:mod:`drape.fe.membrane_forms`); tau and its consistent tangent
d tau / d C12 come from the compiled law at the quadrature points. Every residual evaluation
computes the yarn-frame C at the quadrature points (a compiled
:class:`dolfinx.fem.Expression`), runs the law from the *committed* state (so a line search may
call it any number of times) and writes tau and the tangent into quadrature-space functions.
The Jacobian is ``ufl.derivative`` of the residual with tau frozen (yarn tension and the whole
geometric stiffness) plus the shear tangent ``dtau/dC12 * dE12(du) * 2 dE12(v)``, the
regularisation and the point stiffnesses; with a ``neutral_loading_band`` the shear tangent is
stiffened where a point is only just plastic (:func:`neutral_loading_tangent`).

The law's state (gamma_p, the centres c_1..c_n, gamma_max, the branch's active surface,
direction and Table-2 row, the committed yarn-frame C) lives in quadrature-space functions
too; :meth:`MembraneProblem.commit` writes the last trial state there after a converged step,
:meth:`MembraneProblem.restore` goes back to the committed displacement after a failed one.

Quadrature: 2x2 Gauss points on quadrilaterals (degree 2), the centroid on triangles (degree 1,
exact for linear triangles). The regularisation and point contributions
(:mod:`drape.fe.contributions`) use degree 2 on both.
"""

from __future__ import annotations

import time
from typing import Sequence

import numpy as np

from drape.fe.contributions import PointContribution, all_finite
from drape.fe.membrane_forms import membrane_forms, regularisation_forms
from drape.fe.newton_tangent import neutral_loading_tangent

#: quadrature degree of the law's points, by cell type name
LAW_DEGREE = {"quadrilateral": 2, "triangle": 1}


class MembraneProblem:
    """Spaces, state, forms and the SNES callbacks of the membrane on a :class:`BlankMesh`."""

    def __init__(self, blank_mesh, law, yarn_angle_deg: float | Sequence[float], damping: float,
                 contributions: list[PointContribution] | None = None,
                 jit_params: dict | None = None,
                 bending_rigidity: float = 0.0, inertia: bool = False,
                 neutral_loading_band: float = 0.0):
        """``law``: one :class:`~drape.law.nested_surface.NestedSurfaceLaw` for every cell, or
        a sequence of them, one per ply of a stack (the cells mapped by
        ``blank_mesh.cell_plies()``); ``yarn_angle_deg`` (deg, from x to the warp) likewise one
        or one per ply. ``neutral_loading_band`` (rad): :func:`neutral_loading_tangent`'s band
        for Newton's Jacobian; 0 keeps the law's consistent tangent everywhere."""
        import ufl
        from dolfinx import fem

        self.blank_mesh = blank_mesh
        self.mesh = blank_mesh.mesh
        self.comm = self.mesh.comm
        self._plies(law, yarn_angle_deg)
        self.damping = float(damping)
        self.neutral_loading_band = float(neutral_loading_band)
        self.contributions = list(contributions or [])
        self.timings = dict.fromkeys(("law", "quadrature_values", "contributions",
                                      "residual_assembly",
                                      "jacobian_assembly"), 0.0)
        self.counts = dict.fromkeys(("residual", "jacobian", "law"), 0)
        self.bending_rigidity = float(bending_rigidity)
        jit = dict(jit_params or {})

        areas_with_ghosts = self._quadrature(jit)
        self._point_law()
        self._spaces_and_state()
        u, v, du = self.u, ufl.TestFunction(self.V), ufl.TrialFunction(self.V)
        kinematics, internal, jacobian, self.strip_reduced = membrane_forms(
            self.mesh, blank_mesh, self.plies, u, self.tau, self.dtau, self.degree, v, du)
        F = kinematics.F
        terms = regularisation_forms(self.mesh, self.V, u, self.u_committed, internal, jacobian,
                                     v, du, self.damping, inertia)
        residual, jacobian, regularisation_work = terms.residual, terms.jacobian, terms.work
        self.damping_constant, self.inertia_constant = terms.damping_constant, \
            terms.inertia_constant
        self.u_anchor = terms.u_anchor
        bending_energy = None
        if self.bending_rigidity > 0.0:
            from drape.fe.bending import hinge_energy
            bending_energy, self.cell_size = hinge_energy(self.mesh, F, areas_with_ghosts,
                                                          self.bending_rigidity)
            bending_residual = ufl.derivative(bending_energy, u, v)
            residual += bending_residual
            jacobian += ufl.derivative(bending_residual, u, du)
        from drape.fe.contributions import PointTerms
        self.point_terms = PointTerms(self.mesh, self.contributions, u, self.cells, jit)
        self.extra_points, self.extra_weights = self.point_terms.points, self.point_terms.weights
        residual, jacobian = self.point_terms.add_to(residual, jacobian, v, du)

        self.residual_form = fem.form(residual, jit_params=jit)
        self.jacobian_form = fem.form(jacobian, jit_params=jit)
        self.internal_form = fem.form(internal, jit_params=jit)
        self.regularisation_work_form = fem.form(regularisation_work, jit_params=jit)
        self.bending_energy_form = (fem.form(bending_energy, jit_params=jit)
                                    if bending_energy is not None else None)
        self._point_expressions(kinematics, jit)

        self.bcs = []
        self.response = None
        self._evaluated_at = None
        #: where a NaN/Inf appeared since the last :meth:`clear_nonfinite` ("law", "residual",
        #: a contribution's name), on this rank; the solver gathers it after each solve
        self.nonfinite: set[str] = set()
        self._finite = True

    # --- building the problem ---------------------------------------------------------------
    def _plies(self, law, yarn_angle_deg) -> None:
        """The plies' laws and yarn angles (drape/fe/ply_properties.py), with their attributes
        on the problem: :attr:`laws`, :attr:`yarn_angles_deg`, :attr:`cell_ply`,
        :attr:`uniform_law`, :attr:`yarn_angle_deg` (None when the plies' angles differ)."""
        from drape.fe.ply_properties import PlyProperties
        self.plies = plies = PlyProperties(self.blank_mesh, law, yarn_angle_deg)
        self.laws, self.yarn_angles_deg, self.cell_ply = (plies.laws, plies.yarn_angles_deg,
                                                          plies.cell_ply)
        self.uniform_law, self.yarn_angle_deg = plies.uniform_law, plies.yarn_angle_deg

    def _point_law(self) -> None:
        """The law of every local law point (:attr:`point_law`) and :attr:`law`."""
        self.point_law, self.law = self.plies.point_law(self.n_cells, self.nq)
        #: 2 mu Ksh: a number, or one per point when the plies' laws differ
        self._elastic_shear = self.law.two_mu_ksh
        self._yarn_stiffness = self.point_law.yarn_stiffness()

    def _quadrature(self, jit: dict) -> np.ndarray:
        """The law's quadrature rule, the local cells and their reference areas (mm^2);
        returns the areas of the local and ghost cells (the bending hinges on the edges a rank
        shares need the cell size on both sides)."""
        import basix
        import ufl
        from dolfinx import fem
        msh = self.mesh
        cell_name = msh.topology.cell_type.name
        self.degree = LAW_DEGREE[cell_name]
        self.points, self.weights = basix.make_quadrature(getattr(basix.CellType, cell_name),
                                                          self.degree)
        nq = self.nq = len(self.weights)
        self.n_cells = msh.topology.index_map(2).size_local
        self.cells = np.arange(self.n_cells, dtype=np.int32)
        n_all = self.n_cells + msh.topology.index_map(2).num_ghosts
        detJ = fem.Expression(ufl.JacobianDeterminant(msh), self.points, jit_params=jit)
        weights = (np.abs(detJ.eval(np.arange(n_all, dtype=np.int32))).reshape(n_all, nq)
                   * self.weights)
        areas_with_ghosts = weights.sum(axis=1)
        self.cell_areas = areas_with_ghosts[: self.n_cells]
        self._average_weights = weights[: self.n_cells] / self.cell_areas[:, None]
        return areas_with_ghosts

    def _spaces_and_state(self) -> None:
        """The displacement space and functions, and the quadrature functions of tau, its
        tangent and the law's committed state (virgin)."""
        import ufl
        from dolfinx import fem
        from drape.law.nested_surface import LawState
        msh = self.mesh
        self.V = fem.VectorFunctionSpace(msh, ("CG", 1), dim=3)
        self.u = fem.Function(self.V, name="displacement")
        self.u_committed = fem.Function(self.V, name="committed_displacement")
        #: the converged step before the committed one, and both load factors (a predictor
        #: extrapolates from them; None before two steps have converged)
        self.u_previous = fem.Function(self.V, name="previous_displacement")
        self.t_committed, self.t_previous = 0.0, None
        q_element = ufl.FiniteElement("Quadrature", msh.ufl_cell(), self.degree,
                                      quad_scheme="default")
        self.Q = fem.FunctionSpace(msh, q_element)
        self.qdofs = self.Q.dofmap.list.array.reshape(-1, self.nq)[: self.n_cells].ravel()
        self.tau = fem.Function(self.Q, name="tau")
        self.dtau = fem.Function(self.Q, name="dtau_dC12")
        # the law's committed state, one quadrature function per quantity (LawState.columns)
        virgin = LawState.virgin(1, self.point_law.n).columns()
        points = self.point_law.virgin().columns()
        self.law_state = {name: fem.Function(self.Q, name=f"law_{name}") for name in virgin}
        for name, function in self.law_state.items():
            function.x.array[:] = virgin[name][0]
            function.x.array[self.qdofs] = points[name]
        self.tau.x.array[:] = 0.0
        # elastic until the first evaluation
        self.dtau.x.array[:] = self.laws[0].two_mu_ksh
        self.dtau.x.array[self.qdofs] = self._elastic_shear

    def _point_expressions(self, kinematics, jit: dict) -> None:
        """Compiled values at the law's points: C in the yarn frame (the law's input), the
        deformed yarn directions and the reference coordinates (output)."""
        import ufl
        from dolfinx import fem
        F, C11, C22, C12 = kinematics.F, kinematics.C11, kinematics.C22, kinematics.C12
        G1, G2 = kinematics.G1, kinematics.G2
        self._yarn_C = fem.Expression(ufl.as_vector([C11, C22, C12]), self.points, jit_params=jit)
        self._directions = fem.Expression(ufl.as_vector([(F * G1)[i] for i in range(3)]
                                                        + [(F * G2)[i] for i in range(3)]),
                                          self.points, jit_params=jit)
        x_points = fem.Expression(ufl.SpatialCoordinate(self.mesh), self.points, jit_params=jit)
        self.point_coordinates = x_points.eval(self.cells).reshape(-1, 2)

    # --- the law at the quadrature points ------------------------------------------------------
    def law_state_functions(self) -> dict:
        """The quadrature functions that hold the law's committed state, by name (what a
        checkpoint saves and restores)."""
        return self.law_state

    def committed_state(self):
        from drape.law.nested_surface import LawState
        q = self.qdofs
        return LawState.from_columns({name: f.x.array[q] for name, f in self.law_state.items()},
                                     self.point_law.n)

    def evaluate(self) -> None:
        """Run the law at every local quadrature point for the current u, from the committed
        state; write tau and its tangent; evaluate the point contributions."""
        start = time.perf_counter()
        C = self._yarn_C.eval(self.cells).reshape(-1, 3)
        middle = time.perf_counter()
        committed = self.committed_state()
        response = self.point_law.update(committed, C[:, 0], C[:, 1], C[:, 2])
        end = time.perf_counter()
        # owned cells only: assembly visits owned cells, so ghost entries of quadrature
        # functions are never read (and are not kept up to date)
        self.tau.x.array[self.qdofs] = response.tau
        self.dtau.x.array[self.qdofs] = (
            neutral_loading_tangent(response.dtau_dC12, response.active_surface >= 0,
                                    response.trial.gamma_p - committed.gamma_p,
                                    self._elastic_shear, self.neutral_loading_band)
            if self.neutral_loading_band > 0.0 else response.dtau_dC12)
        self.response = response
        self._finite = all_finite(response.tau, response.dtau_dC12, response.trial.gamma_p,
                                   response.trial.centres)
        if not self._finite:
            self.nonfinite.add("law")
        self.timings["quadrature_values"] += middle - start + time.perf_counter() - end
        self.timings["law"] += end - middle
        self.counts["law"] += 1
        if self.point_terms.entries:
            start = time.perf_counter()
            nonfinite = self.point_terms.evaluate()
            if nonfinite:
                self._finite = False
                self.nonfinite |= nonfinite
            self.timings["contributions"] += time.perf_counter() - start
        self._evaluated_at = self.u.x.array.copy()

    def _ensure_evaluated(self) -> None:
        if self._evaluated_at is None or not np.array_equal(self._evaluated_at, self.u.x.array):
            self.evaluate()

    # --- SNES callbacks ------------------------------------------------------------------------
    def _take(self, x) -> None:
        from petsc4py import PETSc
        # x may be a line-search work vector; its ghosts are read by apply_lifting and set_bc
        x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        x.copy(self.u.vector)
        self.u.vector.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)

    def residual(self, snes, x, b) -> None:
        from dolfinx.fem import petsc as fpetsc
        from petsc4py import PETSc
        self._take(x)
        self.evaluate()
        start = time.perf_counter()
        with b.localForm() as local:
            local.set(0.0)
        fpetsc.assemble_vector(b, self.residual_form)
        fpetsc.apply_lifting(b, [self.jacobian_form], bcs=[self.bcs], x0=[x], scale=-1.0)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        fpetsc.set_bc(b, self.bcs, x, -1.0)
        if not self._finite:
            # a NaN/Inf in the law's (or a contribution's) output on this rank: poison the
            # residual, so that its norm -- and SNES's verdict -- is NaN on every rank
            b.array[:] = np.nan
        elif not np.isfinite(b.array).all():
            self.nonfinite.add("residual")
        self.timings["residual_assembly"] += time.perf_counter() - start
        self.counts["residual"] += 1

    def jacobian(self, snes, x, A, P) -> None:
        from dolfinx.fem import petsc as fpetsc
        self._take(x)
        self._ensure_evaluated()
        start = time.perf_counter()
        A.zeroEntries()
        fpetsc.assemble_matrix(A, self.jacobian_form, bcs=self.bcs)
        A.assemble()
        self.timings["jacobian_assembly"] += time.perf_counter() - start
        self.counts["jacobian"] += 1

    def create_vector(self):
        from dolfinx.fem import petsc as fpetsc
        return fpetsc.create_vector(self.residual_form)

    def create_matrix(self, mat_type: str | None = None):
        """A matrix for the Jacobian; ``mat_type`` a PETSc type ("baij": 3x3 blocks, one per
        node pair), None for DOLFINx's default (AIJ)."""
        from dolfinx.fem import petsc as fpetsc
        return fpetsc.create_matrix(self.jacobian_form, mat_type)

    # --- what a step's caller sets before Newton ------------------------------------------------
    def set_initial_guess(self, u_values) -> None:
        """Newton's starting displacement (this rank's unrolled dof values, ghosts included)."""
        self.u.x.array[:] = u_values

    def set_damping(self, constant: float) -> None:
        """The out-of-plane damping constant of this step (N/mm^3, 0: none)."""
        self.damping_constant.value = constant

    @property
    def inertial(self) -> bool:
        """Whether the problem has the inertial term (built with ``inertia=True``)."""
        return self.u_anchor is not None

    def set_inertia(self, k_m: float, anchor) -> None:
        """The inertial term of this step, k_m (u - anchor) per unit area: k_m in N/mm^3,
        ``anchor`` this rank's unrolled dof values of the motion carried on."""
        self.inertia_constant.value = k_m
        self.u_anchor.x.array[:] = anchor

    # --- steps ------------------------------------------------------------------------------------
    def commit(self, t: float | None = None) -> None:
        """Make the converged step (at load factor t) the committed state (law, displacement,
        contributions); the committed displacement becomes the previous one."""
        self._ensure_evaluated()
        q = self.qdofs
        for name, values in self.response.trial.columns().items():
            self.law_state[name].x.array[q] = values
        if t is not None:
            self.u_previous.x.array[:] = self.u_committed.x.array
            self.t_previous, self.t_committed = self.t_committed, float(t)
        self.u_committed.x.array[:] = self.u.x.array
        for contribution in self.contributions:
            contribution.commit()

    def restore(self) -> None:
        """Back to the committed displacement after a failed attempt (the law's state was never
        changed by the attempt)."""
        self.u.x.array[:] = self.u_committed.x.array
        self._evaluated_at = None

    # --- quantities for output --------------------------------------------------------------------
    def internal_force(self):
        """Assembled internal force vector (N), no boundary conditions, ghosts summed."""
        from dolfinx.fem import petsc as fpetsc
        from petsc4py import PETSc
        vector = fpetsc.assemble_vector(self.internal_form)
        vector.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        return vector

    def regularisation_work(self) -> float:
        """Work of the damping over the current step, 1/2 k int (u_z - u_z,last)^2 dA, plus
        that of the inertial force, 1/2 k_m int |u - u_anchor|^2 dA (N mm)."""
        from dolfinx import fem
        return self.comm.allreduce(fem.assemble_scalar(self.regularisation_work_form))

    def bending_energy(self) -> float:
        """The bending energy W_b of the current displacement (N mm; 0 without bending)."""
        from dolfinx import fem
        if self.bending_energy_form is None:
            return 0.0
        return self.comm.allreduce(fem.assemble_scalar(self.bending_energy_form))

    def cell_average(self, values: np.ndarray) -> np.ndarray:
        """Area-weighted average over each local cell of values at the law's points,
        (n_cells * nq, ...) -> (n_cells, ...)."""
        values = np.asarray(values, dtype=float).reshape(self.n_cells, self.nq, -1)
        averaged = np.einsum("cq,cqk->ck", self._average_weights, values)
        return averaged[:, 0] if averaged.shape[1] == 1 else averaged

    def yarn_strains(self) -> np.ndarray:
        """|yarn strain| (the larger of warp and weft, S_ii / (mu K_i)) at the law's points, as
        the residual sees it: in the strip cells whose yarn tension is integrated at the centre
        (:attr:`strip_reduced`), their cell's mean (the centre's value for a linear field), not
        the 2x2 points' values, which carry the hourglass shape the centre does not feel."""
        r, (mu_K1, mu_K2) = self.response, self._yarn_stiffness
        if r is None or not r.tau.size:
            return np.zeros(0)
        e1, e2 = r.S11 / mu_K1, r.S22 / mu_K2
        if self.strip_reduced:
            strip = self.blank_mesh.strip_cells
            strip = strip[strip < self.n_cells]
            e1, e2 = (np.asarray(e, dtype=float).reshape(self.n_cells, self.nq).copy()
                      for e in (e1, e2))
            for e in (e1, e2):
                e[strip] = self.cell_average(e.ravel())[strip][:, None]
            e1, e2 = e1.ravel(), e2.ravel()
        return np.maximum(np.abs(e1), np.abs(e2))

    def yarn_directions(self) -> tuple[np.ndarray, np.ndarray]:
        """Deformed warp and weft directions F G1, F G2 at the law's points, (P, 3) each."""
        values = self._directions.eval(self.cells).reshape(-1, 6)
        return values[:, :3], values[:, 3:]
