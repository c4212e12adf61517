"""Stopping a run cleanly on SIGTERM or SIGINT (Ctrl-C).

While a run is on, the handlers only note the signal. Before every residual evaluation the
ranks combine their flags, and a flag set on any rank ends the Newton attempt on every rank
there (drape.fe.solver.NewtonSolver); the step loop asks
:meth:`StopRequest.requested` before and after every Newton attempt; it is collective (an
allreduce), so
a signal delivered to one rank or to all of them stops every rank at the same step boundary:
no rank is left waiting in a collective call. The run then writes the checkpoint of the last
converged step and raises :class:`~drape.errors.Interrupted` (exit code 1). A second signal
stops the process at once, the usual way (no checkpoint).
"""

from __future__ import annotations

import os
import signal
import threading

SIGNALS = (signal.SIGTERM, signal.SIGINT)


class StopRequest:
    def __init__(self):
        self.signal = 0
        self._previous = {}

    def install(self) -> "StopRequest":
        """Take over SIGTERM and SIGINT (main thread only; elsewhere nothing changes)."""
        if threading.current_thread() is threading.main_thread():
            for number in SIGNALS:
                self._previous[number] = signal.signal(number, self._note)
        return self

    def uninstall(self) -> None:
        for number, handler in self._previous.items():
            signal.signal(number, handler)
        self._previous = {}

    def _note(self, number, frame) -> None:
        if self.signal:  # the second one: stop now, as if drape had not taken the signal
            self.uninstall()
            signal.signal(number, signal.SIG_DFL)
            os.kill(os.getpid(), number)
            return
        self.signal = number

    def requested(self, comm) -> str | None:
        """Collective: the name of the signal any rank received, else None."""
        from mpi4py import MPI
        number = comm.allreduce(self.signal, op=MPI.MAX)
        return signal.Signals(number).name if number else None
