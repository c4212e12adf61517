"""Partition-independent numbers of a mesh's nodes and cells, under which a checkpoint
(:mod:`drape.io.checkpoint`) stores every value: gathered from any number of ranks and any
partition, and found again by number on resume (issue 30: PT-Scotch's partitions differ from
run to run).
"""

from __future__ import annotations

import numpy as np


class Layout:
    """Global numbers of this rank's nodes and cells that do not depend on the partition: a
    node's index in gmsh's mesh (the geometry's input index) and a cell's (DOLFINx's original
    cell index). A checkpoint stores every value under them, so that a resume restores each
    node and quadrature point from the checkpoint's entry of the same number whatever rank
    holds it, and compares coordinates (to 1e-8 of the blank's size) to tell another mesh."""

    def __init__(self, problem):
        msh, V = problem.mesh, problem.V
        index_map = V.dofmap.index_map
        self.n_owned_nodes = index_map.size_local
        inputs = np.asarray(msh.geometry.input_global_indices, dtype=np.int64)
        self.node_key = np.empty(index_map.size_local + index_map.num_ghosts, dtype=np.int64)
        # P1 dofs and geometry nodes share the cells' vertex order
        self.node_key[V.dofmap.list.array] = inputs[msh.geometry.dofmap.array]
        self.cell_key = np.asarray(msh.topology.original_cell_index, dtype=np.int64)
        self.n_cells = problem.n_cells

    def _cell_index(self, function) -> np.ndarray:
        """Indices into ``function.x.array`` of each owned cell's values, (cells, values)."""
        dofmap = function.function_space.dofmap
        bs = dofmap.index_map_bs
        dofs = dofmap.list.array.reshape(len(self.cell_key), -1)[: self.n_cells]
        return (dofs[:, :, None] * bs + np.arange(bs)).reshape(self.n_cells, -1)

    def cell_rows(self, function) -> np.ndarray:
        return function.x.array[self._cell_index(function)]

    def set_cell_rows(self, function, rows) -> None:
        """Owned cells only: the law's ghost entries are never read or written (membrane.py)."""
        function.x.array[self._cell_index(function)] = rows


def merge_ranks(parts) -> dict[str, np.ndarray]:
    """Rank 0: every rank's :meth:`Checkpoints._local_state` as one array per name and family,
    rows sorted by key ("<family>.key", "<family>.<name>"); "global.<name>" from rank 0."""
    arrays = {f"global.{k}": v for k, v in parts[0]["global"].items()}
    for family in ("nodes", "cells", "prescribed"):
        keys = np.concatenate([part[family][0] for part in parts])
        order = np.argsort(keys, kind="stable")
        arrays[f"{family}.key"] = keys[order]
        for name in parts[0][family][1]:
            rows = [np.asarray(part[family][1][name]) for part in parts]
            width = max([r.size // len(r) for r in rows if len(r)] or [1])
            arrays[f"{family}.{name}"] = np.concatenate([r.reshape(len(r), width)
                                                         for r in rows])[order]
    return arrays


def pick_rows(saved, family, keys):
    """{name: the rows of ``keys``} from a checkpoint's family, and how many keys it lacks."""
    stored = saved.get(f"{family}.key")
    if stored is None:
        return None, len(keys)
    index = np.searchsorted(stored, keys)
    index = np.minimum(index, max(len(stored) - 1, 0))
    found = (stored[index] == keys) if len(stored) else np.zeros(len(keys), bool)
    index = np.where(found, index, 0)
    prefix = f"{family}."
    rows = {k[len(prefix):]: (v[index] if len(v) else v[:0]) for k, v in saved.items()
            if k.startswith(prefix) and k != f"{family}.key"}
    return rows, int((~found).sum())


def coordinate_tolerance(x) -> float:
    return 1e-8 * max(1.0, float(np.abs(x).max())) if x.size else 0.0
