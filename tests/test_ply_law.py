"""Per-ply yarn frame and material (drape/fe/membrane.py with one law and one yarn angle per
ply, drape/law/piecewise.py, drape/forming/plies.py's ply_materials): two flat plies of one
stack under the same homogeneous deformation each give the closed form at their own angle with
their own law (the yarn-frame C of F, the law run on one point) and the internal forces of the
single-ply problem of that angle and material; the Jacobian is the derivative of the residual;
plies sharing the law and angle give today's problem bit for bit."""

import dataclasses
import math

import numpy as np
import pytest

from drape.forming.plies import load_stack, ply_materials
from drape.job import BlankConfig, MeshConfig
from drape.law.nested_surface import LawState, NestedSurfaceLaw
from drape.law.parameters import MaterialParameters, load_material, material_toml
from conftest import CONFIGS
from fe_helpers import central_difference, jacobian_action, residual

I32 = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])
#: two homogeneous deformations (3 x 2): a shear of 12 deg in the x-y frame with some stretch
#: and tilt, then one of 25 deg (plastic at every yarn angle from the first)
DEFORMATIONS = (np.array([[1.004, 0.21], [0.003, 0.998], [0.02, -0.01]]),
                np.array([[1.01, 0.45], [0.015, 0.99], [0.05, 0.03]]))
SQUARE = dict(length=20.0, width=16.0)
MESH = MeshConfig(size=4.0)


def _laws(*files):
    return [NestedSurfaceLaw(load_material(CONFIGS / "materials" / name)) for name in files]


#: a stiffer, one-surface material: other K1, K2, mu and number of surfaces than the paper's
STIFF = dataclasses.replace(load_material(CONFIGS / "materials" / "paper_one_surface.toml"),
                            name="stiff", K1=6000.0, K2=9000.0, mu=1.5)


def _stack(comm, angles):
    from drape.fe.stack_mesh import create_stack_mesh
    blanks = [BlankConfig(**SQUARE, yarn_angle=a) for a in angles]
    return create_stack_mesh(comm, blanks, [0.4 * k for k in range(len(angles))],
                             [0.4] * len(angles), MESH, centred=True)


def test_a_piecewise_law_is_each_law_on_its_own_points():
    """PiecewiseLaw (numpy): three laws (three, one and three surfaces) over interleaved points,
    two increments from the virgin state, against each law run on its points alone; one piece
    is the law itself, value for value."""
    from drape.law.piecewise import PiecewiseLaw
    laws = _laws("paper_three_surface.toml", "paper_one_surface.toml", "cao2008_plain_weave.toml")
    rng = np.random.default_rng(5)
    piece = rng.integers(0, 3, size=60)
    increments = [(1.0 + 0.02 * rng.standard_normal(60), 1.0 + 0.02 * rng.standard_normal(60),
                   s * rng.uniform(0.1, 0.5, 60)) for s in (1.0, -0.5)]
    law = PiecewiseLaw(laws, piece)
    assert law.n == 2 and np.array_equal(law.virgin().active, np.where(piece == 1, 0, 2))
    state, alone = law.virgin(), [LawState.virgin(int(np.sum(piece == k)), l.n)
                                  for k, l in enumerate(laws)]
    for C in increments:
        response = law.update(state, *C)
        for k, own in enumerate(laws):
            mine = piece == k
            expected = own.update(alone[k], *(c[mine] for c in C))
            for name in ("tau", "dtau_dC12", "S11", "S22", "gamma_t_deg", "active_surface"):
                assert np.array_equal(getattr(response, name)[mine], getattr(expected, name))
            for name in ("gamma_p", "active", "direction", "row", "C"):
                assert np.array_equal(getattr(response.trial, name)[..., mine],
                                      getattr(expected.trial, name))
            assert np.array_equal(response.trial.centres[: own.n, mine], expected.trial.centres)
            assert np.all(response.trial.centres[own.n:, mine] == 0.0)
            alone[k] = expected.trial
        state = response.trial
    assert np.any(response.active_surface >= 0) and np.any(response.trial.direction < 0)
    one = PiecewiseLaw(laws[:1], np.zeros(60))
    for name in ("tau", "dtau_dC12", "gamma_t_deg"):
        assert np.array_equal(getattr(one.update(one.virgin(), *increments[0]), name),
                              getattr(laws[0].update(LawState.virgin(60, 2), *increments[0]),
                                      name))


