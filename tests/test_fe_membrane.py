"""The membrane problem (drape/fe/membrane.py): the Jacobian is the derivative of the residual
(the law's consistent tangent, yarn tension and the geometric stiffness, in 3D), point
contributions enter both as documented, and the regularisation shows up in its own column."""

import csv
import math
import textwrap

import numpy as np
import pytest

from drape.job import BlankConfig, MeshConfig, load_job
from drape.law.nested_surface import LawState, NestedSurfaceLaw
from drape.law.parameters import MaterialParameters
from drape.fe.contributions import PointContribution
from fe_helpers import central_difference, jacobian_action, residual


def _problem(comm, cell="quadrilateral", yarn_angle=0.0, pattern="aligned", contributions=None,
             damping=1e-3, bending=0.0, size=10.0, length=40.0, width=30.0, inertia=False):
    from drape.fe.membrane import MembraneProblem
    from drape.fe.mesh import create_blank_mesh
    blank = BlankConfig(length=length, width=width, yarn_angle=yarn_angle)
    bm = create_blank_mesh(comm, blank, MeshConfig(cell=cell, pattern=pattern, size=size))
    law = NestedSurfaceLaw(MaterialParameters())
    return MembraneProblem(bm, law, yarn_angle, damping, contributions=contributions,
                           bending_rigidity=bending, inertia=inertia)


def _set_displacement(problem, shear_deg=15.0):
    """A homogeneous shear (plastic everywhere from the virgin state) plus a smooth 3D wave."""
    g = math.radians(shear_deg)

    def field(x):
        return np.vstack([(math.cos(g / 2) - 1) * x[0] + math.sin(g / 2) * x[1]
                          + 0.3 * np.sin(x[1] / 7),
                          math.sin(g / 2) * x[0] + (math.cos(g / 2) - 1) * x[1]
                          + 0.2 * np.cos(x[0] / 9),
                          2.0 * np.sin(x[0] / 11) * np.cos(x[1] / 13)])
    problem.u.interpolate(field)
    problem.u.x.scatter_forward()
    return field


@pytest.mark.parametrize("cell, yarn_angle, pattern, bending", [
    ("quadrilateral", 0.0, "aligned", 0.0), ("triangle", 30.0, "free", 0.0),
    ("quadrilateral", 0.0, "aligned", 2.0), ("triangle", 30.0, "free", 2.0)])
def test_jacobian_is_the_derivative_of_the_residual(comm, cell, yarn_angle, pattern, bending):
    problem = _problem(comm, cell, yarn_angle, pattern, bending=bending)
    _set_displacement(problem)
    x = problem.u.vector.copy()
    rng = np.random.default_rng(comm.rank + 7)
    direction = x.duplicate()
    direction.array[:] = rng.standard_normal(direction.array.shape)
    action = jacobian_action(problem, x, direction)
    assert np.all(problem.response.active_surface >= 0)        # plastic at every point
    difference = central_difference(problem, x, direction)
    error = difference.copy()
    error.axpy(-1.0, action)
    # the same Jacobian without the law's shear tangent: what the law contributes
    problem.dtau.x.array[:] = 0.0
    from dolfinx.fem import petsc as fpetsc
    A = problem.create_matrix()
    fpetsc.assemble_matrix(A, problem.jacobian_form)
    A.assemble()
    shear = A.createVecLeft()
    A.mult(direction, shear)
    shear.axpy(-1.0, action)
    print(f"|J d| = {action.norm():.4g}, |law's shear part| = {shear.norm():.4g}, "
          f"|FD - J d| = {error.norm():.3g}")
    assert error.norm() <= 1e-8 * action.norm()
    assert error.norm() <= 1e-3 * shear.norm()


