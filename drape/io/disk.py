"""Writing a run's results when the disk may fail (no space, no permission, a quota).

Every write of ``drape run`` goes through :meth:`Disk.write`: the ranks that write catch the
error (OSError; RuntimeError from DOLFINx's HDF5 writer), and the ranks then agree, so that
every rank raises the same :class:`~drape.errors.WriteFailed` (exit code 1, one line naming
what could not be written, where, the free space and about how much a step needs) and none is
left waiting in a collective call. HDF5's own error stack (pages of diagnostics) is not
printed while drape writes: the line says what failed.

Before each converged step's files are written, :meth:`Disk.check` compares the free space of
the results folder with what the step will write (twice the last step's growth, or the
estimate) and, when a checkpoint is due, what it writes too: a step that would not fit stops
the run before anything of it is written, so that every file is as after the last complete
step. :meth:`Disk.warn_at_start` says when the folder has less free space than the run's
estimated need.

The estimate (:func:`estimate`): a written step's fields are the displacement (3 doubles a
node) and the DG0 cell fields (6 scalars and 2 vectors, plus the contact pressure of a forming
job: 13-14 doubles a cell), with about 1 kB of HDF5 and 0.6 kB of XDMF text per field; a
checkpoint is about 8 bytes times 9 per node, 2 + n (surfaces) per law point and 15 per
contribution point, plus its copy of fields.h5 and fields.xdmf.
"""

from __future__ import annotations

import errno
import math
import os
import shutil
from pathlib import Path

from drape.errors import WriteFailed

#: a step is written only if the folder has this many times the last step's growth free
MARGIN = 2.0
#: and at least this much more (HDF5 metadata, the XDMF text rewritten whole)
SLACK = 64 * 1024


def free_bytes(folder) -> int | None:
    """Free bytes (for this user) on the filesystem of ``folder`` (or its nearest parent)."""
    path = Path(folder).absolute()
    while not path.exists() and path != path.parent:
        path = path.parent
    try:
        return shutil.disk_usage(path).free
    except OSError:
        return None


def size(n: float | None) -> str:
    """Bytes as a short text: 812 B, 23.4 kB, 1.5 MB, 2.1 GB."""
    if n is None:
        return "unknown"
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if abs(n) >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{int(n)} B"


def estimate(problem, config, extra_cell_fields: int = 0,
             extra_functions=()) -> dict[str, float]:
    """Bytes a run writes: per written step (fields, ``extra_cell_fields`` and the DOLFINx
    ``extra_functions`` (e.g. a stack's interface fields) beside the usual ones, and a
    steps.csv row), per checkpoint
    (without its copy of fields.h5), and the whole run's need (its least number of steps,
    1 / steps.maximum, with fields.h5 twice: the checkpoints keep a copy of it)."""
    nodes = problem.V.dofmap.index_map.size_global
    cells = problem.mesh.topology.index_map(2).size_global
    points = cells * problem.nq
    extra = cells * len(problem.extra_weights) * len(problem.contributions)
    n_fields = 9 + extra_cell_fields
    fields = 8 * (3 * nodes + (13 + extra_cell_fields) * cells) + n_fields * 1600
    for function in extra_functions:
        space = function.function_space
        fields += 8 * space.dofmap.index_map.size_global * space.dofmap.index_map_bs + 1600
    fields *= config.output.xdmf
    row = 1000
    per_step = fields / config.output.xdmf_every + row
    checkpoint = 8 * (9 * nodes + (3 + problem.law.n) * points + 15 * extra) + 50_000
    checkpoint *= config.output.checkpoint_every > 0
    steps = math.ceil(1.0 / config.steps.maximum)
    snapshot = 8 * (5 * nodes + 6 * points) if config.output.snapshot != "none" else 0
    total = steps * per_step + snapshot + 8 * 2 * cells * problem.nq + 500_000
    if config.output.checkpoint_every:
        total += steps * fields / config.output.xdmf_every + checkpoint
    return {"step": per_step, "checkpoint": checkpoint, "total": total, "steps": steps}


