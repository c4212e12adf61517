"""A stack's outputs (drape/forming/stack_reports.py, the writer's extra fields, `drape view
--ply`): per ply the shear summary of a prescribed homogeneous shear against its closed form
and the draw-in of rigidly translated plies against -d . X/|X|; per interface the summaries of
two plies pressed together and pulled over each other against p A, A, the friction work
sum mu p A min(d/delta, 1) Delta and the slip, the nodal fields' integrals against the
summaries; the XDMF read back with h5py; 1 rank equals 2; ParaView showing one ply."""

import math

import numpy as np
import pytest

from drape.forming.plies import load_stack
from drape.forming.ply_contact import EDGE_RAMP
from drape.forming.stack_reports import (StackFields, interface_summaries, owned_node_plies,
                                         ply_summaries)
from drape.job import MeshConfig
from test_paraview import drape, paraview  # noqa: F401  (the fixture: ParaView installed)
from test_ply_contact import CONSTANT, PENALTY, PRESSURE, _pressed_plies

#: ply 0 a 20 x 20 mm square, ply 1 a disc of radius 8 mm on it; 2.5 mm elements
STACK = load_stack({"plies": [{"thickness": 0.4, "length": 20.0, "width": 20.0},
                              {"thickness": 0.4, "shape": "disc", "radius": 8.0}],
                    "interfaces": [{"friction": 0.3}]})
#: each ply's shear angle under the prescribed simple shear u_x = tan(gamma) Y (deg)
SHEAR_DEG = (10.0, 30.0)
LOCKING_DEG = 20.0


def _stack_problem(comm, stack=STACK):
    from drape.fe.stack_problem import create_stack_problem
    from drape.forming.contact import ContactParameters
    from drape.law.nested_surface import NestedSurfaceLaw
    from drape.law.parameters import MaterialParameters
    return create_stack_problem(comm, stack, MeshConfig(size=2.5), ContactParameters(),
                                NestedSurfaceLaw(MaterialParameters()), 1e-3)


def _node_plies(problem):
    """The ply of every local node (owned and ghosts)."""
    return problem.ply_contact.nodes.ply[problem.global_nodes]


def _prescribe(problem, displacement):
    """u at every local node = displacement(X (n, 2), ply (n,)) (n, 3); the law evaluated."""
    X = problem.V.tabulate_dof_coordinates()[:, :2]
    problem.u.x.array[:] = displacement(X, _node_plies(problem)).ravel()
    problem.u.x.scatter_forward()
    problem.evaluate()


def _simple_shear(X, ply):
    s = np.tan(np.radians(np.asarray(SHEAR_DEG)))[ply]
    return np.column_stack([s * X[:, 1], np.zeros(len(X)), np.zeros(len(X))])


def test_owned_node_plies_are_the_contacts(comm):
    problem = _stack_problem(comm)
    owned = problem.n_owned
    assert np.array_equal(owned_node_plies(problem), _node_plies(problem)[:owned])


def test_each_ply_reports_its_own_shear(comm):
    """u_x = tan(gamma_k) Y on ply k: every point of ply k at gamma_k (the law's
    asin(C12 / sqrt(C11 C22)) = atan(tan gamma_k)); ply 1 past the 20 deg locking angle over
    its whole area, ply 0 nowhere."""
    problem = _stack_problem(comm)
    _prescribe(problem, _simple_shear)
    plies = ply_summaries(problem, STACK, LOCKING_DEG, comm)
    areas = [400.0, comm.allreduce(float(np.sum(
        problem.cell_areas[problem.blank_mesh.cell_plies()[: problem.n_cells] == 1])))]
    assert math.isclose(areas[1], math.pi * 8.0 ** 2, rel_tol=0.05)    # the disc, meshed
    for k, ply in enumerate(plies):
        assert ply["ply"] == k and ply["height_mm"] == (0.0, 0.4)[k]
        assert math.isclose(ply["max_shear_angle_deg"], SHEAR_DEG[k], abs_tol=1e-10)
        assert math.isclose(ply["ply_area_mm2"], areas[k], rel_tol=1e-12)
        locked = areas[k] if SHEAR_DEG[k] > LOCKING_DEG else 0.0
        assert math.isclose(ply["area_above_locking_mm2"], locked, rel_tol=1e-12)
        assert math.isclose(ply["fraction_above_locking"], 1.0 if locked else 0.0, rel_tol=1e-12)
        # where: a point of this ply (the disc's within its radius)
        x, y = ply["max_shear_flat_xy_mm"]
        assert (abs(x) <= 10.0 and abs(y) <= 10.0) if k == 0 else math.hypot(x, y) <= 8.0
        assert ply["locking_angle_deg"] == LOCKING_DEG
    cells = comm.allreduce(np.bincount(problem.blank_mesh.cell_plies()[: problem.n_cells],
                                       minlength=2))
    assert [ply["cells"] for ply in plies] == cells.tolist() and cells[0] == 64