def test_inertia_term_is_k_m_times_the_lag_behind_the_anchor(comm):
    """With inertia the residual gains k_m (u - u_anchor) per unit area: a rigid translation c
    off the anchor (no strain, so no internal force) gives a total force k_m c A, the
    regularisation work 1/2 k_m |c|^2 A, and the Jacobian (k_m times the mass matrix) the
    finite differences of the residual, on top of a strained state."""
    k_m, c, area = 2.5, np.array([0.3, -0.2, 0.5]), 40.0 * 30.0
    problem = _problem(comm, damping=0.0, inertia=True)
    problem.inertia_constant.value = k_m
    problem.u_anchor.x.array[:] = np.tile([1.0, 2.0, -3.0], problem.u.x.array.size // 3)
    problem.u.x.array[:] = problem.u_anchor.x.array + np.tile(c, problem.u.x.array.size // 3)
    b = residual(problem, problem.u.vector)
    n_owned = problem.V.dofmap.index_map.size_local
    totals = comm.allreduce(b.array[: 3 * n_owned].reshape(-1, 3).sum(axis=0))
    assert totals == pytest.approx(k_m * c * area, rel=1e-12)
    assert problem.regularisation_work() == pytest.approx(0.5 * k_m * (c @ c) * area, rel=1e-12)

    _set_displacement(problem)
    x = problem.u.vector.copy()
    direction = x.duplicate()
    direction.array[:] = np.random.default_rng(comm.rank + 3).standard_normal(x.array.shape)
    action = jacobian_action(problem, x, direction)
    difference = central_difference(problem, x, direction)
    difference.axpy(-1.0, action)
    assert difference.norm() <= 1e-8 * action.norm()


class PlaneSpring(PointContribution):
    """f = -k (x3 - a x1 - z0) e3 per unit area: a spring pulling towards a tilted plane."""

    name = "plane spring"

    def __init__(self, k, a, z0):
        self.k, self.a, self.z0 = k, a, z0

    def evaluate(self, positions, displacements):
        force = np.zeros_like(positions)
        force[:, 2] = -self.k * (positions[:, 2] - self.a * positions[:, 0] - self.z0)
        stiffness = np.zeros((len(positions), 3, 3))
        stiffness[:, 2, 2] = self.k
        stiffness[:, 2, 0] = -self.k * self.a
        return force, stiffness


def test_point_contributions_enter_residual_and_jacobian(comm):
    import ufl
    from dolfinx import fem
    from dolfinx.fem import petsc as fpetsc
    from petsc4py import PETSc

    k, a, z0 = 0.7, 0.05, 1.5
    plain = _problem(comm)
    spring = _problem(comm, contributions=[PlaneSpring(k, a, z0)])
    for problem in (plain, spring):
        _set_displacement(problem)
    x = spring.u.vector.copy()
    difference = residual(spring, x)
    difference.axpy(-1.0, residual(plain, x))
    # the same spring written in UFL, at the same (degree 2) quadrature
    u, v = spring.u, ufl.TestFunction(spring.V)
    X = ufl.SpatialCoordinate(spring.mesh)
    dx = ufl.dx(metadata={"quadrature_degree": 2})
    gap = u[2] - a * (X[0] + u[0]) - z0
    expected = fpetsc.assemble_vector(fem.form(k * gap * v[2] * dx))
    expected.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    assert expected.norm() > 1.0
    expected.axpy(-1.0, difference)
    assert expected.norm() <= 1e-10 * difference.norm()
    # Jacobians: the difference is the derivative of the spring term
    direction = x.duplicate()
    direction.array[:] = np.random.default_rng(comm.rank).standard_normal(direction.array.shape)
    jd = jacobian_action(spring, x, direction)
    jd.axpy(-1.0, jacobian_action(plain, x, direction))
    K = fpetsc.assemble_matrix(fem.form(ufl.derivative(k * gap * v[2] * dx, u,
                                                       ufl.TrialFunction(spring.V))))
    K.assemble()
    kd = K.createVecLeft()
    K.mult(direction, kd)
    kd.axpy(-1.0, jd)
    assert kd.norm() <= 1e-10 * jd.norm()


LIFT = """
    title = "a strip lifted at one end: a zero-energy rotation that only the damping resists"
    [blank]
    length = 100.0
    width = 20.0
    [mesh]
    size = 5.0
    [steps]
    initial = 0.05
    maximum = 0.1
    [output]
    xdmf = false
    [history.phi]
    values = [0.0, 20.0]
    [[boundary]]
    on = "left"
    ux = "0"
    uy = "0"
    uz = "0"
    [[boundary]]
    on = "right"
    ux = "100 * (cos(radians(phi)) - 1)"
    uy = "0"
    uz = "100 * sin(radians(phi))"
"""


def test_regularisation_work_is_reported_and_its_effect_shrinks_with_the_damping(comm, shared_tmp):
    """Lifting one end of a strip rotates it rigidly (no strain, no stress): only the damping of
    u_z resists the interior nodes. The share column reports that most of the work goes into
    the damping, and the deviation from the rigid rotation shrinks with the damping constant."""
    from drape.run import run_job
    path = shared_tmp / "lift.toml"
    if comm.rank == 0:
        path.write_text(textwrap.dedent(LIFT))
    comm.barrier()
    deviation, share = {}, {}
    for k in (1e-1, 1e-3):
        job = load_job(path, overrides=[f"regularisation.out_of_plane_damping={k}"])
        summary = run_job(job, comm, output=shared_tmp / f"lift_{k}")
        problem_rows = summary.rows
        share[k] = problem_rows[-1].regularisation_share
        assert problem_rows[-1].regularisation_work > 0.0
        if comm.rank == 0:
            data = np.load(shared_tmp / f"lift_{k}" / "result.npz")
            x = data["node_xy"][:, 0]
            phi = math.radians(20.0)
            rigid = np.column_stack([x * (math.cos(phi) - 1), 0 * x, x * math.sin(phi)])
            deviation[k] = np.abs(data["u"] - rigid).max()
            rows = list(csv.DictReader(open(shared_tmp / f"lift_{k}" / "steps.csv")))
            assert float(rows[-1]["regularisation_share"]) == pytest.approx(share[k])
    assert 0.3 < share[1e-3] < 0.8           # the damping does much of the work here, and says so
    if comm.rank == 0:
        assert deviation[1e-3] < 0.2 * deviation[1e-1]
        assert deviation[1e-3] < 1.0     # mm, on a 100 mm strip


def _bend_into_cylinder(problem, radius, angle_deg=0.0):
    """u such that the blank, turned by angle_deg about z, wraps a cylinder of radius R whose
    axis is along the turned y axis; then turned back: x = R sin(s/R), z = R (1 - cos(s/R))."""
    a = math.radians(angle_deg)
    c, sn = math.cos(a), math.sin(a)

    def field(x):
        s_ = c * x[0] + sn * x[1]                # arc length across the cylinder's axis
        t_ = -sn * x[0] + c * x[1]               # along the axis
        xs, zs = radius * np.sin(s_ / radius), radius * (1 - np.cos(s_ / radius))
        return np.vstack([c * xs - sn * t_ - x[0], sn * xs + c * t_ - x[1], zs])
    problem.u.interpolate(field)
    problem.u.x.scatter_forward()


@pytest.mark.parametrize("cell", ["quadrilateral", "triangle"])
def test_bending_energy_of_a_cylinder_is_the_plate_energy(comm, cell):
    """Wrapped (without stretching) around a cylinder of radius R across the x yarns, an aligned
    mesh of size h has flat elements, and each of its Nx - 1 interior edges along y is a hinge of
    angle h / R: W_b = (Nx - 1) B / (2 h) (2 sin(h / 2R))^2 L_y exactly, which tends to the
    plate's B / (2 R^2) times the area but for the boundary strip (relative h / L_x). A flat
    blank moved rigidly (turned and lifted) has none, and no bending residual."""
    B, R, Lx, Ly = 1.5, 40.0, 40.0, 30.0
    for size in (5.0, 2.5):
        problem = _problem(comm, cell, bending=B, size=size, damping=0.0)
        _bend_into_cylinder(problem, R)
        n_x = round(Lx / size)
        hinges = (n_x - 1) * B / (2 * size) * (2 * math.sin(size / (2 * R))) ** 2 * Ly
        plate = 0.5 * B / R ** 2 * (Lx - size) * Ly
        energy = problem.bending_energy()
        print(f"h = {size}: W_b = {energy:.6g}, hinges {hinges:.6g}, plate {plate:.6g} N mm")
        assert energy == pytest.approx(hinges, rel=1e-9)
        assert energy == pytest.approx(plate, rel=(size / R) ** 2)
    problem = _problem(comm, cell, bending=B, size=5.0, damping=0.0)
    th = math.radians(35.0)
    rotation = np.array([[1, 0, 0], [0, math.cos(th), -math.sin(th)],
                         [0, math.sin(th), math.cos(th)]])
    problem.u.interpolate(lambda x: (rotation @ x) - x + np.array([[3.0], [-2.0], [5.0]]))
    problem.u.x.scatter_forward()
    assert abs(problem.bending_energy()) < 1e-12
    with_bending = residual(problem, problem.u.vector)
    without = residual(_moved_like(problem, comm, cell), problem.u.vector)
    with_bending.axpy(-1.0, without)
    assert with_bending.norm() < 1e-10


def _moved_like(problem, comm, cell):
    other = _problem(comm, cell, bending=0.0, size=5.0, damping=0.0)
    other.u.x.array[:] = problem.u.x.array
    return other


@pytest.mark.parametrize("cell", ["quadrilateral", "triangle"])
def test_the_block_jacobian_is_the_aij_one(comm, cell):
    """The direct solver assembles into 3x3 blocks (BAIJ); with the bending hinges'
    interior-facet form and a clamped edge (the diagonal DOLFINx puts on its rows) the block
    matrix acts as the entry-by-entry one does."""
    from dolfinx import fem, mesh
    problem = _problem(comm, cell, 30.0 if cell == "triangle" else 0.0,
                       "free" if cell == "triangle" else "aligned", bending=2.0)
    _set_displacement(problem)
    msh = problem.V.mesh
    left = mesh.locate_entities_boundary(msh, 1, lambda x: np.isclose(x[0], x[0].min()))
    clamped = fem.locate_dofs_topological(problem.V, 1, left)
    problem.bcs = [fem.dirichletbc(np.zeros(3), clamped, problem.V)]
    x = problem.u.vector.copy()
    rng = np.random.default_rng(comm.rank + 3)
    direction = x.duplicate()
    direction.array[:] = rng.standard_normal(direction.array.shape)
    actions = {}
    for mat_type in (None, "baij"):
        A = problem.create_matrix(mat_type)
        problem.jacobian(None, x, A, A)
        assert A.getType().endswith("baij" if mat_type else "aij")
        actions[mat_type] = A.createVecLeft()
        A.mult(direction, actions[mat_type])
    difference = actions["baij"].copy()
    difference.axpy(-1.0, actions[None])
    assert actions[None].norm() > 0.0
    assert difference.norm() <= 1e-13 * actions[None].norm()


def test_newtons_shear_tangent_is_stiffened_only_near_neutral_loading():
    """solver.neutral_loading_band: a law point that this increment loads only just past its
    elastic range gets sqrt(2 mu Ksh * consistent) in Newton's Jacobian; a point loaded well
    past it, or unloading (elastic), keeps the law's consistent tangent; band 0 changes
    nothing. The points come from the law itself: sheared to 3 deg (plastic), committed, then
    loaded on by 1e-7 and by 1e-2 in C12, and unloaded by 1e-5 (within the innermost
    surface: elastic)."""
    from drape.fe.newton_tangent import neutral_loading_tangent
    law = NestedSurfaceLaw(MaterialParameters())
    one = np.ones(3)
    state = LawState.virgin(3, law.n)
    c12 = math.sin(math.radians(3.0))
    state = law.update(state, one, one, np.full(3, c12)).trial
    on = law.update(state, one, one, c12 + np.array([1e-7, 1e-2, -1e-5]))
    increment = on.trial.gamma_p - state.gamma_p
    plastic = on.active_surface >= 0
    assert list(plastic) == [True, True, False]
    assert 0.0 < increment[0] < 1e-6 and increment[1] > 1e-3 and increment[2] == 0.0
    elastic = 2.0 * law.params.mu * law.params.Ksh     # 284 N/mm
    assert on.dtau_dC12[0] < elastic / 20.0 and on.dtau_dC12[2] == pytest.approx(elastic)
    blended = neutral_loading_tangent(on.dtau_dC12, plastic, increment, elastic, 1e-4)
    assert blended[0] == pytest.approx(math.sqrt(elastic * on.dtau_dC12[0]), rel=1e-14)
    assert on.dtau_dC12[0] < blended[0] < elastic
    assert list(blended[1:]) == list(on.dtau_dC12[1:])
    assert list(neutral_loading_tangent(on.dtau_dC12, plastic, increment, elastic, 0.0)) == list(
        on.dtau_dC12)