def _single(comm, angle, law):
    from drape.fe.membrane import MembraneProblem
    from drape.fe.mesh import create_blank_mesh
    mesh = create_blank_mesh(comm, BlankConfig(**SQUARE, yarn_angle=angle), MESH, centred=True)
    return MembraneProblem(mesh, law, angle, 1e-3)


def _deform(problem, F):
    """u = (F - I32) X."""
    problem.u.interpolate(lambda x: (F - I32) @ x[:2])
    problem.u.x.scatter_forward()


def _two_increments(problem):
    """The first deformation, committed, then the second evaluated."""
    for k, F in enumerate(DEFORMATIONS):
        if k:
            problem.commit()
        _deform(problem, F)
        problem.evaluate()


def _closed_form(law, angle):
    """tau, S11, S22, gamma_t, gamma_p of one point at yarn angle ``angle`` after both
    deformations: C = F^T F in the yarn frame (G1, G2) and the law run on that point alone."""
    theta = math.radians(angle)
    G1, G2 = np.array([math.cos(theta), math.sin(theta)]), np.array([-math.sin(theta),
                                                                      math.cos(theta)])
    state = LawState.virgin(1, law.n)
    for F in DEFORMATIONS:
        C = F.T @ F
        r = law.update(state, [G1 @ C @ G1], [G2 @ C @ G2], [G1 @ C @ G2])
        state = r.trial
    return np.array([r.tau[0], r.S11[0], r.S22[0], r.gamma_t_deg[0], r.trial.gamma_p[0]])


def _point_values(problem):
    """(ply, values (P, 5)) of the local law points: tau, S11, S22, gamma_t, gamma_p."""
    r = problem.response
    ply = np.repeat(problem.cell_ply[: problem.n_cells], problem.nq)
    return ply, np.column_stack([r.tau, r.S11, r.S22, r.gamma_t_deg, r.trial.gamma_p])


