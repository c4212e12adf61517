"""configs/picture_frame.toml: the blank's outline follows the hinged frame (paper eq. 25) through
the cyclic history 10, 20, 30, 40, -40 deg. The field is homogeneous, so every quadrature point
must reproduce the single-point law (drape.picture_frame.drive) driven by the angles of the
FE's own converged steps, and the frame force measured from the boundary's virtual work must
be the closed form a tau cos(pi/4 - gamma/2) of that tau."""

import csv
import xml.etree.ElementTree as ET

import numpy as np

from conftest import CONFIGS
from drape.reports.frame_force import closed_form
from drape.job import load_job
from drape.picture_frame import drive
from drape.run import run_job


def _run(comm, folder, overrides=()):
    job = load_job(CONFIGS / "picture_frame.toml", overrides=list(overrides))
    angles, taus = [], []

    def on_step(record, problem):
        angles.append(record.histories["angle"])
        taus.append(problem.response.tau.copy())

    summary = run_job(job, comm, output=folder, on_step=on_step)
    return job, summary, np.array(angles), taus


def _max_relative_error(comm, job, angles, taus):
    reference = drive(job.params, angles)["tau"]
    scale = np.abs(reference).max()
    local = max(float(np.abs(t - r).max()) if t.size else 0.0 for t, r in zip(taus, reference))
    return comm.allreduce(local, op=max) / scale, reference


def test_every_quadrature_point_follows_the_single_point_law(comm, shared_tmp):
    # fields every 50 steps (and the last): XDMF writing is slow under MPI on a busy machine
    job, summary, angles, taus = _run(comm, shared_tmp / "pf", ["output.xdmf_every=50"])
    assert summary.t == 1.0
    # the history was followed: its waypoints are among the converged steps
    for waypoint in (10.0, 20.0, 30.0, 40.0, -40.0):
        assert np.any(np.isclose(angles, waypoint, atol=1e-12))
    error, reference = _max_relative_error(comm, job, angles, taus)
    assert error < 1e-8
    # not a trivial check: every surface was active, tau reversed with every unloading
    active = drive(job.params, angles)["active_surface"]
    assert set(active) == {0, 1, 2}
    assert np.count_nonzero(np.diff(np.sign(reference))) >= 8
    rows = summary.rows
    # the regularisation never acts in the plane: u_z stays exactly 0
    assert all(row.regularisation_work == 0.0 for row in rows)
    assert all(row.reactions["boundary"][2] == 0.0 for row in rows)

    if comm.rank == 0:
        folder = shared_tmp / "pf"
        # frame force from the boundary's virtual work vs the closed form of the single-point tau
        with open(folder / "frame_force.csv") as stream:
            table = list(csv.DictReader(stream))
        assert len(table) == len(angles) + 1          # step 0 too
        force = np.array([float(r["frame_force"]) for r in table[1:]])
        expected = closed_form(job.config.blank.length, angles, reference)
        assert np.abs(force - expected).max() <= 1e-8 * np.abs(expected).max()
        assert (folder / "frame_force.png").stat().st_size > 10_000
        # steps.csv: one row per converged step, the same as returned
        with open(folder / "steps.csv") as stream:
            steps = list(csv.DictReader(stream))
        assert [int(r["step"]) for r in steps] == list(range(len(angles) + 1))
        for name in ("newton_iterations", "boundary_Fx", "regularisation_share", "frame_force"):
            assert name in steps[0]
        # the XDMF time series: the mesh once, every field by its own name at the written steps
        root = ET.parse(folder / "fields.xdmf").getroot()
        grids = root.findall(".//Grid[@GridType='Collection']")
        names = {g.get("Name") for g in grids}
        assert names >= {"displacement", "shear_angle_deg", "plastic_shear_angle_deg", "tau",
                         "warp_direction", "weft_direction", "active_surface"}
        written = len(angles) // 50 + (1 if len(angles) % 50 else 0) + 1   # + step 0
        for grid in grids:
            assert len(grid.findall("Grid")) == written
        assert len(root.findall(".//Grid[@Name='mesh']")) == 1


def test_any_yarn_angle_and_free_triangles(comm, shared_tmp):
    """The same check with yarns at 30 deg to the frame on gmsh's unstructured triangles: the
    yarn frame is handled at any angle, and a homogeneous field does not lock on any mesh."""
    overrides = ["blank.yarn_angle=30", "mesh.cell=triangle", "mesh.pattern=free",
                 "mesh.size=25", "history.angle.values=[0, 12, -6]", "history.angle.t=[0, 0.5, 1]",
                 "steps.maximum=0.05", "output.xdmf=false", "output.snapshot=none"]
    job, summary, angles, taus = _run(comm, shared_tmp / "pf30", overrides)
    error, _ = _max_relative_error(comm, job, angles, taus)
    assert error < 1e-8