def test_a_one_ply_stack_reports_as_todays_blank(comm):
    """One ply under a smooth displacement: its summary is reports.shear_summary's and
    reports.draw_in's for the blank, value for value; no interface, only the ply field."""
    from drape.forming.reports import draw_in, shear_summary
    stack = load_stack({"plies": [{"thickness": 0.3, "orientation": 0.0, "length": 30.0,
                                   "width": 20.0}]})
    problem = _stack_problem(comm, stack)
    _prescribe(problem, lambda X, ply: np.column_stack([
        0.3 * np.sin(X[:, 1] / 4.0) + 0.02 * X[:, 0], -0.01 * X[:, 1] ** 2 / 10.0,
        0.2 * np.cos(X[:, 0] / 5.0)]))
    (ply,) = ply_summaries(problem, stack, LOCKING_DEG, comm)
    today = comm.bcast(shear_summary(problem, 3.0, comm), root=0)
    (low,) = ply_summaries(problem, stack, 3.0, comm)
    assert today["max_shear_angle_deg"] > 3.0 and today["area_above_locking_mm2"] > 0.0
    for key, value in today.items():
        assert low["ply_area_mm2" if key == "blank_area_mm2" else key] == value, key
    assert ply["draw_in_mm"] == draw_in(problem, stack.plies[0].blank(), comm)["draw_in_mm"]
    assert interface_summaries(problem, comm) == []
    assert list(StackFields(problem).functions) == ["ply"]


def test_the_disk_estimate_counts_the_interface_fields(comm):
    """A stack's XDMF fields (the DG0 ``ply``, three P1 fields per interface) add 8 bytes per
    value and a field's XDMF overhead (1600 bytes) to each written step's estimate, and as
    much to the whole run's need per written step (the fields and the checkpoints' copy)."""
    from drape.io.disk import estimate
    from drape.job import JobConfig
    problem = _stack_problem(comm)
    config = JobConfig()
    fields = StackFields(problem)
    assert len(fields.functions) == 4
    nodes = problem.V.dofmap.index_map.size_global
    cells = problem.mesh.topology.index_map(2).size_global
    plain = estimate(problem, config)
    stack = estimate(problem, config, extra_functions=fields.functions.values())
    added = 8 * (cells + 3 * nodes) + 4 * 1600
    assert stack["step"] - plain["step"] == pytest.approx(added / config.output.xdmf_every)
    assert stack["total"] - plain["total"] == pytest.approx(
        2 * plain["steps"] * added / config.output.xdmf_every)


def test_each_ply_gets_its_own_shear_maps(comm, tmp_path):
    """The gathered cells of the prescribed shear: ply k's cells all at gamma_k; each ply's
    maps written (shear_flat_ply{k}.png, shear_formed_ply{k}.png)."""
    from drape.forming.stack_reports import gather_ply_cells, plot_ply_shear_maps
    problem = _stack_problem(comm)
    _prescribe(problem, _simple_shear)
    cells = gather_ply_cells(problem)
    counts = comm.allreduce(np.bincount(problem.blank_mesh.cell_plies()[: problem.n_cells],
                                        minlength=2))
    if comm.rank != 0:
        assert cells is None
        return
    assert np.bincount(cells["ply"]).tolist() == counts.tolist()
    for k, gamma in enumerate(SHEAR_DEG):
        assert np.allclose(np.abs(cells["shear"][cells["ply"] == k]), gamma, rtol=0,
                           atol=1e-10)
    plot_ply_shear_maps(tmp_path, cells, LOCKING_DEG, "two plies")
    written = sorted(path.name for path in tmp_path.glob("*.png"))
    assert written == ["shear_flat_ply0.png", "shear_flat_ply1.png", "shear_formed_ply0.png",
                       "shear_formed_ply1.png"]


