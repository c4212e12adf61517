"""Checkpoints of a run and resuming from one (``drape run CONFIG --resume``).

``checkpoint.npz`` in the results folder holds the last checkpointed converged step: every
quadrature state (the law's, :meth:`~drape.fe.membrane.MembraneProblem.law_state_functions`, and
any point contribution's :meth:`~drape.fe.membrane.PointContribution.state`: arrays of one row per
point of the rank are matched to their points, other arrays are the same on every rank), the
committed and the previous displacement, the ledgers of
external and regularisation work (with the prescribed forces and displacements their next
increment starts from), the step number, load factor t, the step size the loop proposes next,
the rows written so far, and the effective config and material it was made with.

The values are gathered to rank 0 into one file, each node's and cell's under a number that
does not depend on the partition (:class:`Layout`: gmsh's node index, DOLFINx's original cell
index); a resume finds its nodes and cells there by number and checks their coordinates (to
1e-8 of the blank's size): another mesh is an :class:`~drape.errors.InputError`, another
partition is not. The number of ranks must be the same (the resumed run then gets the same
partition, drape.fe.mesh, and continues with the same numbers). The file is written to a temporary
name and renamed, so a kill or a full disk while writing leaves the previous checkpoint intact.

Resuming rewinds the folder to the checkpoint (:func:`rewind_outputs`): ``steps.csv`` is
rewritten from the checkpoint's rows, the XDMF time series (from its copy ``checkpoint.xdmf``,
taken with the checkpoint) loses the grids after its t, and its HDF5 file (from its copy
``checkpoint.h5``: a hard kill during a write may have left ``fields.h5`` unreadable) is
renamed ``fields-<k>.h5`` (the XDMF follows) so that the resumed run writes into a fresh
``fields.h5`` and never meets a dataset of a step written after the checkpoint.
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
from pathlib import Path

import numpy as np

from drape.errors import InputError

CHECKPOINT_FILE = "checkpoint.npz"
#: a copy of fields.xdmf taken with each checkpoint (dolfinx rewrites the XDMF text in place
#: after every step: a hard kill at that moment leaves it empty)
XDMF_COPY = "checkpoint.xdmf"
#: a copy of fields.h5 taken with each checkpoint: a hard kill while a step's fields are being
#: written can leave the file's group index unreadable, the checkpointed steps' data with it
H5_COPY = "checkpoint.h5"
VERSION = 4
#: config keys a resume may change (they do not change the numbers)
FREE_KEYS = ("title", "material", "output.folder", "output.checkpoint_every")


def signature(job) -> dict[str, str]:
    """The effective config (overrides applied) and material, flattened: key -> repr(value)."""
    flat = {}

    def walk(prefix, value):
        if dataclasses.is_dataclass(value):
            value = {f.name: getattr(value, f.name) for f in dataclasses.fields(value)}
        if isinstance(value, dict):
            for key, item in value.items():
                walk(f"{prefix}.{key}" if prefix else str(key), item)
        elif isinstance(value, (tuple, list)) and value and dataclasses.is_dataclass(value[0]):
            for i, item in enumerate(value):
                walk(f"{prefix}[{i}]", item)
        else:
            flat[prefix] = repr(value)

    walk("", job.config)
    for key in FREE_KEYS:
        flat.pop(key, None)
    walk("material", job.params)
    flat.pop("material.name", None)
    return flat


def differences(saved: dict, now: dict) -> list[str]:
    keys = sorted(set(saved) | set(now))
    return [f"{k} ({saved.get(k, 'unset')} -> {now.get(k, 'unset')})" for k in keys
            if saved.get(k) != now.get(k)]


class Checkpoints:
    """Writes and reads the checkpoint of a run. ``rows``, ``frame_rows`` and ``ledger`` are
    run_job's own (mutable) records: saved as they are, filled in place on resume."""

    def __init__(self, folder, problem, job, every: int, rows: list, frame_rows: list,
                 ledger: dict, prescribed_dofs=()):
        self.folder = Path(folder)
        self.layout = Layout(problem)
        #: the owned, unrolled dofs of the ledger's arrays (PrescribedMotion.prescribed_dofs)
        self.prescribed_dofs = prescribed_dofs
        self.path = self.folder / CHECKPOINT_FILE
        self.problem = problem
        self.comm = problem.comm
        self.every = every
        self.signature = signature(job)
        self.rows, self.frame_rows, self.ledger = rows, frame_rows, ledger
        self.last = None          # the last accepted solver Step
        self.saved_step = None    # number of the step in the file
        self.disk = None          # a drape.io.disk.Disk: the ranks agree on write errors

    # --- writing ----------------------------------------------------------------------------
    def due(self, number: int) -> bool:
        """Whether step ``number`` gets a checkpoint."""
        return bool(self.every) and number % self.every == 0

    def step_done(self, step) -> None:
        """After a converged step is written: save every ``every`` steps."""
        self.last = step
        if self.due(step.number):
            self.save()

    def save_last(self, check_space: bool = False) -> bool:
        """At a stop (signal, failure): save the last converged step unless already saved.
        The problem must hold the committed state. Collective. True if a checkpoint exists.
        ``check_space``: not if the disk has no room for it (drape.io.disk.WriteFailed)."""
        if self.every and self.last is not None and self.saved_step != self.last.number:
            if check_space and self.disk is not None:
                self.disk.check(self.last.number, True, results=False)
            self.save()
        return self.every > 0 and self.saved_step is not None

    def save(self) -> None:
        """Collective: gather every rank's state to rank 0, which writes the file atomically."""
        step = self.last
        parts = self.comm.gather(self._local_state(), root=0)
        if self.comm.rank == 0:
            p = self.problem
            meta = {"version": VERSION, "ranks": self.comm.size, "step": step.number,
                    "t": step.t, "dt": step.next_dt,
                    "t_committed": p.t_committed, "t_previous": p.t_previous,
                    "external_work": self.ledger["external"],
                    "regularisation_work": self.ledger["regularisation"],
                    "rows": self.rows, "frame_rows": self.frame_rows,
                    "signature": self.signature}
            arrays = {"meta": np.array(json.dumps(meta, default=_json_default))}
            arrays.update(_merge(parts))
        else:
            arrays = None

        def write():
            from drape.io.writer import FIELDS_FILE
            xdmf = self.folder / FIELDS_FILE
            h5 = xdmf.with_suffix(".h5")
            # the copies first: a failure (a full disk) after them leaves copies of a later
            # step than the checkpoint's, which hold all its data; never the other way round
            try:
                if xdmf.is_file():
                    _replace_text(self.folder / XDMF_COPY, xdmf.read_text())
                if h5.is_file():
                    _replace_copy(h5, self.folder / H5_COPY)
                _replace_atomically(self.path, lambda stream: _savez(stream, arrays))
            except OSError:
                if not self.path.is_file():     # copies of no checkpoint: space wasted
                    (self.folder / XDMF_COPY).unlink(missing_ok=True)
                    (self.folder / H5_COPY).unlink(missing_ok=True)
                raise

        if self.disk is not None:
            self.disk.write(f"the checkpoint of step {step.number} ({CHECKPOINT_FILE})", write)
        else:
            if self.comm.rank == 0:
                write()
            self.comm.barrier()
        self.saved_step = step.number

    def finished(self) -> None:
        """Collective, after the last step: the run closed fields.h5 whole, so the copy of it
        kept for a torn write is removed (it would double the results' size on disk)."""
        if self.comm.rank == 0:
            (self.folder / H5_COPY).unlink(missing_ok=True)
        self.comm.barrier()

    def _local_state(self) -> dict:
        """{family: (keys, {name: rows})} of this rank's owned entries, keyed by global
        numbers that do not depend on the partition (:class:`Layout`); "global": values
        that are the same on every rank."""
        p, layout = self.problem, self.layout
        owned = layout.n_owned_nodes
        nodes = {"xyz": p.V.tabulate_dof_coordinates()[:owned]}
        for name, function in (("u", p.u_committed), ("u_previous", p.u_previous)):
            nodes[name] = function.x.array.reshape(-1, 3)[:owned]
        n = layout.n_cells
        cells = {"points": p.point_coordinates.reshape(n, -1)}
        for name, function in p.law_state_functions().items():
            cells[f"law.{name}"] = layout.cell_rows(function)
        global_values = {}
        for i, contribution in enumerate(p.contributions):
            points = len(contribution.reference_points)
            for key, value in contribution.state().items():
                value = np.asarray(value)
                if value.ndim and value.shape[0] == points:   # one row per point
                    cells[f"contribution{i}.{key}"] = value.reshape(n, -1)
                    global_values[f"shape.contribution{i}.{key}"] = np.array(value.shape[1:])
                else:
                    global_values[f"contribution{i}.{key}"] = value
        dofs = np.asarray(self.prescribed_dofs, dtype=np.int64)
        prescribed = {"f": _array(self.ledger["f"]), "g": _array(self.ledger["g"])}
        if self.ledger["f"] is None:        # before the first step: no ledger yet
            prescribed = {}
            dofs = dofs[:0]
        return {"nodes": (layout.node_key[:owned], nodes),
                "cells": (layout.cell_key[:n], cells),
                "prescribed": (layout.node_key[dofs // 3] * 3 + dofs % 3, prescribed),
                "global": global_values}

    # --- reading ----------------------------------------------------------------------------
    def load(self):
        """Collective: read the checkpoint into the problem and the records; returns the
        step, t and next step size to continue from. InputError (on every rank) if there is no
        usable checkpoint, the config, material or ranks differ, or the mesh does."""
        error, meta = None, None
        if self.comm.rank == 0:
            try:
                meta = self._read_meta()
            except InputError as failure:
                error = failure
        error = self.comm.bcast(error, root=0)
        if error is not None:
            raise error
        meta = self.comm.bcast(meta, root=0)
        with np.load(self.path) as data:
            saved = {k: data[k] for k in data.files if k != "meta"}
        p, layout = self.problem, self.layout
        nodes, node_mismatch = _pick(saved, "nodes", layout.node_key)   # ghosts too
        cells, cell_mismatch = _pick(saved, "cells", layout.cell_key[:layout.n_cells])
        problems = []
        if nodes is not None:
            X = p.V.tabulate_dof_coordinates()
            node_mismatch += int((np.abs(nodes["xyz"] - X).max(axis=1) > _tolerance(X)).sum())
        if cells is not None:
            x = p.point_coordinates.reshape(layout.n_cells, -1)
            cell_mismatch += int((np.abs(cells["points"] - x).max(axis=1)
                                  > _tolerance(x)).sum()) if x.size else 0
        node_mismatch = self.comm.allreduce(node_mismatch)
        cell_mismatch = self.comm.allreduce(cell_mismatch)
        if node_mismatch:
            problems.append(f"{node_mismatch} node(s) of this mesh are not where the "
                            "checkpoint's are")
        if cell_mismatch:
            problems.append(f"{cell_mismatch} cell(s) of this mesh are not the checkpoint's")
        if problems:
            raise InputError("the checkpoint was made with another mesh: " + "; ".join(problems),
                             source=str(self.path), expected="the mesh of the interrupted run "
                             "(the same blank and mesh keys); or --overwrite to start over")
        p.u.x.array[:] = nodes["u"].ravel()
        p.u_committed.x.array[:] = nodes["u"].ravel()
        p.u_previous.x.array[:] = nodes["u_previous"].ravel()
        p.t_committed = float(meta["t_committed"])
        p.t_previous = None if meta["t_previous"] is None else float(meta["t_previous"])
        for name, function in p.law_state_functions().items():
            if f"law.{name}" not in cells:
                raise InputError(f"the checkpoint has no law state '{name}' (made before "
                                 "version 2 of the law)", source=str(self.path),
                                 expected="a checkpoint of this drape; or --overwrite to start "
                                 "over")
            layout.set_cell_rows(function, cells[f"law.{name}"])
        for i, contribution in enumerate(p.contributions):
            prefix = f"contribution{i}."
            state = {k[len(prefix):]: v for k, v in cells.items() if k.startswith(prefix)}
            points = len(contribution.reference_points)
            state = {k: v.reshape(points, *saved[f"global.shape.{prefix}{k}"])
                     for k, v in state.items()}
            state.update({k[len(f"global.{prefix}"):]: v for k, v in saved.items()
                          if k.startswith(f"global.{prefix}")})
            contribution.load_state(state)
        dofs = np.asarray(self.prescribed_dofs, dtype=np.int64)
        ledger_f = ledger_g = None
        if "prescribed.f" in saved:
            prescribed, missing = _pick(saved, "prescribed",
                                        layout.node_key[dofs // 3] * 3 + dofs % 3)
            if self.comm.allreduce(missing):
                raise InputError("the checkpoint's prescribed boundary differs from this run's",
                                 source=str(self.path), expected="the mesh and boundaries of "
                                 "the interrupted run; or --overwrite to start over")
            ledger_f, ledger_g = prescribed["f"].ravel(), prescribed["g"].ravel()
        p._evaluated_at = None
        p.evaluate()
        self.ledger.update(external=meta["external_work"],
                           regularisation=meta["regularisation_work"], f=ledger_f, g=ledger_g)
        self.rows[:] = meta["rows"]
        self.frame_rows[:] = meta["frame_rows"]
        self.saved_step = meta["step"]
        return meta["step"], meta["t"], meta["dt"]

    def _read_meta(self) -> dict:
        if not self.path.is_file():
            raise InputError("nothing to resume: no checkpoint in the results folder",
                             source=str(self.folder), key="--resume",
                             expected=f"{CHECKPOINT_FILE} there (written every "
                                      "output.checkpoint_every steps and when a run stops)")
        try:
            with np.load(self.path) as data:
                meta = json.loads(str(data["meta"]))
        except Exception as failure:  # a damaged file: name it
            raise InputError(f"the checkpoint cannot be read ({failure})", source=str(self.path),
                             expected="a checkpoint written by drape run") from None
        if meta.get("version") != VERSION:
            raise InputError("the checkpoint is of another drape version", source=str(self.path),
                             value=meta.get("version"), expected=f"version {VERSION}")
        if meta["ranks"] != self.comm.size:
            raise InputError(f"the checkpoint was written by {meta['ranks']} rank(s), this run "
                             f"has {self.comm.size}", source=str(self.path), key="--resume",
                             expected=f"mpirun -n {meta['ranks']} (the same number of ranks)")
        changed = differences(meta["signature"], self.signature)
        if changed:
            raise InputError("the config or material differs from the checkpoint's: "
                             + "; ".join(changed), source=str(self.path), key="--resume",
                             expected="the same config, --set values and material as the "
                                      "interrupted run; or --overwrite to start over")
        return meta



# --- partition-independent keys -------------------------------------------------------------

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


def _merge(parts) -> dict[str, np.ndarray]:
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


def _pick(saved, family, keys):
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


def _tolerance(x) -> float:
    return 1e-8 * max(1.0, float(np.abs(x).max())) if x.size else 0.0


# --- the results folder back to the checkpoint ---------------------------------------------

def rewind_outputs(folder, rows: list, t: float, comm) -> None:
    """Collective (rank 0 works): steps.csv is rewritten with ``rows`` (the checkpoint's);
    fields.xdmf (from the checkpoint's copy) keeps the grids up to ``t``, its fields.h5 (the
    checkpoint's copy where there is one) becomes fields-<k>.h5 (the XDMF follows), and the
    XDMF copy becomes the rewound XDMF, so that a second resume from the same checkpoint finds
    the data where the first one put it."""
    import csv

    from drape.io.writer import FIELDS_FILE, STEPS_FILE, _text
    folder = Path(folder)
    if comm.rank == 0:
        text = io.StringIO(newline="")
        writer = csv.writer(text)
        writer.writerow(list(rows[0]))
        for row in rows:
            writer.writerow([_text(row.get(name, "")) for name in rows[0]])
        _replace_text(folder / STEPS_FILE, text.getvalue())
        xdmf, copy, h5_copy = folder / FIELDS_FILE, folder / XDMF_COPY, folder / H5_COPY
        if copy.is_file():
            _replace_text(xdmf, copy.read_text())
        if h5_copy.is_file():
            os.replace(h5_copy, xdmf.with_suffix(".h5"))
        if xdmf.is_file():
            trim_xdmf(xdmf, t)
            _replace_text(copy, xdmf.read_text())
    comm.barrier()


def trim_xdmf(path: Path, t: float) -> None:
    """Drop every time-series grid after t; move the HDF5 file aside as <stem>-<k>.h5."""
    import xml.etree.ElementTree as ET
    ET.register_namespace("xi", "http://www.w3.org/2001/XInclude")
    tree = ET.parse(path)
    for collection in tree.getroot().iter("Grid"):
        if collection.get("GridType") != "Collection":
            continue
        for grid in list(collection.findall("Grid")):
            time = grid.find("Time")
            if time is not None and float(time.get("Value")) > t:
                collection.remove(grid)
    h5 = path.with_suffix(".h5")
    if h5.is_file():
        k = 1
        while path.with_name(f"{path.stem}-{k}.h5").exists():
            k += 1
        part = path.with_name(f"{path.stem}-{k}.h5")
        for item in tree.getroot().iter("DataItem"):
            if item.text and item.text.strip().startswith(f"{h5.name}:"):
                item.text = item.text.strip().replace(f"{h5.name}:", f"{part.name}:", 1)
        os.replace(h5, part)
    buffer = io.BytesIO()
    tree.write(buffer, encoding="utf-8", xml_declaration=True)
    _replace_text(path, buffer.getvalue().decode())


def _replace_atomically(path: Path, write) -> None:
    """``write(stream)`` into a temporary file beside ``path`` (binary), flush it to disk, then
    rename it onto ``path``: a kill at any moment leaves either the old file or the new one."""
    temporary = path.with_name(f".{path.name}.tmp")
    try:
        with open(temporary, "wb") as stream:
            write(stream)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, path)
    except BaseException:       # a full disk, say: no partial file left behind
        temporary.unlink(missing_ok=True)
        raise


def _replace_text(path: Path, text: str) -> None:
    _replace_atomically(path, lambda stream: stream.write(text.encode()))


def _replace_copy(source: Path, target: Path) -> None:
    """Copy ``source`` onto ``target`` atomically."""
    import shutil

    def copy(stream):
        with open(source, "rb") as original:
            shutil.copyfileobj(original, stream, 1 << 20)
    _replace_atomically(target, copy)


def _savez(stream, arrays) -> None:
    """np.savez into memory first, then to ``stream``: a failed write leaves no half-closed
    zip file behind (whose clean-up prints a traceback)."""
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    stream.write(buffer.getbuffer())


def _array(value) -> np.ndarray:
    return np.zeros(0) if value is None else np.asarray(value)


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"cannot store {type(value).__name__} in a checkpoint")

