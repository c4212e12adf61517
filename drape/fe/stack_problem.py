"""The membrane problem of a stack of plies: MembraneProblem plus the ply-ply contact.

:class:`StackProblem` is a :class:`~drape.fe.membrane.MembraneProblem` on a
:class:`~drape.fe.stack_mesh.StackMesh` whose residual and Jacobian also hold the ply-ply
contact of :mod:`drape.forming.ply_contact`. The contact couples a node of one ply with the
nodes of a triangle of another: entries a form's sparsity pattern does not have. So
:meth:`StackProblem.create_matrix` preallocates the form's pattern plus the node blocks of the
pairs that can be pressed before the next search (every rank's, each rank its own rows), and
:meth:`StackProblem.jacobian` does so again after each load step's search: the direct solver's
factors grow with every coupling entry. The coupling is added after the form's assembly, with
global indices (PETSc sends the entries of rows another rank owns).

MPI: every residual gathers the owned displacements of all ranks into one global (N, 3) array
(:meth:`gather`), each rank evaluates the pairs of the slave nodes it owns, so every pair is
counted once whatever the partition, and 1 rank gives what 2 give (tests/test_ply_contact.py).
Rows and columns of Dirichlet dofs get no contact entries: their rows hold the boundary
condition, and (as DOLFINx's lifting does for the form) their columns' effect is dropped from
the Jacobian, which is exact once the iterate satisfies the conditions.

Every ply has its own yarn angle and law (MembraneProblem's per-ply ``yarn_angle_deg`` and
``law``): :func:`create_stack_problem` takes them from the stack's orientations and
``ply_laws``.
"""

from __future__ import annotations

import time

import numpy as np

from drape.fe.membrane import MembraneProblem
from drape.forming.layup import laid_heights
from drape.forming.ply_contact import DEFAULT_MARGIN, PlyContact
from drape.forming.ply_surfaces import StackNodes, split_cells