def test_the_whole_stack_shear_summary_is_unchanged(comm):
    """shear_summary without a mask: every cell, the largest over both plies."""
    from drape.forming.reports import shear_summary
    problem = _stack_problem(comm)
    _prescribe(problem, _simple_shear)
    whole = comm.bcast(shear_summary(problem, LOCKING_DEG, comm), root=0)
    everything = np.ones(problem.n_cells, dtype=bool)
    masked = comm.bcast(shear_summary(problem, LOCKING_DEG, comm, cells=everything), root=0)
    assert whole == masked
    assert math.isclose(whole["max_shear_angle_deg"], max(SHEAR_DEG), abs_tol=1e-10)


def test_each_ply_reports_its_own_draw_in(comm):
    """Plies translated rigidly by d_k: the draw-in at a point X of ply k's edge is
    -d_k . X / |X| (rectangle: mid-sides and corners; disc: every 45 deg)."""
    from drape.forming.reports import edge_points
    shifts = np.array([[-0.1, 0.05, 0.0], [0.3, -0.2, 0.1]])
    problem = _stack_problem(comm)
    _prescribe(problem, lambda X, ply: shifts[ply])
    plies = ply_summaries(problem, STACK, LOCKING_DEG, comm)
    for k, ply in enumerate(plies):
        points = edge_points(STACK.plies[k].blank())
        assert set(ply["draw_in_mm"]) == set(points) and len(points) == 8
        for name, X in points.items():
            expected = -float(shifts[k, :2] @ np.asarray(X)) / float(np.linalg.norm(X))
            assert math.isclose(ply["draw_in_mm"][name], expected, abs_tol=1e-12), (k, name)
        assert math.isclose(ply["max_shear_angle_deg"], 0.0, abs_tol=1e-6)


def _integral(function):
    """The integral of a scalar function over the stack's reference (mm² times its unit)."""
    import ufl
    from dolfinx import fem
    value = fem.assemble_scalar(fem.form(function * ufl.dx))
    return function.function_space.mesh.comm.allreduce(value)


def _largest(comm, function):
    from mpi4py import MPI
    owned = function.function_space.dofmap.index_map.size_local
    return comm.allreduce(float(function.x.array[:owned].max(initial=0.0)), op=MPI.MAX)


def _h5_fields(folder, comm):
    """On rank 0: {name: [(time, values)]} of fields.h5's functions, and the XDMF text."""
    import h5py
    if comm.rank != 0:
        return None, None
    out = {}
    with h5py.File(folder / "fields.h5", "r") as h5:
        for name, group in h5["Function"].items():
            out[name] = sorted((float(t.replace("_", ".")), np.asarray(data))
                               for t, data in group.items())
    return out, (folder / "fields.xdmf").read_text()


