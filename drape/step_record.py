"""One converged load step of ``drape run`` as the step loop records it (:class:`StepRecord`),
and the running work ledger its works come from (:class:`WorkLedger`).

The loop fills the fields every job has (the step, its solve, the boundary's reactions, the
work ledger, the largest shear and yarn strain); the job's parts (:mod:`drape.fe.job_part`)
add their own columns to :attr:`StepRecord.columns` in :meth:`~drape.fe.job_part.JobPart.
measure`. :meth:`StepRecord.row` is the step's row of ``steps.csv`` (column names and order);
:meth:`StepRecord.from_row` reads one back (a checkpoint keeps the rows as ``steps.csv`` has
them, so a checkpoint of an older drape that stored dicts resumes too).
"""

from __future__ import annotations

import dataclasses

import numpy as np

#: the loop's own columns of steps.csv before the histories, reactions and the rest
_HEAD = ("step", "t", "dt", "newton_iterations", "cutbacks", "residual_norm")
#: the loop's own columns after the reactions (regularisation_share is derived)
_TAIL = ("external_work", "regularisation_work", "regularisation_share", "bending_energy",
         "max_shear_angle_deg", "max_yarn_strain", "shear_oscillation_deg", "tau_mean")
#: the components of a boundary's reaction, as steps.csv names them: <boundary>_Fx, ...
REACTION_AXES = ("Fx", "Fy", "Fz")


@dataclasses.dataclass
class StepRecord:
    """A converged load step (step 0: the blank as meshed, before any load)."""

    step: int                       #: the step's number, 0, 1, 2, ...
    t: float                        #: load factor at the step's end, 0 to 1
    dt: float = 0.0                 #: the step's size in load factor (0 for step 0)
    newton_iterations: int = 0      #: Newton iterations of the step (re-solves included)
    cutbacks: int = 0               #: failed attempts before it converged (each halved dt)
    residual_norm: float = 0.0      #: the residual's 2-norm Newton stopped at (N)
    #: the config's histories at t: name -> value (in the history's own unit)
    histories: dict[str, float] = dataclasses.field(default_factory=dict)
    #: each named boundary's reaction (N): name -> (Fx, Fy, Fz), the internal force summed over
    #: its nodes
    reactions: dict[str, tuple] = dataclasses.field(default_factory=dict)
    #: work done on the blank (N mm): the prescribed boundary motion's (trapezoidal in the
    #: displacement increments), plus what a part adds (a forming job: the punch's)
    external_work: float = 0.0
    regularisation_work: float = 0.0    #: work of the out-of-plane damping (N mm)
    bending_energy: float = 0.0         #: the bending hinges' stored energy (N mm)
    max_shear_angle_deg: float = 0.0    #: largest |shear angle| at a law point (deg)
    max_yarn_strain: float = 0.0        #: largest yarn strain at a law point (1)
    #: cell-to-cell oscillation of the shear map (deg; drape.reports.oscillation)
    shear_oscillation_deg: float = 0.0
    tau_mean: float = 0.0               #: the shear stress tau averaged over the points (N/mm)
    #: the job parts' columns, in the order they were added (units in each part's module)
    columns: dict[str, float] = dataclasses.field(default_factory=dict)
    seconds: float = 0.0                #: wall time of the step's Newton solves (s)

    @property
    def regularisation_share(self) -> float:
        """The damping's work as a fraction of the external work (0 before any work)."""
        work = self.external_work
        return self.regularisation_work / abs(work) if work != 0.0 else 0.0

    def row(self) -> dict:
        """The step's row of steps.csv: column name -> value, in the file's column order."""
        row = {name: getattr(self, name) for name in _HEAD}
        row.update(self.histories)
        for name, force in self.reactions.items():
            row.update({f"{name}_{axis}": value for axis, value in zip(REACTION_AXES, force)})
        row.update({name: getattr(self, name) for name in _TAIL})
        row.update(self.columns)
        row["seconds"] = self.seconds
        return row

    @classmethod
    def from_row(cls, row: dict, histories, boundaries) -> StepRecord:
        """The record of a steps.csv row (a dict, as :meth:`row` gives it); ``histories`` and
        ``boundaries`` name the run's histories and reaction boundaries. Columns that are none
        of the loop's own are the parts'."""
        row = dict(row)
        fields = {name: row.pop(name) for name in (*_HEAD, *_TAIL, "seconds") if name in row}
        fields.pop("regularisation_share", None)
        fields["histories"] = {name: row.pop(name) for name in histories}
        fields["reactions"] = {name: tuple(row.pop(f"{name}_{axis}") for axis in REACTION_AXES)
                               for name in boundaries}
        return cls(**fields, columns=row)


@dataclasses.dataclass
class WorkLedger:
    """The step loop's running works (N mm) and what the next increment of the external work
    starts from: the prescribed dofs' internal forces ``f`` (N) and displacements ``g`` (mm)
    at the last converged step (None before step 0). A checkpoint saves and restores it."""

    external: float = 0.0           #: work of the prescribed boundary motion so far
    regularisation: float = 0.0     #: work of the out-of-plane damping so far
    f: np.ndarray | None = None
    g: np.ndarray | None = None

    def add_boundary_work(self, f: np.ndarray, g: np.ndarray, comm) -> None:
        """The step from the last converged state to (f, g): the trapezoidal rule's work of the
        prescribed motion on this rank's dofs, summed over the ranks (collective)."""
        if self.f is not None:
            local = 0.5 * (self.f + f) @ (g - self.g)
            self.external += comm.allreduce(float(local))
        self.f, self.g = f, g
