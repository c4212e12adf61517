"""What a kind of job adds to the step loop of ``drape run``: the forming process, the picture
frame's frame force, the bias-extension report.

The loop (:class:`drape.step_loop.StepLoop`) knows only this interface: it asks the parts how
to set up the blank's mesh and problem (centred, bending, inertia), hands every part the problem
and the boundary motion once, moves each part's load with its own, asks each for a first guess
before Newton and for a re-solve after it, lets each add its columns to a converged step's
record, and asks each for its files at the end. A patch test is a job with no parts. The
defaults do nothing, so a part overrides only what it needs.
"""

from __future__ import annotations

from pathlib import Path


class JobPart:
    """One kind of job's additions to the step loop (all methods collective over the ranks)."""

    #: point contributions evaluated with the law at every residual (e.g. the tools' contact)
    contributions: tuple = ()
    #: extra cell fields for fields.xdmf: name -> callable giving one value per local cell
    cell_fields: dict = {}
    #: added to a failed run's message (e.g. what may carry a forming run further)
    failure_hint: str = ""
    #: what :meth:`finish` writes, for the message of a failed write
    files: str = ""
    #: :meth:`finish` runs on rank 0 only (True) or on every rank (collective)
    finish_on_root: bool = True
    #: the blank is meshed centred on the origin, not from (0, 0) (a forming job: the tools'
    #: axis)
    centres_blank: bool = False
    #: bending rigidity B (N mm) the problem gets when the config's bending.rigidity is unset
    #: (None: this part has no say; with no part saying, 0)
    default_bending_rigidity: float | None = None
    #: the problem carries the blank's inertia (a forming job with an areal density)
    inertial: bool = False

    def create_problem(self, job, comm, law, damping: float, centred: bool, options: dict):
        """The membrane problem when this part's job needs its own kind (e.g. a stack of
        plies' StackProblem), built with the loop's ``law``, out-of-plane ``damping`` (N/mm^3)
        and MembraneProblem ``options``; None (the default) leaves it to the loop."""
        return None

    def output_fields(self, problem):
        """Fields this part adds to fields.xdmf: an object with ``functions`` ({name: DOLFINx
        Function}) and ``update()`` (e.g. a stack's plies and interfaces), or None."""
        return None

    def bind(self, problem, motion) -> None:
        """Once the membrane problem and the boundary motion exist."""

    def set_load(self, t: float) -> None:
        """Move this part's load (e.g. the punch) to load factor t."""

    def predict(self, t: float) -> None:
        """Before Newton's attempt at t: the first guess and any per-step constants."""

    def resolve(self, t: float, solve, result):
        """After an attempt at t gave ``result`` (SolveResult): ``solve()`` again as often as
        this part needs (e.g. until the holder's force is met); returns the result to keep."""
        return result

    def measure(self, record, records: list, force) -> None:
        """Add this part's columns to the converged step's ``record`` (a
        drape.step_record.StepRecord: its ``columns``, or a loop field the part adds to, as
        a forming job's punch work to ``external_work``); ``records`` are the steps before,
        ``force`` the assembled internal force vector."""

    def finish(self, folder: Path, records: list, seconds: float) -> None:
        """At the end of a run (converged or not, records of at least two steps): this part's
        files in ``folder``."""
