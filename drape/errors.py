"""The two kinds of failure drape reports, and the exit codes the CLI gives them.

* :class:`InputError` -- the input is wrong (a config key misspelt, a value out of range, a
  missing file, a mesh gmsh cannot build). Nothing has been computed yet. Exit code 2.
* :class:`RunFailed` -- a run that had started could not go on (the solver did not converge
  even at the smallest step). Results up to the last converged step are kept. Exit code 1.
* :class:`Interrupted` -- a RunFailed: the run was stopped by SIGTERM or SIGINT; results and
  the checkpoint of the last converged step are written. Exit code 1.
* :class:`WriteFailed` -- a RunFailed: results could not be written (a full disk, say); the
  files are as after the last complete step, the last good checkpoint is kept. Exit code 1.
"""

from __future__ import annotations

EXIT_OK = 0
EXIT_RUN_FAILED = 1
EXIT_BAD_INPUT = 2


class _Unset:
    """'no value' (survives pickling: errors are broadcast under MPI)."""

    def __reduce__(self):
        return "_UNSET"


_UNSET = _Unset()


class InputError(Exception):
    """Bad input, with where it is (file, key), what it is (value) and what was expected."""

    def __init__(self, problem: str, *, source: str | None = None, key: str | None = None,
                 value: object = _UNSET, expected: str | None = None):
        self.problem = problem
        self.source = source
        self.key = key
        self.value = value
        self.expected = expected
        super().__init__(self.message)

    @property
    def message(self) -> str:
        where = []
        if self.source:
            where.append(str(self.source))
        if self.key:
            where.append(f"key '{self.key}'")
        text = ": ".join(where)
        if self.value is not _UNSET:
            if self.key:
                text += f" = {self.value!r}"
            else:
                text += f": value {self.value!r}" if text else f"value {self.value!r}"
        text = f"{text}: {self.problem}" if text else self.problem
        if self.expected:
            text += f"; expected {self.expected}"
        return text

    def located(self, source: str | None = None, prefix: str | None = None) -> "InputError":
        """The same error with its file set (if unset) and its key prefixed by a section."""
        key = self.key
        if prefix:
            key = f"{prefix}.{key}" if key else prefix
        return InputError(self.problem, source=self.source or source, key=key,
                          value=self.value, expected=self.expected)


class RunFailed(Exception):
    """A run that started and could not finish; what converged so far has been written.
    ``resumable``: a checkpoint of the last converged step exists (`drape run --resume` may go
    on from it, with other numerical controls: drape.io.checkpoint.CONTROL_KEYS)."""

    resumable = False

    def __reduce__(self):      # broadcast under MPI with its attributes
        return (type(self), (str(self),), dict(self.__dict__))


class Interrupted(RunFailed):
    """A run stopped by a signal (SIGTERM, SIGINT) after its last converged step was saved."""


class WriteFailed(RunFailed):
    """Results could not be written (no space, no permission, a quota): the run stopped; the
    files are as after the last complete step (``fields_intact`` False: fields.xdmf/h5 may be
    torn; the resume takes them from the checkpoint's copies) and the last good checkpoint is
    kept."""

    def __init__(self, message: str, *, fields_intact: bool = True):
        super().__init__(message)
        self.fields_intact = fields_intact
        self.committed = False      # the failed step was committed in memory (no checkpoint)
        self.resumable = False      # a checkpoint exists: the message gives the resume command


def one_line(command: str, error: Exception) -> str:
    """The line a command reports a failure with (stderr, and the run's log): "drape COMMAND:
    error: ..." for bad input, "stopped: ..." for a stopped run, "run failed: ..." otherwise."""
    if isinstance(error, InputError):
        return f"drape {command}: error: {error.message}"
    kind = "stopped" if isinstance(error, Interrupted) else "run failed"
    return f"drape {command}: {kind}: {error}"
