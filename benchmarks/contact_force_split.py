"""Each tool's contact force on the blank split into its normal and friction parts, vertical
and radial, at the end of a forming run: where a punch force comes from.

    .venv/bin/python benchmarks/contact_force_split.py configs/hemisphere.toml OUT \
        process.stroke=30 output.xdmf=false contact.penalty_factor=0.1

Runs the job (``table.key=value`` overrides as ``drape run --set`` takes them) into the folder
OUT and, at every converged step, sums traction x area over the blank's quadrature points per
tool: N the normal part (pressure p times the tool's normal), F the friction part (the rest);
z vertical (up), r radial (outward from the z axis: on the flange, friction resisting the
draw-in is positive). Prints the last step's sums (N) and writes all of them to
OUT/contact_force_split.json. The figures in docs/forming-checks.md ("Penalty") were taken with it.
"""

from __future__ import annotations

import json
import sys

import numpy as np


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) < 2:
        sys.exit(__doc__)
    config, folder, *overrides = argv
    from mpi4py import MPI

    from drape.forming.press import Forming
    from drape.job import load_job
    from drape.run import run_job

    rows, parts = [], {}

    def split_forces(record, problem):
        """The tools' contact forces of the converged step, split into normal and friction."""
        forming = parts["run"].part(Forming)
        contact, comm = forming.tool_contact, forming.comm
        xy = contact.reference_points[:, :2] + contact._u[:, :2]
        radial = xy / np.maximum(np.linalg.norm(xy, axis=1), 1e-12)[:, None]
        split = {"stroke": record.columns["stroke"]}
        for name, (_, response) in contact.last.items():
            normal = response.pressure[:, None] * contact._trial_slip[name][1]
            for part, traction in (("N", normal), ("F", response.traction - normal)):
                split[f"{name}_{part}z"] = comm.allreduce(float(traction[:, 2] @ forming.areas))
                split[f"{name}_{part}r"] = comm.allreduce(
                    float(np.einsum("ij,ij->i", traction[:, :2], radial) @ forming.areas))
        rows.append(split)

    run_job(load_job(config, overrides=overrides), output=folder,
            on_start=lambda run: parts.update(run=run), on_step=split_forces)
    if MPI.COMM_WORLD.rank == 0:
        with open(f"{folder}/contact_force_split.json", "w") as stream:
            json.dump(rows, stream, indent=1)
        print(json.dumps({key: round(value, 3) for key, value in rows[-1].items()}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
