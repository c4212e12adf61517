"""The run's log in its results folder, ``run.log``: what ``drape run`` reports on rank 0 (the
start, warnings, cutbacks, one line per converged step) and its last line (finished; stopped,
with the command that resumes it; failed, with what to change), each line written and flushed
as it comes.

Why a file as well as the terminal: a batch system that stops a job at its time limit may send
SIGTERM to mpirun and to the ranks at once; mpirun can then be gone before the ranks' last
lines (the one that says the checkpoint is written and how to resume) reach it. Rank 0 writes
them here before it prints them. A resumed run appends to the log (after a header line with its
command); ``--overwrite`` starts a new one.

Lines are kept in memory until :meth:`RunLog.open`, which ``drape run`` calls once the run has
claimed its folder (a folder that holds another run's results is refused before its log is
touched). A log that cannot be written (a full disk) is given up, not the run: the run's own
writes report the disk (drape.io.disk).
"""

from __future__ import annotations

import datetime
from pathlib import Path

#: the log's file name in the results folder
LOG_FILE = "run.log"


class RunLog:
    """A file-like sink (``write``, ``flush``, ``isatty``) for :class:`drape.io.progress.Progress`
    and the run's messages: lines before :meth:`open` are kept, lines after are written and
    flushed at once. Disabled (every call a no-op) on ranks other than 0."""

    def __init__(self, folder, *, append: bool, enabled: bool = True):
        self.path = Path(folder) / LOG_FILE
        self.append = bool(append)
        self.enabled = bool(enabled)
        self._pending: list[str] = []
        self._stream = None

    def open(self, header: str) -> None:
        """Start writing: ``header`` (the command) with the date first, then the kept lines."""
        if not self.enabled or self._stream is not None:
            return
        when = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
        pending, self._pending = self._pending, []
        try:
            self._stream = open(self.path, "a" if self.append else "w", encoding="utf-8")
        except OSError:
            self.enabled = False
            return
        self.write(f"# {when}: {header}\n" + "".join(pending))

    def write(self, text: str) -> None:
        if not self.enabled:
            return
        if self._stream is None:
            self._pending.append(text)
            return
        try:
            self._stream.write(text)
            self._stream.flush()
        except OSError:
            self._give_up()

    def flush(self) -> None:
        """Every write is flushed already (Progress calls this after each line)."""

    def isatty(self) -> bool:
        return False

    def close(self, last_line: str | None = None) -> None:
        """Write ``last_line`` (if the log was opened) and close the file."""
        if self._stream is not None and last_line:
            self.write(last_line.rstrip("\n") + "\n")
        self._give_up()

    def _give_up(self) -> None:
        stream, self._stream = self._stream, None
        self.enabled = False
        if stream is not None:
            try:
                stream.close()
            except OSError:
                pass
