"""A preconditioner that factors the membrane and the bending hinges apart, in the local
tangent frame (``solver.linear = "tangent_split"``).

At every node the three displacement dofs are rotated into (t1, t2, n), n the current unit
normal of the deformed blank there (the area-weighted mean of the adjacent cells' normals,
from the displacement the Jacobian was assembled at), t1, t2 any orthonormal pair in its
tangent plane: A' = R^T A R with R block-diagonal (one 3x3 rotation per node). A' splits
into the tangential block (2 dofs per node: the membrane's stretch and shear, which the
bending hinges barely touch) and the normal block (1 dof per node: the hinges, the contact's
normal stiffness and the membrane's geometric stiffness). The hinges' interior-facet form
couples every node with its neighbours' neighbours; in the tangential block those couplings
are dropped (only the entries between nodes of a common cell are kept), so that it factors
with the membrane's own stencil, while the normal block keeps them: a scalar problem, cheap
to factor even with the wide stencil. Each block is factored by MUMPS, and the preconditioner
is one block Gauss-Seidel sweep (tangential, then normal with the tangential correction)
inside an outer GMRES on the true Jacobian, so that the answer is Newton's own to the
KSP's tolerance.

Why: at 10 000 cells MUMPS spends 7.44 GFlop on the whole Jacobian against 1.12 GFlop for the
membrane alone (docs/speed.md); an x-y / z split does not work once the wall of a formed part
turns vertical, a split in the tangent frame follows it.
"""

from __future__ import annotations

import numpy as np


def tangent_frames(normals: np.ndarray) -> np.ndarray:
    """Per node a rotation Q (n, 3, 3) whose columns are (t1, t2, n): ``normals`` (n, 3), any
    length > 0. t1 is the coordinate axis least aligned with n, made orthogonal to it."""
    n = normals / np.linalg.norm(normals, axis=1)[:, None]
    axis = np.zeros_like(n)
    axis[np.arange(len(n)), np.argmin(np.abs(n), axis=1)] = 1.0
    t1 = axis - np.sum(axis * n, axis=1)[:, None] * n
    t1 /= np.linalg.norm(t1, axis=1)[:, None]
    t2 = np.cross(n, t1)
    return np.stack([t1, t2, n], axis=2)


