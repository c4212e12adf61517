"""Progress of a run over its load steps, shown by rank 0 only.

On a terminal: one line redrawn in place (bar, load factor, step, Newton iterations, step size,
time left). Otherwise (a log file, a batch job): one plain line per converged step. Silent when
disabled (``--quiet``, or ranks other than 0).

The time left is the load still to go at the slower of two paces: the run's average since its
first step, and its last few steps'. Forming slows down near its end (the shear locks, steps
are cut back), which the average alone sees too late: it promised seconds where most of a
minute was left. Paces count from the load the run started at, so a resumed run is not
credited with the load of the run it continues.
"""

from __future__ import annotations

import sys
import time


def _duration(seconds: float) -> str:
    if seconds != seconds or seconds == float("inf"):
        return "?"
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds}s"
    if seconds < 3600:
        return f"{seconds // 60}m{seconds % 60:02d}s"
    return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m"


class Progress:
    """Report converged steps of a run whose load factor goes from 0 to ``total``."""

    def __init__(self, total: float = 1.0, *, enabled: bool = True, stream=None,
                 label: str = "load", width: int = 24, clock=time.monotonic,
                 recent_steps: int = 3):
        self.total = total
        self.recent_steps = recent_steps
        self.enabled = enabled
        self.stream = stream if stream is not None else sys.stderr
        self.label = label
        self.width = width
        self.clock = clock
        self.start = clock()
        self.interactive = enabled and hasattr(self.stream, "isatty") and self.stream.isatty()
        self._drawn = False
        #: (clock, load) at the start and at every converged step since
        self.history: list[tuple[float, float]] = []

    def record(self, load: float, step_size: float) -> None:
        """A step of ``step_size`` converged at ``load``; the first one also fixes the load the
        run started from (``load - step_size``: 0, or where a resumed run picks up)."""
        if not self.history:
            self.history.append((self.start, max(load - step_size, 0.0)))
        self.history.append((self.clock(), load))

    def time_left(self) -> float:
        """Seconds until the load reaches ``total`` at the slower of the average pace and the
        last ``recent_steps`` steps' pace (inf before a step has added load)."""
        if len(self.history) < 2:
            return float("inf")
        now, load = self.history[-1]
        still = max(self.total - load, 0.0)

        def pace(since):
            then, load_then = since
            return (now - then) / (load - load_then) if load > load_then else float("inf")

        slowest = max(pace(self.history[0]),
                      pace(self.history[max(len(self.history) - 1 - self.recent_steps, 0)]))
        return 0.0 if still == 0.0 else slowest * still

    def step(self, step: int, load: float, newton_iterations: int, step_size: float,
             note: str = "") -> None:
        """A step converged at load factor ``load``."""
        if not self.enabled:
            return
        done = min(max(load / self.total if self.total else 1.0, 0.0), 1.0)
        self.record(load, step_size)
        left = _duration(self.time_left())
        text = (f"step {step}: {self.label} {load:.4g}/{self.total:g} (+{step_size:.3g}), "
                f"{newton_iterations} Newton iterations, {_duration(self.clock() - self.start)} "
                f"elapsed, ~{left} left")
        if note:
            text += f", {note}"
        if self.interactive:
            filled = int(round(done * self.width))
            bar = "#" * filled + "." * (self.width - filled)
            self.stream.write(f"\r[{bar}] {100 * done:5.1f}% " + text[:100].ljust(100))
            self._drawn = True
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def message(self, text: str) -> None:
        """A line that must not be lost in the redrawn bar (a cutback, a warning)."""
        if not self.enabled:
            return
        if self._drawn:
            self.stream.write("\n")
            self._drawn = False
        self.stream.write(text + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.enabled and self._drawn:
            self.stream.write("\n")
            self.stream.flush()
            self._drawn = False