def test_pressed_plies_pulled_over_each_other(comm, tmp_path):
    """Two 20 x 20 mm plies on one 5 mm mesh (5 x 5 nodes each), the upper pressed on the
    held lower one with p = 0.1 MPa, then pulled by Delta = 0.02 mm a step (mu = 0.3, stick
    zone delta = 0.05 mm). At rest the interface carries p A on A = 400 mm², all 50 nodes in
    contact, and penetrates by p / eps_N - g0/2. Sliding by k Delta, the 5 nodes of the upper
    ply's right edge and of the lower ply's left edge lie k Delta beyond the other ply's edge
    (barycentric lambda = -k Delta / 5 mm): each edge's half nodal areas (25 mm²) count times
    the edge ramp 3 s² - 2 s³, s = 1 + lambda / EDGE_RAMP. The friction work is
    sum mu p A min(k Delta / delta, 1) Delta and every node has slipped k Delta. The pressure
    field integrates to twice the normal force (both plies carry it), the slip field to
    2 A Delta, the accumulated slip's largest value is the summary's; the written XDMF has
    them all."""
    from drape.io.writer import ResultsWriter
    smoothing, step, delta = 0.05, 0.02, 0.05
    problem, solver, pulled = _pressed_plies(comm, CONSTANT, smoothing)
    fields = StackFields(problem)
    folder = comm.bcast(tmp_path, root=0)
    writer = ResultsWriter(folder, problem, snapshot="none", extra_fields=fields)
    area, force = 400.0, PRESSURE * 400.0
    work = 0.0
    for k in range(0, 5):
        pulled[0].x.array[:] = k * step
        result = solver.solve()
        assert result.converged, result
        problem.commit(k)
        writer.write_fields(float(k))
        (summary,) = interface_summaries(problem, comm)
        assert summary["interface"] == 0 and summary["plies"] == [0, 1]
        assert summary["nodes_in_contact"] == 50
        # the edge nodes lie k Delta beyond the other ply's edge (lambda = -k Delta / 5 mm)
        s = 1.0 - k * step / (5.0 * EDGE_RAMP)
        ramped = 50.0 * (1.0 - s * s * (3.0 - 2.0 * s))
        assert math.isclose(summary["contact_area_mm2"], area - ramped, rel_tol=1e-6)
        assert math.isclose(summary["normal_force_N"], force, rel_tol=1e-6)
        if k == 0:
            assert math.isclose(summary["max_penetration_mm"],
                                max(0.0, PRESSURE / PENALTY - smoothing / 2), abs_tol=1e-12)
        work += 0.3 * force * min(k * step / delta, 1.0) * step if k else 0.0
        assert math.isclose(summary["friction_work_Nmm"], work, rel_tol=1e-4, abs_tol=1e-12)
        assert math.isclose(summary["max_accumulated_slip_mm"], k * step, rel_tol=1e-5,
                            abs_tol=1e-12)
        functions = fields.functions
        assert math.isclose(_integral(functions["interface0_pressure"]),
                            2 * summary["normal_force_N"], rel_tol=1e-12)
        assert math.isclose(_integral(functions["interface0_slip"]), 2 * area * step * bool(k),
                            rel_tol=1e-4, abs_tol=1e-12)
        assert _largest(comm, functions["interface0_accumulated_slip"]) == \
            summary["max_accumulated_slip_mm"]
        assert math.isclose(_integral(functions["ply"]), area, rel_tol=1e-12)
    solver.close()
    writer.close()
    comm.barrier()
    h5, xdmf = _h5_fields(folder, comm)
    if comm.rank == 0:
        names = {"ply", "interface0_pressure", "interface0_slip", "interface0_accumulated_slip"}
        assert names <= set(h5) and all(f'Name="{name}"' in xdmf for name in names)
        assert [t for t, _ in h5["ply"]] == [0.0, 1.0, 2.0, 3.0, 4.0]
        assert np.bincount(h5["ply"][-1][1].ravel().astype(int)).tolist() == [16, 16]
        pressure = h5["interface0_pressure"][0][1].ravel()
        assert len(pressure) == 50 and np.allclose(pressure, PRESSURE, rtol=1e-9)
        assert np.allclose(h5["interface0_accumulated_slip"][-1][1], 4 * step, rtol=1e-5)


def _by_coordinates(problem, function, comm):
    """{(x, y, ply): value} of a P1 function's owned values, from every rank (the ply of a
    dof from the cells around it)."""
    space = function.function_space
    owned = space.dofmap.index_map.size_local
    cells = space.dofmap.list.array.reshape(-1, space.dofmap.dof_layout.num_dofs)
    plies = np.empty(owned + space.dofmap.index_map.num_ghosts, dtype=int)
    plies[cells.ravel()] = np.repeat(problem.blank_mesh.cell_plies()[: len(cells)],
                                     cells.shape[1])
    xy = space.tabulate_dof_coordinates()[:owned, :2]
    rows = [(round(a, 9), round(b, 9), int(k), float(v))
            for (a, b), k, v in zip(xy, plies[:owned], function.x.array[:owned])]
    return {r[:3]: r[3] for part in comm.allgather(rows) for r in part}