class Disk:
    """The results folder's space and the agreement of the ranks on write errors."""

    def __init__(self, folder, comm, need: dict):
        self.folder = Path(folder)
        self.comm = comm
        self.need = dict(need)
        self.growth = None          # bytes the last complete step added to the folder
        self._sizes = None

    # --- before ------------------------------------------------------------------------------
    def warn_at_start(self, say) -> None:
        if self.comm.rank == 0:
            free = free_bytes(self.folder)
            if free is not None and free < self.need["total"]:
                say(f"drape run: warning: {self.folder} has {size(free)} free; this run needs "
                    f"about {size(self.need['total'])} (at least {self.need['steps']} steps of "
                    f"about {size(self.need['step'])} each, with the checkpoint's copy of "
                    "fields.h5): it will stop when the disk is full (resume after freeing "
                    "space; docs/faults.md)")

    def check(self, step: int, checkpoint_due: bool, results: bool = True) -> None:
        """Collective, before step ``step``'s files are written: WriteFailed (nothing of the
        step written) if the folder has less free space than the step's ``results`` (and the
        checkpoint then due) will write."""
        message = None
        if self.comm.rank == 0:
            free = free_bytes(self.folder)
            need = ((self.step_bytes() if results else 0.0)
                    + (self.checkpoint_bytes() if checkpoint_due else 0.0))
            if free is not None and free < need:
                what = " and ".join([f"step {step}'s results"] * results
                                    + ["checkpoint"] * checkpoint_due)
                message = (f"could not write {what} in {self.folder}: "
                           f"{os.strerror(errno.ENOSPC)} ({size(free)} free; "
                           f"{self.describe_need()})")
        message = self.comm.bcast(message, root=0)
        if message is not None:
            raise WriteFailed(message, fields_intact=True)

    def step_bytes(self) -> float:
        """What the next step is allowed to need: MARGIN times the last step's growth (the
        estimate before one is measured), plus SLACK."""
        return MARGIN * (self.growth or self.need["step"]) + SLACK

    def checkpoint_bytes(self) -> float:
        """A checkpoint now: checkpoint.npz (the last one's size, else the estimate) and the
        copies of fields.h5 and fields.xdmf; written next to the old ones, then renamed."""
        files = [self.folder / name for name in ("fields.h5", "fields.xdmf")]
        npz = self.folder / "checkpoint.npz"
        last = npz.stat().st_size if npz.is_file() else 0
        return max(last, self.need["checkpoint"]) + sum(f.stat().st_size for f in files
                                                        if f.is_file())

    def describe_need(self) -> str:
        text = f"a step writes about {size(self.growth or self.need['step'])}"
        if self.need["checkpoint"]:
            text += f", a checkpoint about {size(self.checkpoint_bytes())}"
        return text

    def measure(self, files) -> None:
        """Rank 0, after a complete step: the folder's growth over the step (``files``: names
        of the files the steps grow)."""
        if self.comm.rank != 0:
            return
        sizes = sum((self.folder / name).stat().st_size for name in files
                    if (self.folder / name).is_file())
        if self._sizes is not None and sizes > self._sizes:
            self.growth = sizes - self._sizes
        self._sizes = sizes

    # --- while writing -----------------------------------------------------------------------
    def write(self, what: str, action, *, root_only: bool = True, fields: bool = False):
        """Run ``action()`` (on rank 0 only, or on every rank), then agree: WriteFailed on every
        rank if it failed on any. ``what``: the file(s), for the message; ``fields``: the
        action writes fields.xdmf/h5 (a failure may leave them torn)."""
        message = None
        result = None
        if not root_only or self.comm.rank == 0:
            try:
                with quiet_hdf5():
                    result = action()
            except (OSError, RuntimeError) as failure:
                message = self.describe(what, failure)
        messages = self.comm.allgather(message)
        failed = [m for m in messages if m is not None]
        if failed:
            raise WriteFailed(failed[0], fields_intact=not fields)
        return result

    def describe(self, what: str, failure) -> str:
        free = free_bytes(self.folder)
        if isinstance(failure, OSError) and failure.strerror:
            reason = failure.strerror
        elif free is not None and free < MARGIN * (self.growth or self.need["step"]):
            reason = f"{os.strerror(errno.ENOSPC)} (HDF5: {str(failure).strip()})"
        else:
            reason = str(failure).strip() or type(failure).__name__
        return (f"could not write {what} in {self.folder}: {reason} ({size(free)} free; "
                f"{self.describe_need()})")