class StackProblem(MembraneProblem):
    """MembraneProblem on a stack with ply-ply contact (module docstring). ``law`` and
    ``yarn_angle_deg``: one for every ply or one per ply (as MembraneProblem); ``laws``: a
    :class:`~drape.forming.ply_pair.FrictionLaw` per interface; ``penalty`` ε_N (N/mm³),
    ``smoothing`` g0 (mm) and ``regularisation`` δ (mm) as the tools' contact."""

    def __init__(self, stack_mesh, law, yarn_angle_deg, damping: float, laws,
                 penalty: float, smoothing: float, regularisation: float,
                 margin: float = DEFAULT_MARGIN, **options):
        super().__init__(stack_mesh, law, yarn_angle_deg, damping, **options)
        self.timings.update(ply_search=0.0, ply_forces=0.0, ply_assembly=0.0)
        index_map = self.V.dofmap.index_map
        self.n_owned = index_map.size_local
        n_local = self.n_owned + index_map.num_ghosts
        self.global_nodes = np.asarray(index_map.local_to_global(
            np.arange(n_local, dtype=np.int32)), dtype=np.int64)
        self.n_global = index_map.size_global
        self.first = index_map.local_range[0]
        nodes = self._stack_nodes(stack_mesh)
        owned = np.zeros(self.n_global, dtype=bool)
        owned[self.global_nodes[: self.n_owned]] = True
        self.ply_contact = PlyContact(nodes, stack_mesh.thicknesses, laws, penalty, smoothing,
                                      regularisation, owned=owned, margin=margin)
        self._pattern_version, self._form_entries = 0, None
        self.begin_step()
        self._forces_at = None
        self._constrained_for = None
        self._layout_of = self._layout = None

    # --- the stack's nodes, gathered ------------------------------------------------------------
    def _stack_nodes(self, stack_mesh) -> StackNodes:
        import ufl
        from dolfinx import fem
        from dolfinx.fem import petsc as fpetsc
        from petsc4py import PETSc

        V, n_owned = self.V, self.n_owned
        cell_ply = stack_mesh.cell_plies()
        nv = V.dofmap.dof_layout.num_dofs
        cells = V.dofmap.list.array.reshape(-1, nv)
        node_ply = np.full(len(self.global_nodes), -1, dtype=np.int32)
        node_ply[cells.ravel()] = np.repeat(cell_ply[: len(cells)], nv)
        xy = V.tabulate_dof_coordinates()[:, :2]
        # lumped nodal areas: the integral of each shape function over the reference
        v = ufl.TestFunction(V)
        area = fpetsc.assemble_vector(fem.form(v[0] * ufl.dx(domain=self.mesh)))
        area.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        areas = area.array.reshape(-1, 3)[:n_owned, 0].copy()
        area.destroy()
        n_cells = self.n_cells
        mine = (self.global_nodes[:n_owned], xy[:n_owned], node_ply[:n_owned], areas,
                self.global_nodes[cells[:n_cells]], cell_ply[:n_cells])
        parts = self.comm.allgather(mine)
        reference = np.zeros((self.n_global, 3))
        ply = np.zeros(self.n_global, dtype=np.int32)
        nodal_area = np.zeros(self.n_global)
        for ids, part_xy, part_ply, part_area, _, _ in parts:
            reference[ids, :2], ply[ids], nodal_area[ids] = part_xy, part_ply, part_area
        all_cells = np.vstack([p[4] for p in parts])
        all_cell_ply = np.concatenate([p[5] for p in parts])
        triangles, origin = split_cells(all_cells, reference[:, :2])
        # each ply on the plies under it, or on the die past a partial ply's edge
        reference[:, 2], _ = laid_heights(reference[:, :2], triangles, all_cell_ply[origin],
                                          stack_mesh.thicknesses, reference[:, :2], ply)
        self._node_order = np.concatenate([p[0] for p in parts])
        return StackNodes(reference, ply, nodal_area, triangles, all_cell_ply[origin])

    def gather(self, function) -> np.ndarray:
        """A vector function's nodal values on all ranks, (N, 3) in global node numbers."""
        owned = function.x.array.reshape(-1, 3)[: self.n_owned]
        out = np.empty((self.n_global, 3))
        out[self._node_order] = np.vstack(self.comm.allgather(owned))
        return out

    # --- steps ----------------------------------------------------------------------------------
    def begin_step(self) -> None:
        """Search the candidate pairs at the current displacement (once per load step)."""
        start = time.perf_counter()
        self.ply_contact.search(self.gather(self.u))
        # the Jacobian's pattern follows this search (jacobian, _preallocate)
        self._pattern_version += 1
        self.timings["ply_search"] += time.perf_counter() - start

    def commit(self, t: float | None = None) -> None:
        super().commit(t)
        self._ensure_forces()
        self.ply_contact.commit()
        self.begin_step()

    def restore(self) -> None:
        """Back to the committed step after a failed attempt: the next attempt pairs the
        slave nodes afresh, as this one did."""
        super().restore()
        self.ply_contact.reset_pairing()
        self._forces_at = None

    def _ensure_forces(self):
        from mpi4py import MPI
        changed = self._forces_at is None or not np.array_equal(self._forces_at, self.u.x.array)
        # collective: the gather below must run on every rank, also where u did not change
        if self.comm.allreduce(changed, op=MPI.LOR):
            start = time.perf_counter()
            searches = self.ply_contact.counts["searches"]
            self.forces = self.ply_contact.evaluate(self.gather(self.u),
                                                    self.gather(self.u_committed))
            if self.ply_contact.counts["searches"] != searches:
                self.counts["ply_research"] = self.counts.get("ply_research", 0) + 1
            self._forces_at = self.u.x.array.copy()
            self.timings["ply_forces"] += time.perf_counter() - start
        return self.forces

    def _constrained(self) -> np.ndarray:
        """Global mask of the Dirichlet dofs (N * 3,), the same on every rank."""
        key = tuple(id(bc) for bc in self.bcs)
        if self._constrained_for != key:
            local = [bc.dof_indices()[0] for bc in self.bcs]
            local = np.concatenate(local) if local else np.zeros(0, dtype=np.int32)
            local = local[local < 3 * self.n_owned]
            dofs = 3 * self.global_nodes[local // 3] + local % 3
            mask = np.zeros(3 * self.n_global, dtype=bool)
            mask[np.concatenate(self.comm.allgather(dofs)).astype(np.int64)] = True
            self._mask, self._constrained_for = mask, key
        return self._mask

    # --- SNES callbacks -------------------------------------------------------------------------
    def residual(self, snes, x, b) -> None:
        from petsc4py import PETSc
        super().residual(snes, x, b)
        forces = self._ensure_forces()
        start = time.perf_counter()
        if not np.isfinite(forces.force).all():
            self.nonfinite.add("ply contact")
            b.array[:] = np.nan
            return
        rows = (3 * forces.nodes[:, :, None] + np.arange(3)).ravel()
        values = -forces.force.ravel()
        keep = ~self._constrained()[rows]
        b.setValues(rows[keep].astype(PETSc.IntType), values[keep], addv=PETSc.InsertMode.ADD)
        b.assemblyBegin()
        b.assemblyEnd()
        self.timings["ply_assembly"] += time.perf_counter() - start

    def jacobian(self, snes, x, A, P) -> None:
        from petsc4py import PETSc
        if A.getAttr("drape_pattern") != self._pattern_version:
            self._remake_pattern(snes, A)
        super().jacobian(snes, x, A, P)
        if snes is not None:
            self._repair(snes, x)
        forces = self._ensure_forces()
        start = time.perf_counter()
        constrained = self._constrained()
        nodes = forces.nodes
        free = ~constrained[3 * nodes[:, :, None] + np.arange(3)]              # (P, 4, 3)
        # the (P, 4, 4) node blocks of 3 x 3, each pair's rows in turn
        blocks = -(forces.jacobian * free[:, :, :, None, None] * free[:, None, None, :, :])
        blocks = np.ascontiguousarray(blocks.transpose(0, 1, 3, 2, 4)).reshape(-1, 9)
        # the pairs share node blocks (a master triangle's nodes serve many slaves): summed
        # here, each block goes to PETSc once, in CSR order (its insertion was the cost)
        if len(nodes):
            rows, starts, columns, order, segments = self._coupling_layout(nodes)
            summed = np.add.reduceat(blocks[order], segments, axis=0)
            A.setValuesBlockedIJV(starts, columns, summed.ravel(), addv=PETSc.InsertMode.ADD,
                                  rowmap=rows)
        A.assemble()
        self.timings["ply_assembly"] += time.perf_counter() - start

    def _coupling_layout(self, nodes):
        """For the pairs' nodes (P, 4): the distinct node blocks (row, column) of their 16 P
        blocks as CSR (block rows, row starts, columns), the order that groups each distinct
        block's copies and where each group starts; kept while the pairs stay the same."""
        from petsc4py import PETSc
        if self._layout_of is not None and np.array_equal(self._layout_of, nodes):
            return self._layout
        nodes = np.asarray(nodes, dtype=np.int64)
        keys = (nodes[:, :, None] * self.n_global + nodes[:, None, :]).ravel()
        order = np.argsort(keys, kind="stable")
        keys = keys[order]
        segments = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
        block_rows, columns = np.divmod(keys[segments], self.n_global)
        first = np.flatnonzero(np.r_[True, block_rows[1:] != block_rows[:-1]])
        int_type = PETSc.IntType
        self._layout = (block_rows[first].astype(int_type),
                        np.r_[first, len(block_rows)].astype(int_type),
                        columns.astype(int_type), order, segments)
        self._layout_of = nodes.copy()
        return self._layout

    def _repair(self, snes, x) -> None:
        """A new Newton iteration: slave nodes that left their triangles are paired again
        (PlyContact.repair; collective) and the residual SNES holds for this iterate is made
        again with the new pairs, so that Newton's step solves for it; kept only if its norm
        is no larger than the one SNES's line search will compare with (it cannot be told a
        new one), else the pairs stay as they were."""
        from mpi4py import MPI
        if not self.comm.allreduce(self.ply_contact.repair(self.gather(self.u)), op=MPI.LOR):
            return
        residual = snes.getFunction()[0]
        if not residual.handle:     # a SNES without a residual (a bare solve): pairs as found
            return
        self._forces_at = None
        self.residual(snes, x, residual)
        if residual.norm() > snes.getFunctionNorm():
            self.ply_contact.undo_repair()
            self._forces_at = None
            self.residual(snes, x, residual)

    def create_matrix(self, mat_type: str | None = None):
        """The form's matrix (DOLFINx's layout and local-to-global map) with its sparsity
        pattern enlarged by the coupling of the pairs that can be pressed before the next
        search (module docstring); made again at the first Jacobian after a load step's
        search. Pairs a search within the step finds outside it are still accepted (PETSc
        allocates them).

        On more than one rank a stack's matrix is AIJ, whatever ``mat_type``: with BAIJ, a
        stack with a partial ply aborted in MUMPS's factorisation at random on 2 ranks
        ("free(): invalid pointer" in dmumps_fac_driver_, 3 runs in 49 and once in the test
        suite), with AIJ in none of 44 (docs/notes.md); the cause is not known."""
        if self.comm.size > 1 and mat_type == "baij":
            mat_type = None
        A = super().create_matrix(mat_type)
        self._preallocate(A)
        return A

    def _remake_pattern(self, snes, A) -> None:
        """The pattern of the last search for A, the first Jacobian after it (collective). A
        factorisation would keep its analysis of the old pattern (PETSc's preallocation does
        not mark the pattern as changed): its KSP is reset, to analyse the new one. Other
        preconditioners (the field split keeps its index sets) keep the old pattern, which
        PETSc's allocations enlarge where a pair falls outside it."""
        if snes is not None:
            ksp = snes.getKSP()
            if ksp.getPC().getType() not in ("lu", "cholesky"):
                A.setAttr("drape_pattern", self._pattern_version)
                return
            ksp.reset()
        self._preallocate(A)

    def _preallocate(self, A) -> None:
        """Give A the pattern of the form and of the pairs of the last load step's search,
        zeros at every entry (collective)."""
        from petsc4py import PETSc
        rows, columns = self._coupled_entries()
        keys = np.unique(rows * self.n_global + columns)
        rows, columns = np.divmod(keys, self.n_global)
        counts = np.bincount(rows - self.first, minlength=self.n_owned)
        if "baij" in A.getType():
            starts = np.r_[0, np.cumsum(counts)]
        else:
            # AIJ: every block entry as its 3 x 3 scalars, row by row
            counts = np.repeat(3 * counts, 3)
            starts = np.r_[0, np.cumsum(counts)]
            per_row = np.split(columns, np.cumsum(counts[::3] // 3)[:-1])
            columns = np.concatenate([np.tile((3 * c[:, None] + np.arange(3)).ravel(), 3)
                                      for c in per_row]) if len(per_row) else columns
        A.setPreallocationCSR((starts.astype(PETSc.IntType), columns.astype(PETSc.IntType)))
        A.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, False)
        A.setAttr("drape_pattern", self._pattern_version)

    def _coupled_entries(self):
        """The global (block) rows and columns of the Jacobian's entries in the rows this rank
        owns: the form's, then the 4 x 4 node blocks of every rank's pairs that can be
        pressed (:meth:`~drape.forming.ply_contact.PlyContact.coupled_nodes`)."""
        if self._form_entries is None:
            from dolfinx import fem
            form_pattern = fem.create_sparsity_pattern(self.jacobian_form)
            form_pattern.assemble()
            graph = form_pattern.graph
            # the owned rows (the graph may list the ghost rows after them, empty)
            offsets = np.asarray(graph.offsets)[: self.n_owned + 1]
            rows = np.repeat(np.arange(self.n_owned, dtype=np.int64), np.diff(offsets))
            columns = np.asarray(form_pattern.column_index_map().local_to_global(
                np.asarray(graph.array[: offsets[-1]], dtype=np.int32)), dtype=np.int64)
            self._form_entries = (self.first + rows, columns)
        rows, columns = self._form_entries
        pairs = [p for p in self.ply_contact.coupled_nodes() if len(p)]
        pairs = np.vstack(pairs) if pairs else np.zeros((0, 4), dtype=np.int64)
        pairs = np.vstack(self.comm.allgather(pairs)).astype(np.int64)
        pair_rows = np.repeat(pairs, 4, axis=1).ravel()
        pair_columns = np.tile(pairs, (1, 4)).ravel()
        mine = (pair_rows >= self.first) & (pair_rows < self.first + self.n_owned)
        return (np.concatenate([rows, pair_rows[mine]]),
                np.concatenate([columns, pair_columns[mine]]))


def create_stack_problem(comm, stack, mesh_config, contact, law, damping: float,
                         centred: bool = True, ply_laws=None, **options) -> StackProblem:
    """The StackProblem of a :class:`~drape.forming.plies.StackConfig`: its plies meshed with
    ``mesh_config`` (``[mesh]``), each with its orientation and its law (``ply_laws``, one
    per ply, e.g. of :func:`~drape.forming.plies.ply_materials`; None: ``law`` for every
    ply), one :class:`FrictionLaw` per interface, and the penalty, smoothing and stick zone of
    ``contact`` (``[contact]``, a ContactParameters) by the tools' rule with the stiffest
    ply's yarns: ε_N = c max_k mu K_max,k / h², g0 = 0.05 h (h = mesh.size), so that plies
    press on each other as the fabric presses on the tools. ``options`` go to
    MembraneProblem."""
    from drape.fe.stack_mesh import create_stack_mesh
    from drape.forming.ply_pair import FrictionLaw
    laws = [law] * len(stack.plies) if ply_laws is None else list(ply_laws)
    if len(laws) != len(stack.plies):
        raise ValueError(f"{len(laws)} ply laws for {len(stack.plies)} plies")
    stiffest = max(p.mu * max(p.K1, p.K2) for p in (law.params for law in laws))
    h = mesh_config.size
    mesh = create_stack_mesh(comm, [ply.blank() for ply in stack.plies], stack.heights(),
                             [ply.thickness for ply in stack.plies], mesh_config, centred)
    return StackProblem(mesh, laws, [ply.orientation for ply in stack.plies], damping,
                        [FrictionLaw.of(interface) for interface in stack.interface_list()],
                        penalty=contact.penalty_for(stiffest, h),
                        smoothing=contact.smoothing_for(h),
                        regularisation=contact.slip_regularisation, **options)
