"""Checkpoints of a run and resuming from one (``drape run CONFIG --resume``).

``checkpoint.npz`` in the results folder holds the last checkpointed converged step: every
quadrature state (the law's, :meth:`~drape.fe.membrane.MembraneProblem.law_state_functions`, and
any point contribution's :meth:`~drape.fe.membrane.PointContribution.state`: arrays of one row per
point of the rank are matched to their points, other arrays are the same on every rank), the
committed and the previous displacement, the ledgers of
external and regularisation work (with the prescribed forces and displacements their next
increment starts from), the step number, load factor t, the step size the loop proposes next,
the step records so far (as steps.csv's rows, :meth:`drape.step_record.StepRecord.row`), and
the effective config and material it was made with.

The values are gathered to rank 0 into one file, each node's and cell's under a number that
does not depend on the partition (:class:`drape.io.layout.Layout`: gmsh's node index,
DOLFINx's original cell index); a resume finds its nodes and cells there by number and checks
their coordinates (to 1e-8 of the blank's size): another mesh is an
:class:`~drape.errors.InputError`, another partition or number of ranks is not. On the same
number of ranks the resumed run gets the same partition (drape.fe.mesh) and continues with the
same numbers; on another, it continues as a run on that number of ranks would (1 rank and 2
agree to round-off), and its fields refer to the mesh written again
(:class:`drape.io.writer.ResultsWriter`'s ``resumed_from_ranks``). The file is written to a
temporary name and renamed (:mod:`drape.io.atomic`), so a kill or a full disk while writing
leaves the previous checkpoint intact. Resuming rewinds the folder's other files to the
checkpoint: :func:`drape.io.rewind.rewind_outputs`.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from drape.config import field_default
from drape.errors import InputError
from drape.io.atomic import replace_atomically, replace_copy, replace_text, savez
from drape.io.layout import Layout, coordinate_tolerance, merge_ranks, pick_rows
from drape.io.rewind import H5_COPY, XDMF_COPY

CHECKPOINT_FILE = "checkpoint.npz"
VERSION = 4
#: config keys a resume may change (they do not change the numbers)
FREE_KEYS = ("title", "material", "output.folder", "output.checkpoint_every")
#: config keys (and tables, ending in ".") a resume may change that steer how the remaining
#: steps are solved, not the problem: a run that stopped or failed to converge goes on from
#: its checkpoint with smaller steps, more iterations or other solver settings (logged)
CONTROL_KEYS = ("steps.", "solver.", "process.holder_prediction")
#: CONTROL_KEYS as the messages name them: "steps.*, solver.* and process.holder_prediction"
CONTROLS_TEXT = " and ".join([", ".join(k + "*" if k.endswith(".") else k
                                        for k in CONTROL_KEYS[:-1]), CONTROL_KEYS[-1]])


def signature(job, defaults: bool = False) -> dict[str, str]:
    """The effective config (overrides applied) and material, flattened: key -> repr(value);
    ``defaults``: each key's default instead (keys of settings without one left out)."""
    flat = {}

    def walk(prefix, value):
        if dataclasses.is_dataclass(value):
            for field in dataclasses.fields(value):
                key = f"{prefix}.{field.name}" if prefix else field.name
                item = getattr(value, field.name)
                if defaults and not dataclasses.is_dataclass(item):
                    item = field_default(field)
                    if item is dataclasses.MISSING:
                        continue     # a required setting: no default to match
                walk(key, item)
        elif isinstance(value, dict):
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


def is_control(key: str) -> bool:
    """Whether a resume may change config ``key`` (CONTROL_KEYS)."""
    return any(key.startswith(c) if c.endswith(".") else key == c for c in CONTROL_KEYS)


def differences(saved: dict, now: dict, defaults: dict | None = None) -> dict[str, str]:
    """The keys whose values differ, each with "key (saved -> now)" for messages. A key the
    checkpoint lacks (a setting newer than the drape that wrote it) matches where its value now
    is the setting's default (``defaults``, :func:`signature` with ``defaults=True``): the
    default of a new setting keeps the behaviour before it."""
    defaults = defaults or {}
    keys = sorted(set(saved) | set(now))
    return {k: f"{k} ({saved.get(k, 'unset')} -> {now.get(k, 'unset')})" for k in keys
            if saved.get(k) != now.get(k)
            and not (k not in saved and k in defaults and now.get(k) == defaults[k])}