class quiet_hdf5:
    """Turn off the automatic printing of HDF5's error stack (DOLFINx's libhdf5, the one
    loaded in this process) while writing; restored afterwards."""

    _library = None

    def __enter__(self):
        self._saved = None
        library = _hdf5()
        if library is not None:
            import ctypes
            func, data = ctypes.c_void_p(), ctypes.c_void_p()
            if library.H5Eget_auto2(0, ctypes.byref(func), ctypes.byref(data)) >= 0:
                self._saved = (func, data)
                library.H5Eset_auto2(0, None, None)
        return self

    def __exit__(self, kind, *exc):
        # after a failure, quiet for good: the file left open (drape.io.writer._abandon) fails
        # to close again when HDF5 shuts down at exit
        if self._saved is not None and kind is None:
            _hdf5().H5Eset_auto2(0, self._saved[0], self._saved[1])
        return False


def _hdf5():
    """The HDF5 library DOLFINx uses (already loaded in this process: libhdf5_openmpi on
    Debian; h5py brings its own serial one), or None."""
    if quiet_hdf5._library is None:
        import ctypes
        quiet_hdf5._library = False
        try:
            with open("/proc/self/maps") as maps:
                names = {line.split()[-1] for line in maps if "/libhdf5" in line}
        except OSError:
            names = set()
        names = sorted((n for n in names if "_hl" not in Path(n).name),
                       key=lambda n: "openmpi" not in n)
        for name in names[:1]:
            try:
                library = ctypes.CDLL(name)
                pointer = ctypes.POINTER(ctypes.c_void_p)
                library.H5Eget_auto2.argtypes = [ctypes.c_int64, pointer, pointer]
                library.H5Eset_auto2.argtypes = [ctypes.c_int64, ctypes.c_void_p,
                                                 ctypes.c_void_p]
                quiet_hdf5._library = library
            except (OSError, AttributeError):
                pass
    return quiet_hdf5._library or None


def write_failed(failure, writer, checkpoints, records, folder):
    """After a write failure (:meth:`Disk.write`): fields.xdmf back to its last complete step; a
    checkpoint of that step when the failure came before the step changed anything (a step
    that would not fit) and there is room for one (else the last good one is kept). Returns
    the WriteFailed to raise: the failure, what is kept, and whether a resume can follow."""
    if not failure.fields_intact:
        writer.rewind_fields()
    room = None
    if not getattr(failure, "committed", False):
        try:
            checkpoints.save_last(check_space=True)
        except WriteFailed:
            room = size(checkpoints.disk.checkpoint_bytes())
    kept = (f"; results up to step {records[-1].step} (t = {records[-1].t:.6g}) are kept in "
            f"{folder}")
    saved = checkpoints.saved_step
    if saved is not None:
        kept += f", with the checkpoint of step {saved}"
        if room is not None:
            kept += f" (no room for a newer one: about {room})"
    elif room is not None:
        kept += (f", without a checkpoint (no room for one either: about {room}): --overwrite "
                 "starts over once there is space")
    else:
        kept += (", without a checkpoint (output.checkpoint_every = 0 or none written yet): "
                 "--overwrite starts over")
    error = WriteFailed(f"{failure}{kept}", fields_intact=failure.fields_intact)
    error.resumable = saved is not None
    return error
