"""Results folders are never overwritten silently.

A command that writes results into a folder first asks :func:`claim`: if the folder already
holds any of the command's result files, it stops with an :class:`~drape.errors.InputError`
(exit code 2) naming them, unless ``--overwrite`` (the old results are deleted first) or, for
``drape run``, ``--resume`` (continue from the checkpoint there). Under MPI rank 0 decides and
every rank raises the same error.
"""

from __future__ import annotations

from pathlib import Path

from drape.errors import InputError

#: what `drape run` writes in its folder (claim refuses to overwrite them silently)
RESULT_FILES = ("steps.csv", "fields.xdmf", "result.npz", "checkpoint.npz")
#: removed with them by --overwrite
ALSO_REMOVED = ("fields.h5", "fields-*.h5", "checkpoint.xdmf", "checkpoint.h5", "run.log",
                "frame_force.csv", "frame_force.png", "bias_extension.csv", "bias_extension.png")


def claim(folder, results, *, comm=None, overwrite: bool = False, resume: bool = False,
          also_remove=(), can_resume: bool = False) -> None:
    """Check (and with ``overwrite`` clear) ``folder`` for a command writing ``results``
    (file names or glob patterns); ``also_remove`` are removed with them on overwrite."""
    error = None
    if comm is None or comm.rank == 0:
        try:
            _claim(Path(folder), results, overwrite, resume, also_remove, can_resume)
        except InputError as failure:
            error = failure
    if comm is not None:
        error = comm.bcast(error, root=0)
    if error is not None:
        raise error


def _claim(folder, results, overwrite, resume, also_remove, can_resume) -> None:
    if overwrite and resume:
        raise InputError("--overwrite and --resume exclude each other", key="--resume",
                         expected="one of them: --overwrite starts over, --resume continues")
    existing = sorted({path.name for pattern in results for path in folder.glob(pattern)})
    if resume or not existing:
        return
    if not overwrite:
        options = ("--overwrite to start over, or --resume to continue from its checkpoint"
                   if can_resume else "--overwrite to replace them")
        raise InputError(f"the results folder already holds results ({', '.join(existing)})",
                         source=str(folder),
                         expected=f"a new or empty folder (--output DIR); {options}")
    for pattern in (*results, *also_remove):
        for path in folder.glob(pattern):
            if path.is_file():
                path.unlink()