class Checkpoints:
    """Writes and reads the checkpoint of a run. ``records`` (the step loop's
    drape.step_record.StepRecord list) and ``ledger`` (its drape.step_record.WorkLedger) are
    the loop's own: saved as they are, filled in place on resume; ``read_row`` turns a saved
    steps.csv row back into a record."""

    def __init__(self, folder, problem, job, every: int, records: list, ledger,
                 prescribed_dofs=(), read_row=None):
        self.folder = Path(folder)
        self.layout = Layout(problem)
        #: the owned, unrolled dofs of the ledger's arrays (PrescribedMotion.prescribed_dofs)
        self.prescribed_dofs = prescribed_dofs
        self.path = self.folder / CHECKPOINT_FILE
        self.problem = problem
        self.comm = problem.comm
        self.every = every
        self.signature = signature(job)
        self.defaults = signature(job, defaults=True)
        self.records, self.ledger = records, ledger
        self.read_row = read_row
        self.last = None          # the last accepted solver Step
        self.saved_step = None    # number of the step in the file
        self.changed_controls = []    # what a resume changed (CONTROL_KEYS), "key (a -> b)"
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
                    "external_work": self.ledger.external,
                    "regularisation_work": self.ledger.regularisation,
                    "rows": [record.row() for record in self.records],
                    "signature": self.signature}
            arrays = {"meta": np.array(json.dumps(meta, default=_json_default))}
            arrays.update(merge_ranks(parts))
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
                    replace_text(self.folder / XDMF_COPY, xdmf.read_text())
                if h5.is_file():
                    replace_copy(h5, self.folder / H5_COPY)
                replace_atomically(self.path, lambda stream: savez(stream, arrays))
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
        plies = getattr(p, "ply_contact", None)
        if plies is not None:
            nodes.update(_ply_rows(plies, p.global_nodes[:owned]))
            global_values["ply.friction_work"] = self.comm.allreduce(plies.friction_work)
        dofs = np.asarray(self.prescribed_dofs, dtype=np.int64)
        prescribed = {"f": _array(self.ledger.f), "g": _array(self.ledger.g)}
        if self.ledger.f is None:        # before the first step: no ledger yet
            prescribed = {}
            dofs = dofs[:0]
        return {"nodes": (layout.node_key[:owned], nodes),
                "cells": (layout.cell_key[:n], cells),
                "prescribed": (layout.node_key[dofs // 3] * 3 + dofs % 3, prescribed),
                "global": global_values}

    # --- reading ----------------------------------------------------------------------------
    def load(self):
        """Collective: read the checkpoint into the problem, the ledger and the records;
        returns the step, t and next step size to continue from. InputError (on every rank)
        if there is no usable checkpoint, the config or material differ, or the mesh does."""
        meta = self._shared_meta()
        with np.load(self.path) as data:
            saved = {k: data[k] for k in data.files if k != "meta"}
        nodes, cells = self._find_mesh(saved)
        p = self.problem
        p.u.x.array[:] = nodes["u"].ravel()
        p.u_committed.x.array[:] = nodes["u"].ravel()
        p.u_previous.x.array[:] = nodes["u_previous"].ravel()
        p.t_committed = float(meta["t_committed"])
        p.t_previous = None if meta["t_previous"] is None else float(meta["t_previous"])
        self._restore_points(saved, cells)
        self._restore_plies(saved, nodes)
        ledger_f, ledger_g = self._prescribed(saved)
        p._evaluated_at = None
        p.evaluate()
        ledger = self.ledger
        ledger.external, ledger.regularisation = meta["external_work"], meta["regularisation_work"]
        ledger.f, ledger.g = ledger_f, ledger_g
        self.records[:] = [self.read_row(row) for row in meta["rows"]]
        self.saved_step = meta["step"]
        #: the number of ranks of the run that wrote the checkpoint
        self.saved_ranks = int(meta["ranks"])
        #: the numerical controls this resume changed, as "key (saved -> now)"
        self.changed_controls = meta["changed_controls"]
        return meta["step"], meta["t"], meta["dt"]

    def _shared_meta(self) -> dict:
        """The checkpoint's meta data, read and checked on rank 0, on every rank."""
        error, meta = None, None
        if self.comm.rank == 0:
            try:
                meta = self._read_meta()
            except InputError as failure:
                error = failure
        error = self.comm.bcast(error, root=0)
        if error is not None:
            raise error
        return self.comm.bcast(meta, root=0)

    def _find_mesh(self, saved: dict):
        """This rank's nodes and cells in the checkpoint ({name: rows} each, ghost nodes too),
        their coordinates checked; InputError if the mesh is another."""
        p, layout = self.problem, self.layout
        nodes, node_mismatch = pick_rows(saved, "nodes", layout.node_key)
        cells, cell_mismatch = pick_rows(saved, "cells", layout.cell_key[:layout.n_cells])
        problems = []
        if nodes is not None:
            X = p.V.tabulate_dof_coordinates()
            node_mismatch += int((np.abs(nodes["xyz"] - X).max(axis=1)
                                  > coordinate_tolerance(X)).sum())
        if cells is not None:
            x = p.point_coordinates.reshape(layout.n_cells, -1)
            cell_mismatch += int((np.abs(cells["points"] - x).max(axis=1)
                                  > coordinate_tolerance(x)).sum()) if x.size else 0
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
        return nodes, cells

    def _restore_points(self, saved: dict, cells: dict) -> None:
        """The law's state and every point contribution's, from this rank's cells."""
        p, layout = self.problem, self.layout
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

    def _restore_plies(self, saved: dict, nodes: dict) -> None:
        """A stack's ply-ply contact: friction's memory and the accumulated slip of the slave
        nodes this rank owns, the friction work (its total on rank 0), and the candidate pairs
        searched again at the restored displacement, as after the step's commit."""
        p = self.problem
        plies = getattr(p, "ply_contact", None)
        if plies is None:
            return
        if "ply.elastic_slip_0" not in nodes and plies.directions:
            raise InputError("the checkpoint has no ply-ply contact state", source=str(self.path),
                             expected="a checkpoint of this stack; or --overwrite to start over")
        owned = p.global_nodes[: self.layout.n_owned_nodes]
        state = {}
        for i in range(len(plies.directions)):
            memory = np.zeros_like(plies.memory[i])
            memory[owned] = nodes[f"ply.elastic_slip_{i}"][: len(owned)]
            state[f"elastic_slip_{i}"] = memory
            plies.accumulated_slip[i][:] = 0.0
            plies.accumulated_slip[i][owned] = nodes[f"ply.accumulated_slip_{i}"][: len(owned), 0]
        plies.load_state(state)
        total = np.asarray(saved["global.ply.friction_work"], dtype=float)
        plies.friction_work[:] = total if self.comm.rank == 0 else 0.0
        p.begin_step()

    def _prescribed(self, saved: dict):
        """The ledger's prescribed forces and displacements on this rank's prescribed dofs
        (None, None before the first step)."""
        if "prescribed.f" not in saved:
            return None, None
        dofs = np.asarray(self.prescribed_dofs, dtype=np.int64)
        prescribed, missing = pick_rows(saved, "prescribed",
                                        self.layout.node_key[dofs // 3] * 3 + dofs % 3)
        if self.comm.allreduce(missing):
            raise InputError("the checkpoint's prescribed boundary differs from this run's",
                             source=str(self.path), expected="the mesh and boundaries of "
                             "the interrupted run; or --overwrite to start over")
        return prescribed["f"].ravel(), prescribed["g"].ravel()

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
        changed = differences(meta["signature"], self.signature, self.defaults)
        problem = [text for key, text in changed.items() if not is_control(key)]
        if problem:
            raise InputError("the config or material differs from the checkpoint's: "
                             + "; ".join(problem), source=str(self.path), key="--resume",
                             expected="the same config, --set values and material as the "
                                      f"interrupted run (only the {CONTROLS_TEXT} settings "
                                      "may change); or --overwrite to start over")
        meta["changed_controls"] = list(changed.values())
        return meta


def _ply_rows(plies, owned_nodes) -> dict:
    """A stack's per-node ply-ply contact state on this rank's owned nodes (global numbers
    ``owned_nodes``): friction's memory and the accumulated slip, per direction."""
    rows = {}
    for i, memory in enumerate(plies.memory):
        rows[f"ply.elastic_slip_{i}"] = memory[owned_nodes]
        rows[f"ply.accumulated_slip_{i}"] = plies.accumulated_slip[i][owned_nodes][:, None]
    return rows


def _array(value) -> np.ndarray:
    return np.zeros(0) if value is None else np.asarray(value)


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"cannot store {type(value).__name__} in a checkpoint")

