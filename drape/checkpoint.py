"""Checkpoints of a run and resuming from one (``drape run CONFIG --resume``).

``checkpoint.npz`` in the results folder holds the last checkpointed converged step: every
quadrature state (the law's state functions, any point contribution's
:meth:`~drape.membrane.PointContribution.state`), the committed displacement, the ledgers of
external and regularisation work (with the prescribed forces and displacements their next
increment starts from), the step number, load factor t, the step size the loop proposes next,
the rows written so far, and the effective config and material it was made with.

The data is per rank (ghosts included), gathered to rank 0 into one file. A resume therefore
needs the same number of ranks and the same partition (checked, node by node): otherwise an
:class:`~drape.errors.InputError`. The file is written to a temporary name and renamed, so a
kill while writing leaves the previous checkpoint intact.

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
VERSION = 3
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
                 ledger: dict):
        self.folder = Path(folder)
        self.path = self.folder / CHECKPOINT_FILE
        self.problem = problem
        self.comm = problem.comm
        self.every = every
        self.signature = signature(job)
        self.rows, self.frame_rows, self.ledger = rows, frame_rows, ledger
        self.last = None          # the last accepted solver Step
        self.saved_step = None    # number of the step in the file

    # --- writing ----------------------------------------------------------------------------
    def step_done(self, step) -> None:
        """After a converged step is written: save every ``every`` steps."""
        self.last = step
        if self.every and step.number % self.every == 0:
            self.save()

    def save_last(self) -> bool:
        """At a stop (signal, failure): save the last converged step unless already saved.
        The problem must hold the committed state. Collective. True if a checkpoint exists."""
        if self.every and self.last is not None and self.saved_step != self.last.number:
            self.save()
        return self.every > 0 and self.saved_step is not None

    def save(self) -> None:
        """Collective: gather every rank's state to rank 0, which writes the file atomically."""
        step = self.last
        local = self._local_state()
        parts = self.comm.gather(local, root=0)
        if self.comm.rank == 0:
            meta = {"version": VERSION, "ranks": self.comm.size, "step": step.number,
                    "t": step.t, "dt": step.next_dt,
                    "external_work": self.ledger["external"],
                    "regularisation_work": self.ledger["regularisation"],
                    "rows": self.rows, "frame_rows": self.frame_rows,
                    "signature": self.signature}
            arrays = {"meta": np.array(json.dumps(meta, default=_json_default))}
            for rank, part in enumerate(parts):
                arrays.update({f"rank{rank}.{name}": value for name, value in part.items()})
            from drape.output import FIELDS_FILE
            xdmf = self.folder / FIELDS_FILE
            h5 = xdmf.with_suffix(".h5")
            if xdmf.is_file():
                _replace_text(self.folder / XDMF_COPY, xdmf.read_text())
            if h5.is_file():
                _replace_copy(h5, self.folder / H5_COPY)
            _replace_atomically(self.path, lambda stream: np.savez(stream, **arrays))
        self.comm.barrier()
        self.saved_step = step.number

    def finished(self) -> None:
        """Collective, after the last step: the run closed fields.h5 whole, so the copy of it
        kept for a torn write is removed (it would double the results' size on disk)."""
        if self.comm.rank == 0:
            (self.folder / H5_COPY).unlink(missing_ok=True)
        self.comm.barrier()

    def _local_state(self) -> dict[str, np.ndarray]:
        p = self.problem
        state = {"node_xyz": p.V.tabulate_dof_coordinates(),
                 "u": p.u_committed.x.array.copy(),
                 "u_previous": p.u_previous.x.array.copy(),
                 "t_steps": np.array([p.t_committed, np.nan if p.t_previous is None
                                      else p.t_previous]),
                 "ledger_f": _array(self.ledger["f"]), "ledger_g": _array(self.ledger["g"])}
        for name, function in p.law_state_functions().items():
            state[f"law.{name}"] = function.x.array.copy()
        for i, contribution in enumerate(p.contributions):
            for key, value in contribution.state().items():
                state[f"contribution{i}.{key}"] = np.asarray(value)
        return state

    # --- reading ----------------------------------------------------------------------------
    def load(self):
        """Collective: read the checkpoint into the problem and the records; returns the
        step, t and next step size to continue from. InputError (on every rank) if there is no
        usable checkpoint or the config, material, ranks or partition differ."""
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
            prefix = f"rank{self.comm.rank}."
            local = {k[len(prefix):]: data[k] for k in data.files if k.startswith(prefix)}
        p = self.problem
        same = np.array_equal(local["node_xyz"], p.V.tabulate_dof_coordinates())
        if not self.comm.allreduce(same, op=_mpi_land()):
            raise InputError("the checkpoint was made with another partition of the mesh",
                             source=str(self.path), expected="the same mesh and ranks as the "
                             "interrupted run; or --overwrite to start over")
        p.u.x.array[:] = local["u"]
        p.u_committed.x.array[:] = local["u"]
        p.u_previous.x.array[:] = local["u_previous"]
        p.t_committed = float(local["t_steps"][0])
        p.t_previous = None if np.isnan(local["t_steps"][1]) else float(local["t_steps"][1])
        for name, function in p.law_state_functions().items():
            if f"law.{name}" not in local:
                raise InputError(f"the checkpoint has no law state '{name}' (made by an older "
                                 "drape, before version 2 of the law)", source=str(self.path),
                                 expected="a checkpoint of this version; or --overwrite to "
                                 "start over")
            function.x.array[:] = local[f"law.{name}"]
        for i, contribution in enumerate(p.contributions):
            prefix = f"contribution{i}."
            contribution.load_state({k[len(prefix):]: v for k, v in local.items()
                                     if k.startswith(prefix)})
        p._evaluated_at = None
        p.evaluate()
        self.ledger.update(external=meta["external_work"],
                           regularisation=meta["regularisation_work"],
                           f=local["ledger_f"], g=local["ledger_g"])
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


# --- the results folder back to the checkpoint ---------------------------------------------

def rewind_outputs(folder, rows: list, t: float, comm) -> None:
    """Collective (rank 0 works): steps.csv is rewritten with ``rows`` (the checkpoint's);
    fields.xdmf (from the checkpoint's copy) keeps the grids up to ``t``, its fields.h5 (the
    checkpoint's copy where there is one) becomes fields-<k>.h5 (the XDMF follows), and the
    XDMF copy becomes the rewound XDMF, so that a second resume from the same checkpoint finds
    the data where the first one put it."""
    import csv

    from drape.output import FIELDS_FILE, STEPS_FILE, _text
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
    with open(temporary, "wb") as stream:
        write(stream)
        stream.flush()
        os.fsync(stream.fileno())
    os.replace(temporary, path)


def _replace_text(path: Path, text: str) -> None:
    _replace_atomically(path, lambda stream: stream.write(text.encode()))


def _replace_copy(source: Path, target: Path) -> None:
    """Copy ``source`` onto ``target`` atomically."""
    import shutil

    def copy(stream):
        with open(source, "rb") as original:
            shutil.copyfileobj(original, stream, 1 << 20)
    _replace_atomically(target, copy)


def _array(value) -> np.ndarray:
    return np.zeros(0) if value is None else np.asarray(value)


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"cannot store {type(value).__name__} in a checkpoint")


def _mpi_land():
    from mpi4py import MPI
    return MPI.LAND