class TangentSplitPC:
    """A petsc4py Python PC (``pc.setPythonContext``) over a MembraneProblem's Jacobian (AIJ).

    ``stats`` counts the set-ups, applications and, after each set-up, the two factors' sizes
    (MUMPS INFOG(20)) and operations (RINFOG(3)), for benchmarks and tests."""

    def __init__(self, problem, prefix: str = "drape_tangent_", drop_hinges: bool = True):
        import ufl
        from dolfinx import fem
        from petsc4py import PETSc

        self.problem = problem
        self.prefix = prefix
        V, u = problem.V, problem.u
        v = ufl.TestFunction(V)
        I32 = ufl.as_matrix([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])
        F = I32 + ufl.grad(u)
        # the unnormalised normal F e1 x F e2 integrated against the hat functions: per node
        # the area-weighted mean normal of the adjacent cells (its length does not matter)
        self.normal_form = fem.form(ufl.inner(ufl.cross(F[:, 0], F[:, 1]), v) * ufl.dx)
        self.normal_vector = fem.petsc.create_vector(self.normal_form)
        index_map, bs = V.dofmap.index_map, V.dofmap.index_map_bs
        assert bs == 3, "the tangent split needs a 3-component displacement"
        self.n_local = index_map.size_local
        self.first = index_map.local_range[0]
        self.n_global = index_map.size_global
        comm = problem.comm
        nodes = self.first + np.arange(self.n_local, dtype=np.int32)
        tangential = np.column_stack([3 * nodes, 3 * nodes + 1]).ravel().astype(np.int32)
        self.is_t = PETSc.IS().createGeneral(tangential, comm=comm)
        self.is_n = PETSc.IS().createGeneral((3 * nodes + 2).astype(np.int32), comm=comm)
        self._membrane_pairs = self._cell_neighbours(V)
        self.drop_hinges = drop_hinges
        self.R = self.A_aij = self.rotated = self.whole_t = self.block_t = None
        self.block_n = self.coupling_nt = self.coupling_tn = self.work_x = None
        self.sweep = __import__("os").environ.get("DRAPE_TS_SWEEP", "tn")
        self.ksp_t = self.ksp_n = None
        self.stats = {"setups": 0, "applications": 0, "factor_entries": {}, "gflop": {},
                      "seconds": {}}

    # --- set-up ---------------------------------------------------------------------------------
    def _cell_neighbours(self, V) -> np.ndarray:
        """Sorted keys i * N + j of the (owned row node i, any node j) pairs that share a cell:
        the sparsity of a mass matrix, which DOLFINx builds right across the ranks."""
        import ufl
        from dolfinx import fem
        from dolfinx.fem import petsc as fpetsc
        s = ufl.TrialFunction(V)
        mass = fpetsc.assemble_matrix(fem.form(ufl.inner(s, ufl.TestFunction(V)) * ufl.dx))
        mass.assemble()
        indptr, columns, _ = mass.getValuesCSR()
        mass.destroy()
        rows = self.first * 3 + np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
        keys = (rows // 3).astype(np.int64) * self.n_global + columns // 3
        return np.unique(keys)

    def _rotation(self, A):
        """R (AIJ, the layout of A): per owned node the 3x3 frame of the current normal."""
        from dolfinx.fem import petsc as fpetsc
        from petsc4py import PETSc
        b = self.normal_vector
        with b.localForm() as local:
            local.set(0.0)
        fpetsc.assemble_vector(b, self.normal_form)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        normals = b.array[: 3 * self.n_local].reshape(-1, 3)
        frames = tangent_frames(normals)
        n3 = 3 * self.n_local
        indptr = np.arange(0, 3 * n3 + 1, 3, dtype=np.int32)
        rows_node = np.arange(self.n_local).repeat(3)
        columns = (3 * (self.first + rows_node)[:, None] + np.arange(3)).astype(np.int32)
        values = frames.reshape(-1, 3)        # row 3k + a: Q_k[a, :]
        if self.R is None:
            R = PETSc.Mat().createAIJ(A.getSizes(), csr=(indptr, columns.ravel(),
                                                        values.ravel()), comm=A.getComm())
            R.assemble()
            self.R = R
        else:
            self.R.setValuesCSR(indptr, columns.ravel(), values.ravel())
            self.R.assemble()
        return self.R

    def _membrane_block(self, T):
        """The tangential block with only the entries between nodes of a common cell (the
        pattern is found once; later calls copy the values into the same matrix)."""
        from petsc4py import PETSc
        indptr, columns, values = T.getValuesCSR()
        if self.block_t is None:
            start = T.getOwnershipRange()[0]
            rows = start + np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
            keys = (rows // 2).astype(np.int64) * self.n_global + columns // 2
            self._keep = keep = np.isin(keys, self._membrane_pairs)
            counts = np.diff(np.concatenate([[0], np.cumsum(keep)])[indptr])
            self._kept_indptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
            self._kept_columns = columns[keep].astype(np.int32)
            self.block_t = PETSc.Mat().createAIJ(
                T.getSizes(), csr=(self._kept_indptr, self._kept_columns, values[keep]),
                comm=T.getComm())
        else:
            self.block_t.setValuesCSR(self._kept_indptr, self._kept_columns, values[self._keep])
        self.block_t.assemble()
        return self.block_t

    def _factor(self, name: str, matrix, old):
        from petsc4py import PETSc
        ksp = old or PETSc.KSP().create(matrix.getComm())
        if old is None:
            ksp.setOptionsPrefix(f"{self.prefix}{name}_")
            ksp.setType("preonly")
            pc = ksp.getPC()
            pc.setType("lu")
            pc.setFactorSolverType("mumps")
            ksp.setFromOptions()
            ksp.setOperators(matrix)
        ksp.getPC().setUp()                                  # factors now, not in the first solve
        factor = ksp.getPC().getFactorMatrix()
        self.stats["factor_entries"][name] = factor.getMumpsInfog(20)
        self.stats["gflop"][name] = factor.getMumpsRinfog(3) / 1e9
        return ksp

    def _time(self, phase: str, started: float) -> float:
        import time
        now = time.perf_counter()
        self.stats["seconds"][phase] = self.stats["seconds"].get(phase, 0.0) + now - started
        return now

    def setUp(self, pc) -> None:
        import time

        from petsc4py import PETSc
        A, _ = pc.getOperators()
        clock = time.perf_counter()
        R = self._rotation(A)
        clock = self._time("rotation", clock)
        if A.getType().endswith("baij"):                    # PtAP needs AIJ
            # (an empty Mat: convert(out=None) would convert the Jacobian itself in place)
            self.A_aij = A.convert("aij", self.A_aij or PETSc.Mat())
            A = self.A_aij
        clock = self._time("convert", clock)
        self.rotated = A.PtAP(R, self.rotated)               # R^T A R
        clock = self._time("ptap", clock)
        T = self.rotated.createSubMatrix(self.is_t, self.is_t, self.whole_t)
        self.whole_t = T
        if self.drop_hinges:
            self._membrane_block(T)
        else:
            self.block_t = T
        self.block_n = self.rotated.createSubMatrix(self.is_n, self.is_n, self.block_n)
        self.coupling_nt = self.rotated.createSubMatrix(self.is_n, self.is_t, self.coupling_nt)
        self.coupling_tn = self.rotated.createSubMatrix(self.is_t, self.is_n, self.coupling_tn)
        normal = self.block_n
        import os
        if os.environ.get("DRAPE_TS_SCHUR"):
            normal = self._schur_estimate()
        if self.sweep.startswith("m"):
            self._coupled_block()
            self.ksp_m = self._factor("m", self.block_m, getattr(self, "ksp_m", None))
        clock = self._time("blocks", clock)
        if not self.sweep.startswith("m"):
            self.ksp_t = self._factor("t", self.block_t, self.ksp_t)
        self.ksp_n = self._factor("n", normal, self.ksp_n)
        clock = self._time("factor", clock)
        if self.work_x is None:
            self.work_x = R.createVecRight()
            self.work_y = R.createVecRight()
            self.work_n = self.block_n.createVecLeft()
        self.stats["setups"] += 1

    def _coupled_block(self):
        """The rotated Jacobian with only the entries between nodes of a common cell."""
        from petsc4py import PETSc
        indptr, columns, values = self.rotated.getValuesCSR()
        if getattr(self, "block_m", None) is None:
            start = self.rotated.getOwnershipRange()[0]
            rows = start + np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
            keys = (rows // 3).astype(np.int64) * self.n_global + columns // 3
            self._keep_m = keep = np.isin(keys, self._membrane_pairs)
            counts = np.diff(np.concatenate([[0], np.cumsum(keep)])[indptr])
            self._m_indptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
            self._m_columns = columns[keep].astype(np.int32)
            self.block_m = PETSc.Mat().createAIJ(
                self.rotated.getSizes(), csr=(self._m_indptr, self._m_columns, values[keep]),
                comm=self.rotated.getComm())
        else:
            self.block_m.setValuesCSR(self._m_indptr, self._m_columns, values[self._keep_m])
        self.block_m.assemble()

    def _schur_estimate(self):
        """A_nn - C_nt D^-1 C_tn, D the 2x2 diagonal blocks of the tangential block, C the
        couplings kept to the membrane stencil (an experiment)."""
        from petsc4py import PETSc
        indptr, columns, values = self.block_t.getValuesCSR()
        start = self.block_t.getOwnershipRange()[0]
        rows = start + np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
        same = rows // 2 == columns // 2
        blocks = np.zeros((len(indptr) - 1) // 2 * 4)
        local = (rows[same] - start)
        blocks[(local // 2) * 4 + (local % 2) * 2 + columns[same] % 2] = values[same]
        inverse = np.linalg.inv(blocks.reshape(-1, 2, 2))
        n = len(inverse)
        first = start // 2
        dip = np.arange(0, 4 * n + 1, 2, dtype=np.int32)
        dcols = (2 * (first + np.arange(n)))[:, None, None] + np.array([[0, 1], [0, 1]])
        D = PETSc.Mat().createAIJ(self.block_t.getSizes(), csr=(
            dip, dcols.ravel().astype(np.int32), inverse.ravel()), comm=self.block_t.getComm())
        D.assemble()

        def restricted(M, row_bs, col_bs):
            ip, cols, vals = M.getValuesCSR()
            r0 = M.getOwnershipRange()[0]
            rws = r0 + np.repeat(np.arange(len(ip) - 1), np.diff(ip))
            keys = (rws // row_bs).astype(np.int64) * self.n_global + cols // col_bs
            keep = np.isin(keys, self._membrane_pairs)
            counts = np.diff(np.concatenate([[0], np.cumsum(keep)])[ip])
            nip = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
            out = PETSc.Mat().createAIJ(M.getSizes(), csr=(nip, cols[keep].astype(np.int32),
                                                           vals[keep]), comm=M.getComm())
            out.assemble()
            return out
        C_nt = restricted(self.coupling_nt, 1, 2)
        C_tn = restricted(self.coupling_tn, 2, 1)
        product = C_nt.matMult(D).matMult(C_tn)
        S = self.block_n.duplicate(copy=True)
        S.axpy(-1.0, product, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
        for M in (D, C_nt, C_tn, product):
            M.destroy()
        if getattr(self, "_schur", None) is not None:
            self._schur.destroy()
        self._schur = S
        if self.ksp_n is not None:
            self.ksp_n.setOperators(S)
        return S

    # --- application
    def _apply_coupled(self):
        """work_y = one sweep: the membrane-stencil LU, then the normal block on the rest."""
        r, y = self.work_x, self.work_y
        if getattr(self, "work_r", None) is None:
            self.work_r = r.duplicate()
        s = self.work_r
        self.ksp_m.solve(r, y)
        self.rotated.mult(y, s)
        s.aypx(-1.0, r)                                        # r - A' y
        sn = s.getSubVector(self.is_n)
        yn = y.getSubVector(self.is_n)
        dn = sn.duplicate()
        self.ksp_n.solve(sn, dn)
        yn.axpy(1.0, dn)
        s.restoreSubVector(self.is_n, sn)
        y.restoreSubVector(self.is_n, yn)
        if self.sweep == "mnm":
            self.rotated.mult(y, s)
            s.aypx(-1.0, r)
            d = s.duplicate()
            self.ksp_m.solve(s, d)
            y.axpy(1.0, d)
    def apply(self, pc, x, y) -> None:
        """y = R M^-1 R^T x, M^-1 one block Gauss-Seidel sweep (tangential, then normal)."""
        import time
        clock = time.perf_counter()
        self.R.multTranspose(x, self.work_x)
        if self.sweep.startswith("m"):
            self._apply_coupled()
            self.R.mult(self.work_y, y)
            self.stats["applications"] += 1
            self._time("apply", clock)
            return
        rt = self.work_x.getSubVector(self.is_t)
        rn = self.work_x.getSubVector(self.is_n)
        yt = self.work_y.getSubVector(self.is_t)
        yn = self.work_y.getSubVector(self.is_n)
        self.ksp_t.solve(rt, yt)
        self.coupling_nt.mult(yt, self.work_n)
        self.work_n.aypx(-1.0, rn)                            # rn - A_nt yt
        self.ksp_n.solve(self.work_n, yn)
        if self.sweep == "tnt":
            wt = rt.duplicate()
            self.coupling_tn.mult(yn, wt)
            wt.aypx(-1.0, rt)
            self.ksp_t.solve(wt, yt)
        self.work_x.restoreSubVector(self.is_t, rt)
        self.work_x.restoreSubVector(self.is_n, rn)
        self.work_y.restoreSubVector(self.is_t, yt)
        self.work_y.restoreSubVector(self.is_n, yn)
        self.R.mult(self.work_y, y)
        self.stats["applications"] += 1
        self._time("apply", clock)
