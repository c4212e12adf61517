"""configs/bias_extension.toml: a 100 x 50 mm blank, yarns at +-45 deg, left end clamped, right
end pulled by d. Inextensible yarns give three zones: undeformed next to the clamps, gamma/2
along the free edges, gamma in the centre with gamma = pi/2 - 2 acos((D + d)/(sqrt 2 D)),
D = length - width. Also: which meshes lock (docs/fe-results.md, "Shear locking")."""

import math

import numpy as np
import pytest

from conftest import CONFIGS
from drape.job import load_job
from drape.run import run_job

LENGTH, WIDTH = 100.0, 50.0
D = LENGTH - WIDTH


def kinematic_deg(d):
    return math.degrees(math.pi / 2 - 2 * math.acos((D + d) / (math.sqrt(2) * D)))


def mean_abs_shear(comm, problem, centre, radius):
    """Mean |gamma_t| (deg) over the law's points within radius (mm) of centre, all ranks."""
    near = np.linalg.norm(problem.point_coordinates - centre, axis=1) < radius
    total = comm.allreduce(float(np.abs(problem.response.gamma_t_deg[near]).sum()))
    count = comm.allreduce(int(near.sum()))
    return total / count


def run(comm, folder, overrides=()):
    job = load_job(CONFIGS / "bias_extension.toml",
                   overrides=list(overrides) + ["output.xdmf=false"])
    records = []

    def on_step(record, problem):
        records.append({
            "d": record.histories["d"], "force": record.reactions["right"][0],
            "left_force": record.reactions["left"][0],
            "strain": record.max_yarn_strain, "reg": record.regularisation_work,
            "centre": mean_abs_shear(comm, problem, (LENGTH / 2, WIDTH / 2), 0.1 * WIDTH),
            # zone C (next to the left clamp) and zone B (along the bottom edge, left)
            "C": mean_abs_shear(comm, problem, (WIDTH / 5, WIDTH / 2), 0.08 * WIDTH),
            "B": mean_abs_shear(comm, problem, (WIDTH / 2, WIDTH / 6), 0.08 * WIDTH)})

    run_job(job, comm, output=folder, on_step=on_step)
    return records


def test_aligned_quadrilaterals_follow_the_three_zone_kinematics(comm, shared_tmp):
    records = run(comm, shared_tmp / "be")
    assert records[-1]["d"] == 15.0 and kinematic_deg(15.0) > 43.0
    checked = [r for r in records if kinematic_deg(r["d"]) <= 40.0]
    assert len(checked) >= 20
    for r in checked:
        gamma = kinematic_deg(r["d"])
        assert abs(r["centre"] - gamma) < 1.0, r
        assert abs(r["B"] - gamma / 2) < 1.0, r
        assert r["C"] < 0.1, r
        assert r["strain"] < 1e-3                       # the yarns barely stretch
        assert r["reg"] == 0.0                          # flat: the regularisation does nothing
        assert r["left_force"] == pytest.approx(-r["force"], rel=1e-6, abs=1e-9)
    worst = max(abs(r["centre"] - kinematic_deg(r["d"])) for r in checked)
    print(f"largest deviation from the kinematic angle up to 40 deg: {worst:.3f} deg")


def test_which_meshes_lock(comm, shared_tmp):
    """Central shear angle, pulling force and yarn strain at d = 11.25 mm (kinematic 30 deg)
    for yarn-aligned and unstructured meshes of both cell types. Aligned triangles (the
    right-triangle split of the yarn lattice) follow the kinematics like aligned quads;
    gmsh's unstructured triangles and quads lock: the yarns stretch by percents, the force
    is an order of magnitude too high and the central zone over-shears."""
    d = 11.25
    gamma = kinematic_deg(d)
    results = {}
    for cell in ("quadrilateral", "triangle"):
        for pattern in ("aligned", "free"):
            records = run(comm, shared_tmp / f"lock_{cell}_{pattern}",
                          [f"mesh.cell={cell}", f"mesh.pattern={pattern}",
                           f"history.d.values=[0.0, {d}]", "steps.maximum=0.1",
                           "output.snapshot=none"])
            results[cell, pattern] = records[-1]
    if comm.rank == 0:
        print(f"\nbias extension at d = {d} mm, kinematic central shear {gamma:.2f} deg")
        print(f"{'mesh':<26}{'centre (deg)':>14}{'force (N)':>12}{'yarn strain':>13}")
        for (cell, pattern), r in results.items():
            print(f"{pattern + ' ' + cell:<26}{r['centre']:>14.2f}{r['force']:>12.2f}"
                  f"{r['strain']:>13.2e}")
    reference = results["quadrilateral", "aligned"]
    for cell in ("quadrilateral", "triangle"):
        aligned, free = results[cell, "aligned"], results[cell, "free"]
        assert abs(aligned["centre"] - gamma) < 1.0
        assert aligned["force"] == pytest.approx(reference["force"], rel=0.1)
        assert aligned["strain"] < 1e-3
        # locking
        assert free["force"] > 5.0 * reference["force"]
        assert free["strain"] > 10.0 * aligned["strain"]
        assert free["centre"] - gamma > 2.0