def _by_node(problem, vector):
    """{(x, y, ply): values (3,)} of a PETSc vector's owned nodes, from every rank."""
    V = problem.V
    n_owned = V.dofmap.index_map.size_local
    nv = V.dofmap.dof_layout.num_dofs
    node_ply = np.zeros(n_owned + V.dofmap.index_map.num_ghosts, dtype=int)
    node_ply[V.dofmap.list.array] = np.repeat(problem.cell_ply[: len(V.dofmap.list.array) // nv],
                                              nv)
    xy = V.tabulate_dof_coordinates()[:n_owned, :2]
    values = vector.array.reshape(-1, 3)[:n_owned]
    rows = [(round(a, 9), round(b, 9), int(k), tuple(v))
            for (a, b), k, v in zip(xy, node_ply, values)]
    rows = [r for part in problem.comm.allgather(rows) for r in part]
    return {r[:3]: np.array(r[3]) for r in rows}


def _check_plies_against_single(comm, angles, laws):
    """Each ply of the stack (angles, laws) against the closed form at its points and the
    single-ply problem of its angle and law at its nodes; returns the largest relative
    difference of the nodal forces."""
    from drape.fe.membrane import MembraneProblem
    stack = MembraneProblem(_stack(comm, angles), laws, angles, 1e-3)
    _two_increments(stack)
    ply, values = _point_values(stack)
    forces = _by_node(stack, stack.internal_force())
    worst = 0.0
    for k, (angle, law) in enumerate(zip(angles, laws)):
        expected = _closed_form(law, angle)
        scale = np.abs(expected) + [1e-3, 1.0, 1.0, 1e-3, 1e-6]
        assert np.all(np.abs(values[ply == k] - expected) <= 1e-10 * scale)
        single = _single(comm, angle, law)
        _two_increments(single)
        own = _by_node(single, single.internal_force())
        mine = {key[:2]: value for key, value in forces.items() if key[2] == k}
        assert mine.keys() == {key[:2] for key in own}
        largest = max(np.abs(v).max() for v in own.values())
        for key, value in own.items():
            worst = max(worst, np.abs(mine[key[:2]] - value).max() / largest)
    print(f"plies at {angles} deg: largest nodal force difference {worst:.2g} of the largest")
    assert worst <= 1e-12
    return stack


def test_plies_at_0_and_45_deg_each_give_their_own_angle(comm):
    """Shear of the x-y frame is yarn shear at 0 deg and mostly yarn stretch at 45 deg: the two
    plies differ, and each equals its own closed form and single-ply problem."""
    law = NestedSurfaceLaw(MaterialParameters())
    stack = _check_plies_against_single(comm, (0.0, 45.0), [law, law])
    assert stack.law is law and stack.yarn_angle_deg is None
    at_0, at_45 = _closed_form(law, 0.0), _closed_form(law, 45.0)
    assert abs(at_0[3]) > 20.0 and abs(at_45[3]) < 5.0          # gamma_t (deg)
    assert abs(at_45[1] - at_45[2]) > 100.0                     # S11 != S22 at 45 deg


@pytest.mark.parametrize("other", ["paper_one_surface.toml", "cao2008_plain_weave.toml",
                                   "stiff"])
def test_plies_of_two_materials_each_give_their_own(comm, other):
    """The paper's three surfaces below another material (fewer surfaces; other tables; other
    yarn stiffness and mu), at 0 and at -45 deg."""
    laws = _laws("paper_three_surface.toml") + (
        [NestedSurfaceLaw(STIFF)] if other == "stiff" else _laws(other))
    for angles in ((0.0, 0.0), (0.0, -45.0)):
        stack = _check_plies_against_single(comm, angles, laws)
        assert stack.point_law.n == 2 and stack.law is stack.point_law
        # the points' state has the three-surface law's two centres; the other ply's unused
        # ones stay at the virgin state's zero, its active surface counted on its own law
        state = stack.response.trial
        ply = np.repeat(stack.cell_ply[: stack.n_cells], stack.nq)
        assert np.all(state.centres[laws[1].n:, ply == 1] == 0.0)
        assert np.all(state.active[ply == 1] <= laws[1].n)


def test_the_jacobian_of_plies_with_their_own_angle_and_law(comm):
    """Central differences of the residual (a 3D wave on a sheared state, plastic at every
    point) against the Jacobian, two plies at -45 and 90 deg with the paper's and the stiff
    one-surface law."""
    from drape.fe.membrane import MembraneProblem
    angles = (-45.0, 90.0)
    problem = MembraneProblem(_stack(comm, angles), [NestedSurfaceLaw(MaterialParameters()),
                                                     NestedSurfaceLaw(STIFF)], angles, 1e-3)
    problem.u.interpolate(lambda x: np.vstack([0.25 * x[1] + 0.3 * np.sin(x[1] / 7),
                                               0.2 * np.cos(x[0] / 9),
                                               2.0 * np.sin(x[0] / 11) * np.cos(x[1] / 13)]))
    problem.u.x.scatter_forward()
    x = problem.u.vector.copy()
    direction = x.duplicate()
    direction.array[:] = np.random.default_rng(comm.rank + 3).standard_normal(
        direction.array.shape)
    action = jacobian_action(problem, x, direction)
    assert comm.allreduce(int(np.sum(problem.response.active_surface < 0))) == 0
    error = central_difference(problem, x, direction)
    error.axpy(-1.0, action)
    print(f"|FD - J d| / |J d| = {error.norm() / action.norm():.2g}")
    assert error.norm() <= 1e-8 * action.norm()


def test_plies_sharing_law_and_angle_are_todays_problem_bit_for_bit(comm):
    """Two plies, each given its own (equal) law and the same angle: residual and Jacobian
    action equal those of the problem given one law and one angle, value for value."""
    from drape.fe.membrane import MembraneProblem
    mesh = _stack(comm, (45.0, 45.0))
    params = load_material(CONFIGS / "materials" / "cao2008_plain_weave.toml")
    per_ply = MembraneProblem(mesh, [NestedSurfaceLaw(params), NestedSurfaceLaw(params)],
                              [45.0, 45.0], 1e-3)
    plain = MembraneProblem(mesh, NestedSurfaceLaw(params), 45.0, 1e-3)
    vectors = []
    for problem in (per_ply, plain):
        _deform(problem, DEFORMATIONS[0])
        problem.evaluate()
        problem.commit()
        problem.u.interpolate(lambda x: np.vstack([0.2 * x[1] + 0.05 * np.sin(x[1] / 3),
                                                   0.02 * x[0], 0.1 * np.cos(x[0] / 4)]))
        problem.u.x.scatter_forward()
        x = problem.u.vector.copy()
        direction = x.duplicate()
        direction.array[:] = np.cos(np.arange(len(direction.array)) + comm.rank)
        vectors.append((residual(problem, x).array.copy(),
                        jacobian_action(problem, x, direction).array.copy(),
                        problem.yarn_strains()))
    assert per_ply.uniform_law and per_ply.yarn_angle_deg == 45.0
    for mine, today in zip(*vectors):
        assert np.array_equal(mine, today)


def test_ply_materials_and_the_stiffest_plys_penalty(comm, tmp_path):
    """ply_materials: a ply's file relative to the job's folder, else the job's material, the
    job's surfaces applied; create_stack_problem: every ply's law and orientation, the penalty
    of the stiffest ply's yarns, a missing file named by its key."""
    from drape.errors import InputError
    from drape.fe.stack_problem import create_stack_problem
    from drape.forming.contact import ContactParameters
    (tmp_path / "stiff.toml").write_text(material_toml(STIFF))
    stack = load_stack({"plies": [{"thickness": 0.3, **SQUARE, "orientation": 45.0},
                                  {"thickness": 0.3, **SQUARE, "material": "stiff.toml"},
                                  {"thickness": 0.3, **SQUARE, "orientation": -45.0,
                                   "material": "stiff.toml"}]})
    job = MaterialParameters()
    params = ply_materials(stack, job, tmp_path)
    assert params[0] is job and params[1] is params[2] and params[1] == STIFF
    assert ply_materials(stack, job, tmp_path, surfaces=0)[1] == STIFF      # n = 0 already
    with pytest.raises(InputError, match="surfaces"):
        ply_materials(stack, job, tmp_path, surfaces=1)
    with pytest.raises(InputError, match=r"plies\[1\]\.material"):
        ply_materials(stack, job, tmp_path / "elsewhere")
    laws = [NestedSurfaceLaw(p) for p in params]
    problem = create_stack_problem(comm, stack, MESH, ContactParameters(), laws[0], 1e-3,
                                   ply_laws=laws)
    assert problem.yarn_angles_deg == (45.0, 0.0, -45.0) and problem.laws == tuple(laws)
    # the tools' rule eps = c mu K_max / h^2 (c = 1 by default), with the stiff ply's 1.5 * 9000
    assert problem.ply_contact.penalty == 1.5 * 9000.0 / MESH.size ** 2
    same = create_stack_problem(comm, stack, MESH, ContactParameters(), laws[0], 1e-3)
    assert same.laws == (laws[0],) * 3 and same.ply_contact.penalty == 10000.0 / MESH.size ** 2


def test_the_jacobian_of_a_pressed_stack_with_its_own_angles_and_laws(comm):
    """create_stack_problem with plies at 45 and 0 deg, the paper's and the stiff law, the
    upper ply pressed into the lower and shifted: the contact's and the per-ply membrane's
    Jacobian together against central differences of the residual."""
    from drape.fe.stack_problem import create_stack_problem
    from drape.forming.contact import ContactParameters
    stack = load_stack({"plies": [{"thickness": 0.4, **SQUARE, "orientation": 45.0},
                                  {"thickness": 0.4, "shape": "disc", "radius": 7.0}]})
    laws = [NestedSurfaceLaw(MaterialParameters()), NestedSurfaceLaw(STIFF)]
    problem = create_stack_problem(comm, stack, MESH, ContactParameters(), laws[0], 1e-3,
                                   ply_laws=laws)
    problem.u.interpolate(lambda x: np.vstack([0.05 * np.sin(x[1] / 3 + 1) + 0.02 * x[0],
                                               0.04 * np.cos(x[0] / 4),
                                               0.03 * np.sin(x[0] / 5) * np.cos(x[1] / 6)]))
    values = problem.u.x.array.reshape(-1, 3)
    values[problem.ply_contact.nodes.ply[problem.global_nodes] == 1] += [0.07, 0.0, -0.03]
    problem.u.x.scatter_forward()
    problem.begin_step()
    x = problem.u.vector.copy()
    direction = x.duplicate()
    direction.array[:] = np.random.default_rng(comm.rank).normal(size=direction.array.shape)
    action = jacobian_action(problem, x, direction)
    pairs = comm.allreduce(problem.ply_contact.counts["pairs"])
    error = central_difference(problem, x, direction)
    error.axpy(-1.0, action)
    print(f"{pairs} pairs, |FD - J d| / |J d| = {error.norm() / action.norm():.2g}")
    assert pairs > 20
    assert error.norm() <= 1e-8 * action.norm()