def test_one_rank_equals_two(comm):
    """The summaries and nodal fields of a stack pressed into itself and sheared, one step
    committed, on the distributed mesh and on every rank alone (COMM_SELF)."""
    from mpi4py import MPI
    results = []
    for each in (comm, MPI.COMM_SELF):
        problem = _stack_problem(each)
        problem.ply_contact.set_step_duration(0.5)

        def shear_and_press(X, ply):
            u = _simple_shear(X, ply) * 0.01 + np.column_stack(
                [0.02 * np.sin(X[:, 1] / 3.0), 0.01 * X[:, 0], 0.0 * X[:, 0]])
            u[ply == 1] += [0.07, 0.0, -0.03]
            return u

        _prescribe(problem, shear_and_press)
        problem.begin_step()
        problem.residual(None, problem.u.vector, problem.create_vector())
        problem.commit(1.0)
        fields = StackFields(problem)
        nodal = {name: _by_coordinates(problem, function, each)
                 for name, function in fields.functions.items() if name != "ply"}
        results.append((ply_summaries(problem, STACK, LOCKING_DEG, each),
                        interface_summaries(problem, each), nodal))
    (plies2, interfaces2, nodal2), (plies1, interfaces1, nodal1) = results
    assert interfaces1[0]["nodes_in_contact"] > 20 and interfaces1[0]["friction_work_Nmm"] > 0
    for one, two in zip(plies1 + interfaces1, plies2 + interfaces2):
        assert one.keys() == two.keys()
        for key, value in one.items():
            if isinstance(value, float):
                assert math.isclose(value, two[key], rel_tol=1e-10, abs_tol=1e-12), key
            elif key == "draw_in_mm":
                for name in value:
                    assert math.isclose(value[name], two[key][name], abs_tol=1e-12)
            elif key != "max_shear_flat_xy_mm" and key != "max_shear_formed_xyz_mm":
                assert value == two[key], key
    for name in nodal1:
        assert nodal1[name].keys() == nodal2[name].keys()
        scale = max(1e-12, max(abs(v) for v in nodal1[name].values()))
        for node, value in nodal1[name].items():
            assert abs(value - nodal2[name][node]) <= 1e-10 * scale, (name, node)


@pytest.mark.serial
def test_drape_view_ply_checks_its_argument(tmp_path, capsys):
    from drape import cli, view
    (tmp_path / "fields.xdmf").write_text('<?xml version="1.0"?><Xdmf><Attribute '
                                          'Name="shear_angle_deg"/></Xdmf>')
    (tmp_path / "fields.h5").write_bytes(b"")
    assert cli.main(["view", str(tmp_path), "--ply", "1"]) == 2
    assert "not the results of a stack" in capsys.readouterr().err
    assert cli.main(["view", str(tmp_path), "--ply", "-1"]) == 2
    assert "not a ply" in capsys.readouterr().err
    (tmp_path / "fields.xdmf").write_text('<?xml version="1.0"?><Xdmf><Attribute Name="ply"/>'
                                          '</Xdmf>')
    (tmp_path / "summary.json").write_text('{"plies": [{}, {}]}')
    assert cli.main(["view", str(tmp_path), "--ply", "2"]) == 2
    assert "no ply 2: the stack has 2 plies" in capsys.readouterr().err
    view.check_ply(tmp_path, 1)

    class Args:
        time, ply = None, 1
    assert view.script_arguments(Args, tmp_path, 40.0)[-2:] == ["--ply", "1"]


@pytest.mark.serial
@pytest.mark.slow
@pytest.mark.usefixtures("paraview")
def test_drape_view_shows_one_ply(tmp_path):
    """A stack's fields written by the writer (ply 0 sheared 10 deg, ply 1 30 deg): `drape view
    --ply N --screenshot` shows ply N's cells only (the caption's cell count and largest shear
    are ply N's), without --ply both plies; --ply 2 is refused by ParaView's script (exit 2)."""
    from mpi4py import MPI

    from drape.io.writer import ResultsWriter
    comm = MPI.COMM_SELF
    problem = _stack_problem(comm)
    _prescribe(problem, _simple_shear)
    writer = ResultsWriter(tmp_path, problem, snapshot="none", extra_fields=StackFields(problem))
    writer.write_fields(1.0)
    writer.close()
    cells = np.bincount(problem.blank_mesh.cell_plies()[: problem.n_cells]).tolist()
    for ply, largest, locked, shown in ((0, 10.0, 0, cells[0]), (1, 30.0, cells[1], cells[1]),
                                        (None, 30.0, cells[1], sum(cells))):
        png = tmp_path / f"ply_{ply}.png"
        extra = [] if ply is None else ["--ply", ply]
        done = drape("view", tmp_path, "--screenshot", png, "--locking-angle", LOCKING_DEG,
                     *extra)
        assert done.returncode == 0, done.stderr
        name = tmp_path.name + ("" if ply is None else f" ply {ply}")
        assert f"{name}: t = 1, largest shear angle magnitude {largest:.2f} deg" in done.stdout
        assert f"({locked} of {shown} cells past it)" in done.stdout, done.stdout
        assert png.stat().st_size > 10_000
    done = drape("view", tmp_path, "--screenshot", tmp_path / "none.png", "--ply", 2)
    assert done.returncode == 2 and "no ply 2: the stack has plies 0 to 1" in done.stderr
