"""The bias-extension report of a `drape run` job with a [bias_extension] table.

A rectangle H x W (length along x, the pulling direction), yarns at +-45 deg, one end clamped
and the other pulled by d. With inextensible yarns and no slip the central zone shears by the
kinematic angle (Cao et al. 2008, eqs. 12-13; L0 = H - W)

    gamma = pi/2 - 2 acos((L0 + d) / (sqrt(2) L0)),

the zones along the free edges by gamma/2, and the zones at the clamps not at all. The run
writes, for every converged step, the clamp displacement, the pulling force (the x reaction of
the pulled side), the central shear angle (mean |gamma_t| of the law's points within
centre_radius of the blank's centre) and the kinematic angle: bias_extension.csv and
bias_extension.png (columns also in steps.csv).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from drape.fe.job_part import JobPart
from drape.io.writer import write_table

FILE_STEM = "bias_extension"
COLUMNS = ("step", "t", "displacement_mm", "time_s", "force_N", "central_shear_deg",
           "kinematic_shear_deg")


def kinematic_deg(length: float, width: float, d):
    """Central-zone shear angle (deg) of the three-zone kinematics; nan past full closure."""
    l0 = length - width
    ratio = (l0 + np.asarray(d, dtype=float)) / (math.sqrt(2.0) * l0)
    with np.errstate(invalid="ignore"):
        return np.degrees(np.pi / 2 - 2 * np.arccos(np.where(ratio <= 1.0, ratio, np.nan)))


def displacement_at_angle(length: float, width: float, gamma_deg):
    """The clamp displacement d (mm) at which the kinematic central angle is gamma (deg)."""
    l0 = length - width
    return l0 * (math.sqrt(2.0) * np.cos((np.pi / 2 - np.radians(gamma_deg)) / 2) - 1.0)


def central_shear(comm, problem, centre, radius: float) -> float:
    """Mean |gamma_t| (deg) over the law's points within radius of centre, on all ranks."""
    near = np.linalg.norm(problem.point_coordinates - np.asarray(centre), axis=1) < radius
    total = comm.allreduce(float(np.abs(problem.response.gamma_t_deg[near]).sum()))
    count = comm.allreduce(int(near.sum()))
    return total / count if count else float("nan")


def measure(config, comm, problem, record) -> dict:
    """The report's columns of one step (a drape.step_record.StepRecord; added to its
    columns, and so to steps.csv)."""
    bias, blank = config.bias_extension, config.blank
    radius = bias.centre_radius if bias.centre_radius is not None else 0.1 * blank.width
    d = float(record.histories[bias.displacement])
    pulled_x = record.reactions[bias.pulled][0]
    return {"displacement_mm": d, "time_s": 60.0 * abs(d) / bias.speed,
            "force_N": float(pulled_x) * (1.0 if bias.pulled == "right" else -1.0),
            "central_shear_deg": central_shear(comm, problem,
                                               (blank.length / 2, blank.width / 2), radius),
            "kinematic_shear_deg": float(kinematic_deg(blank.length, blank.width, abs(d)))}


class BiasExtensionReport(JobPart):
    """A bias-extension job (``[bias_extension]``): the report's columns of every converged
    step (:func:`measure`) and bias_extension.csv/.png at the end."""

    files = "bias_extension.csv/.png"

    def __init__(self, config, comm):
        self.config, self.comm = config, comm

    def bind(self, problem, motion) -> None:
        self.problem = problem

    def measure(self, record, records: list, force) -> None:
        record.columns.update(measure(self.config, self.comm, self.problem, record))

    def finish(self, folder: Path, records: list, seconds: float) -> None:
        write(folder, [{"step": r.step, "t": r.t, **r.columns} for r in records],
              self.config.title)


def write(folder: Path, rows: list[dict], title: str = "") -> None:
    """bias_extension.csv and bias_extension.png from the steps' rows (rank 0 only)."""
    folder = Path(folder)
    write_table(folder / f"{FILE_STEM}.csv", COLUMNS, rows)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = np.array([r["displacement_mm"] for r in rows])
    fig, (left, right) = plt.subplots(1, 2, figsize=(11.0, 4.5), dpi=110)
    left.plot(d, [r["force_N"] for r in rows], color="tab:blue", lw=1.8)
    left.set_xlabel("clamp displacement d (mm)")
    left.set_ylabel("force (N)")
    right.plot(d, [r["central_shear_deg"] for r in rows], color="tab:blue", lw=1.8,
               label="finite elements (centre)")
    right.plot(d, [r["kinematic_shear_deg"] for r in rows], color="black", lw=1.0, ls="--",
               label="kinematic, three zones")
    right.set_xlabel("clamp displacement d (mm)")
    right.set_ylabel("central shear angle (deg)")
    right.legend(loc="upper left", fontsize=9)
    for ax in (left, right):
        ax.grid(alpha=0.3)
    fig.suptitle(title or "bias extension", fontsize=10)
    fig.tight_layout()
    fig.savefig(folder / f"{FILE_STEM}.png")
    plt.close(fig)
