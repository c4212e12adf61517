"""The frame force of a picture-frame test, from the finite-element run and in closed form.

A square frame of side a, hinged at its corners, holds the blank with the yarns along its
sides; pulling two opposite corners apart shears the blank homogeneously (paper eq. 25): the
corners' distance is d = 2 a cos(phi), phi = pi/4 - gamma/2, gamma the shear angle. With
C12 = sin gamma and S = tau/2 (G1 G2 + G2 G1) (C11 = C22 = 1, no yarn tension), the internal
virtual work of the blank is a^2 tau/2 cos(gamma) d gamma, and the frame's is P dd =
P a sin(phi) d gamma. Hence the frame force

    P = a tau cos(gamma) / (2 sin phi) = a tau cos(phi)        (N, with tau in N/mm, a in mm)

(cos gamma = sin 2 phi = 2 sin phi cos phi). The run measures P independently of tau: the
generalised force conjugate to the frame angle, Q = sum_i f_i dg_i/d gamma over the prescribed
boundary nodes (f the internal nodal forces, g the prescribed displacements), divided by
dd/d gamma = a sin(phi).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from drape import picture_frame
from drape.fe.job_part import JobPart
from drape.io.writer import write_table

FILE_STEM = "frame_force"
#: frame_force.csv's columns after step, t and angle_deg (the first two are the report's
#: columns in steps.csv, tau_mean is the step loop's)
COLUMNS = ("frame_force", "frame_force_from_tau", "tau_mean")


class FrameForceReport(JobPart):
    """A picture-frame job (``[picture_frame]``): the frame force of every converged step,
    measured from the boundary's conjugate force and in closed form from the mean tau."""

    files = "frame_force.csv/.png"

    def __init__(self, config):
        self.side = config.blank.length
        self.angle = config.picture_frame.angle       # the history that is the frame angle

    def bind(self, problem, motion) -> None:
        self.motion = motion

    def measure(self, record, records: list, force) -> None:
        angle = record.histories[self.angle]
        q = self.motion.conjugate_force(force, record.t, self.angle)
        record.columns["frame_force"] = (from_conjugate_force(self.side, angle, q)
                                         if record.step > 0 else 0.0)
        record.columns["frame_force_from_tau"] = float(closed_form(self.side, angle,
                                                                   record.tau_mean))

    def finish(self, folder: Path, records: list, seconds: float) -> None:
        write(folder, self.side, [{"step": r.step, "t": r.t, "angle_deg": r.histories[self.angle],
                                   **r.columns, "tau_mean": r.tau_mean} for r in records])


def corner_distance_rate(side: float, angle_deg: float) -> float:
    """dd/d gamma (mm per rad) of the corner-to-corner distance d = 2 a cos(pi/4 - gamma/2)."""
    return side * math.sin(math.pi / 4 - math.radians(angle_deg) / 2)


def closed_form(side: float, angle_deg, tau):
    """Frame force P = a tau cos(pi/4 - gamma/2) (N): ``drape.picture_frame.frame_force``."""
    return picture_frame.frame_force(tau, angle_deg, side)


def from_conjugate_force(side: float, angle_deg: float, q_per_deg: float) -> float:
    """P from Q = dW/d gamma given per degree of the angle history (N mm / deg)."""
    return q_per_deg * (180.0 / math.pi) / corner_distance_rate(side, angle_deg)


def write(folder: Path, side: float, rows: list[dict]) -> None:
    """frame_force.csv and frame_force.png from the run's rows (rank 0 only)."""
    folder = Path(folder)
    write_table(folder / f"{FILE_STEM}.csv", ("step", "t", "angle_deg", *COLUMNS), rows)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    angle = np.array([r["angle_deg"] for r in rows])
    fig, ax = plt.subplots(figsize=(7.5, 5.0), dpi=120)
    ax.plot(angle, [r["frame_force"] for r in rows], color="tab:blue", lw=1.8,
            label="finite elements (work of the frame's motion)")
    ax.plot(angle, [r["frame_force_from_tau"] for r in rows], color="tab:orange", lw=1.0, ls="--",
            label=r"$a\,\tau\,\cos(\pi/4-\gamma/2)$ with the FE's $\tau$")
    force = np.array([r["frame_force"] for r in rows])
    turns = picture_frame.reversal_indices(angle)
    turns = turns[np.abs(angle[turns]) > 1e-9]            # the peaks, not the returns to 0
    if turns.size:
        ax.plot(angle[turns], force[turns], ls="none", marker="o", ms=5, mfc="white",
                mec="black", mew=1.0, zorder=4, label="reversal points (angle, force)")
        for i in turns:
            ax.annotate(f"{angle[i]:+.1f}\u00b0, {force[i]:.3g} N", (angle[i], force[i]),
                        textcoords="offset points", xytext=(-6 if angle[i] > 0 else 6, 6),
                        ha="right" if angle[i] > 0 else "left", fontsize=8, color="0.25")
    ax.axhline(0.0, color="0.6", lw=0.6)
    ax.axvline(0.0, color="0.6", lw=0.6)
    ax.set_xlabel(r"frame shear angle $\gamma$ (deg)")
    ax.set_ylabel("frame force P (N)")
    ax.set_title(f"Picture frame, side {side:g} mm, {len(rows) - 1} load steps: force to pull "
                 f"the frame's corners apart", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=9, framealpha=0.9)
    fig.tight_layout()
    fig.savefig(folder / f"{FILE_STEM}.png")
    plt.close(fig)
