"""The stack of plies (drape/forming/plies.py, drape/fe/stack_mesh.py) and the ply-ply contact
(drape/forming/ply_contact.py, drape/fe/stack_problem.py): the interface's Jacobian against
central differences of its forces, friction plateauing at mu p A (constant and pressure/rate-
dependent mu), the gap under a pressure against the penalty's inverse, 1 rank against 2, and
a one-ply stack against today's blank."""

import math

import numpy as np
import pytest

from drape.config import from_mapping
from drape.errors import InputError
from drape.forming.contact import gap_for_pressure
from drape.forming.plies import PlyConfig, StackConfig, load_stack, ply_heights, single_ply_stack
from drape.forming.ply_contact import PlyContact
from drape.forming.ply_pair import FrictionLaw
from drape.forming.ply_surfaces import StackNodes, split_cells
from drape.job import BlankConfig, MeshConfig
from fe_helpers import central_difference, jacobian_action, residual

CONSTANT = FrictionLaw(0.3)
#: mu = 0.3 (1 + p/0.5)^-0.6 (1 + v/2)^0.3
DEPENDENT = FrictionLaw(0.3, reference_pressure=0.5, pressure_exponent=0.6,
                        reference_slip_rate=2.0, rate_exponent=0.3)
#: a square ply under a shifted, slanted quadrilateral one: no node over another's
SQUARE = BlankConfig(length=20.0, width=20.0)
SLANTED = BlankConfig(shape="polygon", points=((-6.3, -5.1), (7.2, -5.4), (6.9, 7.3),
                                               (-5.8, 6.7)))


# --- the stack's data --------------------------------------------------------------------------

def test_plies_and_interfaces_are_read_and_checked():
    stack = load_stack({"plies": [{"thickness": 0.3, "orientation": 45.0},
                                  {"thickness": 0.5, "shape": "disc", "radius": 30.0}],
                        "interfaces": [{"friction": 0.25, "pressure_exponent": 0.5}]})
    assert stack.heights() == (0.0, 0.4)
    assert ply_heights([0.2, 0.4, 0.6]) == (0.0, 0.30000000000000004, 0.8)
    assert stack.plies[1].blank() == BlankConfig(shape="disc", radius=30.0)
    assert stack.interface_list()[0].friction == 0.25
    assert len(load_stack({"plies": [{"thickness": 1.0}] * 3}).interface_list()) == 2
    bad = [({"plies": [{"orientation": 0.0}]}, "plies[0].thickness"),
           ({"plies": [{"thickness": 0.3, "orientation": 95.0}]}, "plies[0].orientation"),
           ({"plies": [{"thickness": 0.3}, {"thickness": 0.3, "shape": "polygon",
                                            "points": [[0, 0], [1, 1], [1, 0], [0, 1]]}]},
            "plies[1].points"),
           ({"plies": [{"thickness": 0.3}] * 3, "interfaces": [{"friction": 0.2}]},
            "interfaces"),
           ({"plies": [{"thickness": 0.3}] * 2, "interfaces": [{"friction": -0.2}]},
            "interfaces[0].friction"),
           ({"plies": []}, "plies")]
    for data, key in bad:
        with pytest.raises(InputError) as caught:
            load_stack(data, source="job.toml")
        assert caught.value.key == key, (data, caught.value)


def test_a_one_ply_stack_is_todays_blank():
    for blank in (SQUARE, BlankConfig(shape="disc", radius=40.0, yarn_angle=30.0), SLANTED):
        stack = single_ply_stack(blank, thickness=0.3)
        assert stack.plies[0].blank() == blank
        assert stack.heights() == (0.0,) and stack.interface_list() == ()
        assert from_mapping(PlyConfig, {"thickness": 0.3, "orientation": blank.yarn_angle,
                                        "shape": blank.shape, "length": blank.length,
                                        "width": blank.width, "radius": blank.radius,
                                        "points": [list(p) for p in blank.points]}
                            ).blank() == blank
    assert isinstance(stack, StackConfig)


def test_a_one_ply_stack_mesh_is_todays_blank_mesh(comm):
    from drape.fe.mesh import create_blank_mesh
    from drape.fe.stack_mesh import create_stack_mesh
    for blank in (BlankConfig(length=40.0, width=40.0, yarn_angle=45.0),
                  BlankConfig(shape="disc", radius=20.0, yarn_angle=30.0)):
        mesh_config = MeshConfig(size=5.0)
        today = create_blank_mesh(comm, blank, mesh_config, centred=True)
        stack = create_stack_mesh(comm, [blank], (0.0,), (0.3,), mesh_config, centred=True)
        assert np.array_equal(today.mesh.geometry.x, stack.mesh.geometry.x)
        assert np.array_equal(today.mesh.geometry.dofmap.array, stack.mesh.geometry.dofmap.array)
        assert np.array_equal(today.strip_cells, stack.strip_cells)
        assert np.array_equal(today.facet_tags.indices, stack.facet_tags.indices)
        assert np.array_equal(today.facet_tags.values, stack.facet_tags.values)
        assert today.description == stack.description
        assert {k: v for k, v in stack.boundaries.items() if "." not in k} == today.boundaries
        assert set(stack.cell_plies()) == {0}


def test_plies_are_disconnected_pieces_tagged_by_ply(comm):
    from drape.fe.stack_mesh import create_stack_mesh
    mesh = create_stack_mesh(comm, [SQUARE, SLANTED], (0.0, 0.4), (0.4, 0.4), MeshConfig(size=2.5),
                             centred=True)
    plies = mesh.cell_plies()
    n = mesh.mesh.topology.index_map(2).size_local
    assert comm.allreduce(np.bincount(plies[:n], minlength=2)).tolist() == [64, 21]
    # no vertex shared between the plies: each vertex's cells all lie in one ply
    mesh.mesh.topology.create_connectivity(0, 2)
    vertex_cells = mesh.mesh.topology.connectivity(0, 2)
    for v in range(mesh.mesh.topology.index_map(0).size_local):
        assert len(set(plies[vertex_cells.links(v)])) == 1
    assert "ply0.left" in mesh.boundaries and "left" not in mesh.boundaries
    assert "ply1.edge" in mesh.boundaries and "edge" not in mesh.boundaries


# --- the interface's forces and Jacobian (numpy) -----------------------------------------------

def _grid(nx, ny, spacing, shift):
    X, Y = np.meshgrid(np.arange(nx + 1) * spacing, np.arange(ny + 1) * spacing, indexing="ij")
    xy = np.column_stack([X.ravel(), Y.ravel()]) + shift
    index = lambda i, j: i * (ny + 1) + j     # noqa: E731
    quads = np.array([[index(i, j), index(i + 1, j), index(i, j + 1), index(i + 1, j + 1)]
                      for i in range(nx) for j in range(ny)])      # DOLFINx's vertex order
    return xy, quads


def _small_stack(rng):
    """Two plies 0.5 mm thick: a 3x3 grid under a shifted 2x2 one whose edge x = 0.1 passes
    just beside the lower grid's nodes at x = 0 (they lie in its edge ramp); random nodal
    areas."""
    xy0, quads0 = _grid(3, 3, 2.0, np.zeros(2))
    xy1, quads1 = _grid(2, 2, 2.0, np.array([0.1, 1.1]))
    reference = np.vstack([np.column_stack([xy0, np.zeros(len(xy0))]),
                           np.column_stack([xy1, np.full(len(xy1), 0.5)])])
    ply = np.r_[np.zeros(len(xy0), int), np.ones(len(xy1), int)]
    tri0, _ = split_cells(quads0, reference[:, :2])
    tri1, _ = split_cells(quads1 + len(xy0), reference[:, :2])
    return StackNodes(reference, ply, rng.uniform(0.5, 1.5, len(reference)),
                      np.vstack([tri0, tri1]), np.r_[np.zeros(len(tri0), int),
                                                     np.ones(len(tri1), int)])


@pytest.mark.parametrize("law", [CONSTANT, DEPENDENT], ids=["constant", "dependent"])
def test_the_interface_jacobian_is_the_derivative_of_its_forces(law):
    rng = np.random.default_rng(1)
    nodes = _small_stack(rng)
    n = len(nodes.reference)
    contact = PlyContact(nodes, (0.5, 0.5), [law], penalty=50.0, smoothing=0.05,
                         regularisation=0.05)
    contact.set_step_duration(0.1)
    committed = rng.normal(0.0, 0.05, (n, 3))
    u = committed + rng.normal(0.0, 0.04, (n, 3))
    u[nodes.ply == 1, 2] -= 0.03                                  # pressed into each other
    for memory in contact.memory:
        memory[:] = rng.normal(0.0, 0.02, (n, 3))
    contact.search(u)

    def forces(u):
        pairs = contact.evaluate(u, committed)
        out = np.zeros((n, 3))
        np.add.at(out, pairs.nodes, pairs.force)
        return out.ravel(), pairs

    f, pairs = forces(u)
    # a common translation needs no new search; a node moved apart by more than the margin does
    searches = contact.counts["searches"]
    contact.evaluate(u + [3.0, -2.0, 1.0], committed)
    assert contact.counts["searches"] == searches
    apart = u.copy()
    apart[0] += [0.6, 0.0, 0.0]
    contact.evaluate(apart, committed)
    assert contact.counts["searches"] == searches + 1
    contact.search(u)
    f, pairs = forces(u)
    states = np.bincount(contact.states(), minlength=3)
    assert states[1] > 0 and states[2] > 0, states              # stick and slip both
    weights = contact.last("weight") / (0.5 * nodes.area[contact.last("slaves").astype(int)])
    assert np.any((weights > 0.0) & (weights < 1.0))            # a node beyond an edge
    assert np.allclose(f.reshape(n, 3).sum(axis=0), 0.0, atol=1e-12)   # action = reaction
    jacobian = np.zeros((3 * n, 3 * n))
    for node_ids, block in zip(pairs.nodes, pairs.jacobian):
        dofs = (3 * node_ids[:, None] + np.arange(3)).ravel()
        jacobian[np.ix_(dofs, dofs)] += block.reshape(12, 12)
    eps, differences = 1e-6, np.zeros_like(jacobian)
    for j in range(3 * n):
        step = np.zeros(3 * n)
        step[j] = eps
        step = step.reshape(n, 3)
        differences[:, j] = (forces(u + step)[0] - forces(u - step)[0]) / (2 * eps)
    assert np.abs(jacobian - differences).max() <= 1e-7 * np.abs(jacobian).max()
    # friction's memory: kept at commit as contact.elastic_slip says, and through a checkpoint
    contact.commit()
    slaves, slip = contact.last("slaves").astype(int), contact.last("slip")
    sticking = contact.states() == 1
    first = contact.directions[0].slave == nodes.ply[slaves]
    kept = np.where(first[:, None], contact.memory[0][slaves], contact.memory[1][slaves])
    normal = contact.last("normal")
    tangential = slip - np.sum(slip * normal, axis=1)[:, None] * normal
    assert np.allclose(kept[sticking], tangential[sticking])
    assert np.allclose(np.linalg.norm(kept[contact.states() == 2], axis=1), 0.05)
    again = PlyContact(nodes, (0.5, 0.5), [law], penalty=50.0, smoothing=0.05,
                       regularisation=0.05)
    again.load_state(contact.state())
    assert all(np.array_equal(a, b) for a, b in zip(again.memory, contact.memory))


def _bent_twin_plies(order):
    """Two plies 0.4 mm thick on the same 4 x 4 grid of 2 mm, node numbers and triangles in
    ``order`` (a permutation of the nodes, as another partition numbers them), bent into a
    dome 0.2 mm high and pressed 0.03 mm into each other: (nodes, u, old -> new numbers)."""
    xy, quads = _grid(4, 4, 2.0, np.zeros(2))
    n = len(xy)
    reference = np.vstack([np.column_stack([xy, np.zeros(n)]),
                           np.column_stack([xy, np.full(n, 0.4)])])
    cells = np.vstack([quads, quads + n])
    new = np.empty(2 * n, dtype=int)
    new[order] = np.arange(2 * n)
    triangles, origin = split_cells(new[cells], reference[order, :2])
    cell_ply = np.r_[np.zeros(len(quads), int), np.ones(len(quads), int)]
    turn = np.random.default_rng(7).permutation(len(triangles))
    nodes = StackNodes(reference[order], np.r_[np.zeros(n, int), np.ones(n, int)][order],
                       np.full(2 * n, 4.0), triangles[turn], cell_ply[origin][turn])
    r2 = np.sum((nodes.reference[:, :2] - 4.0) ** 2, axis=1)
    u = np.zeros((2 * n, 3))
    u[:, 2] = 0.2 * (1.0 - r2 / 32.0)
    u[nodes.ply == 1, 2] -= 0.03
    return nodes, u, new


def test_ties_between_master_triangles_do_not_depend_on_round_off_or_numbering():
    """Every slave node of two plies meshed alike lies over a master vertex, as close to all
    the triangles around it, whose normals differ once the plies bend: the winner of the tie
    must not be decided by the last bits of u (MUMPS' order of summation differs between runs
    and ranks) nor by the node numbers (the partition's). Forces per node (by its reference
    position) under u, u changed by a few ulps, and the nodes renumbered: equal to round-off
    (before ties were decided by their reference centroids: 1e-2 of the largest force)."""
    rng = np.random.default_rng(3)
    results = []
    for order, noise in ((np.arange(50), 0.0), (np.arange(50), 4e-16),
                         (rng.permutation(50), 0.0), (rng.permutation(50), 4e-16)):
        nodes, u, new = _bent_twin_plies(order)
        contact = PlyContact(nodes, (0.4, 0.4), [CONSTANT], penalty=100.0, smoothing=0.05,
                             regularisation=0.05)
        u = u * (1.0 + noise * rng.standard_normal(u.shape))
        contact.search(u)
        pairs = contact.evaluate(u, np.zeros_like(u))
        force = np.zeros_like(u)
        np.add.at(force, pairs.nodes, pairs.force)
        results.append(force[new])              # back in the first numbering
    scale = np.abs(results[0]).max()
    assert scale > 1.0
    for other in results[1:]:
        assert np.abs(other - results[0]).max() <= 1e-12 * scale


def test_the_near_candidates_hold_the_closest_triangle_until_the_next_search():
    """The search keeps, per slave, the triangles that can be its closest while no two nodes
    move more than the margin relative to each other: forces equal those of a search over
    every triangle (margin 100 mm) for motions within that bound; and only pairs less than
    g0 + 2 margin apart enter the Jacobian's pattern."""
    rng = np.random.default_rng(3)
    xy0, quads0 = _grid(8, 8, 1.0, np.zeros(2))
    xy1, quads1 = _grid(6, 6, 1.0, np.array([0.37, 0.61]))
    reference = np.vstack([np.column_stack([xy0, np.zeros(len(xy0))]),
                           np.column_stack([xy1, np.full(len(xy1), 0.5)])])
    ply = np.r_[np.zeros(len(xy0), int), np.ones(len(xy1), int)]
    tri0, _ = split_cells(quads0, reference[:, :2])
    tri1, _ = split_cells(quads1 + len(xy0), reference[:, :2])
    nodes = StackNodes(reference, ply, np.ones(len(reference)), np.vstack([tri0, tri1]),
                       np.r_[np.zeros(len(tri0), int), np.ones(len(tri1), int)])
    n = len(reference)
    options = dict(penalty=50.0, smoothing=0.05, regularisation=0.05)
    contact = PlyContact(nodes, (0.5, 0.5), [CONSTANT], margin=0.5, **options)
    every = PlyContact(nodes, (0.5, 0.5), [CONSTANT], margin=100.0, **options)
    u0 = rng.normal(0.0, 0.05, (n, 3))
    contact.search(u0)
    kept = sum(len(c[0]) for c in contact.candidates)
    every.search(u0)
    assert kept < 0.5 * sum(len(c[0]) for c in every.candidates)
    for _ in range(20):
        # the nodes' motions at most 0.49 margin from their middle (no new search), the
        # upper ply pressed into the lower
        step = rng.normal(0.0, 0.1, (n, 3))
        step[ply == 1, 2] -= 0.02
        middle = 0.5 * (step.max(axis=0) + step.min(axis=0))
        step = middle + (step - middle) * 0.49 * 0.5 / np.linalg.norm(step - middle,
                                                                       axis=1).max()
        u = u0 + [1.0, -0.5, 0.2] + step
        mine, theirs = contact.evaluate(u, u0), every.evaluate(u, u0)
        assert np.array_equal(mine.nodes, theirs.nodes)
        assert np.allclose(mine.force, theirs.force, rtol=0.0, atol=1e-12)
    assert contact.counts["searches"] == 1
    # flat plies lifted apart by g: pressed pairs for g below g0 + 2 margin = 1.05 mm only
    for lift, pairs in ((1.0, True), (1.1, False)):
        u = np.zeros((n, 3))
        u[ply == 1, 2] = lift
        contact.search(u)
        coupled = contact.coupled_nodes()
        assert [len(c) > 0 for c in coupled] == [pairs, pairs]
        if pairs:
            assert set(coupled[1][:, 0]) == set(np.nonzero(ply == 1)[0])


def test_the_friction_law_and_its_derivatives():
    p, v = np.array([0.0, 0.3, 2.0]), np.array([0.0, 1.5, 10.0])
    mu, dmu_dp, dmu_dv = DEPENDENT(p, v)
    assert mu[0] == 0.3
    assert np.allclose(mu, 0.3 * (1 + p / 0.5) ** -0.6 * (1 + v / 2.0) ** 0.3)
    h = 1e-6
    assert np.allclose(dmu_dp, (DEPENDENT(p + h, v)[0] - DEPENDENT(p - h, v)[0]) / (2 * h))
    assert np.allclose(dmu_dv, (DEPENDENT(p, v + h)[0] - DEPENDENT(p, v - h)[0]) / (2 * h))
    assert np.all(CONSTANT(p, v)[0] == 0.3)


# --- the stack problem (DOLFINx) ---------------------------------------------------------------

def _stack_problem(comm, plies, thicknesses, laws, penalty=200.0, smoothing=0.05, size=2.5,
                   contributions=None, damping=1e-3):
    from drape.fe.stack_mesh import create_stack_mesh
    from drape.fe.stack_problem import StackProblem
    from drape.forming.plies import ply_heights
    from drape.law.nested_surface import NestedSurfaceLaw
    from drape.law.parameters import MaterialParameters
    mesh = create_stack_mesh(comm, plies, ply_heights(thicknesses), thicknesses,
                             MeshConfig(size=size), centred=True)
    return StackProblem(mesh, NestedSurfaceLaw(MaterialParameters()), 0.0, damping, laws,
                        penalty=penalty, smoothing=smoothing, regularisation=0.05,
                        contributions=contributions)


def _pressed_and_shifted(problem):
    """A smooth displacement, the upper ply pushed 0.03 mm into the lower and 0.07 mm along x."""
    problem.u.interpolate(lambda x: np.vstack([0.05 * np.sin(x[1] / 3 + 1) + 0.02 * x[0],
                                               0.04 * np.cos(x[0] / 4),
                                               0.03 * np.sin(x[0] / 5) * np.cos(x[1] / 6)]))
    values = problem.u.x.array.reshape(-1, 3)
    upper = problem.ply_contact.nodes.ply[problem.global_nodes] == 1
    values[upper] += [0.07, 0.0, -0.03]
    problem.u.x.scatter_forward()
    problem.ply_contact.set_step_duration(0.5)
    problem.begin_step()


def test_the_stack_jacobian_is_the_derivative_of_its_residual(comm):
    problem = _stack_problem(comm, [SQUARE, SLANTED], (0.4, 0.4), [DEPENDENT])
    _pressed_and_shifted(problem)
    x = problem.u.vector.copy()
    direction = x.duplicate()
    direction.array[:] = np.random.default_rng(comm.rank).normal(size=direction.array.shape)
    action = jacobian_action(problem, x, direction)
    difference = central_difference(problem, x, direction, eps=1e-6)
    assert comm.allreduce(problem.ply_contact.counts["pairs"]) > 40
    error = action.copy()
    error.axpy(-1.0, difference)
    assert error.norm() <= 1e-8 * action.norm()
    # the enlarged pattern holds every coupling entry: no allocation while assembling
    A = problem.create_matrix()
    problem.jacobian(None, x, A, A)
    assert A.getInfo()["mallocs"] == 0


def test_the_pattern_follows_each_steps_search_and_the_factorisation_with_it(comm):
    """The first Jacobian after a search preallocates the new pairs' pattern (no malloc) and
    resets a factorisation's KSP, which would keep its analysis of the old pattern: LU solves
    (MUMPS, the matrix shifted to be regular) hold before and after the plies slid 1.3 mm."""
    from mpi4py import MPI
    from petsc4py import PETSc
    problem = _stack_problem(comm, [SQUARE, SLANTED], (0.4, 0.4), [CONSTANT])
    _pressed_and_shifted(problem)
    A = problem.create_matrix("baij")
    snes = PETSc.SNES().create(comm)
    ksp = snes.getKSP()
    ksp.setType("preonly")
    ksp.getPC().setType("lu")
    ksp.getPC().setFactorSolverType("mumps")
    upper = problem.ply_contact.nodes.ply[problem.global_nodes] == 1
    patterns = []
    for slide in (0.0, 1.3):
        problem.u.x.array.reshape(-1, 3)[upper] += [slide, 0.0, 0.0]
        problem.u.x.scatter_forward()
        problem.begin_step()
        x = problem.u.vector.copy()
        problem.jacobian(snes, x, A, A)
        A.shift(1e-3 * A.norm(PETSc.NormType.INFINITY))
        ksp.setOperators(A, A)
        b, y = A.createVecLeft(), A.createVecRight()
        b.array[:] = np.cos(np.arange(len(b.array)) + comm.rank)
        ksp.solve(b, y)
        check = b.duplicate()
        A.mult(y, check)
        check.axpy(-1.0, b)
        assert check.norm() <= 1e-8 * b.norm()
        assert A.getInfo()["mallocs"] == 0
        patterns.append(sorted(map(tuple, np.vstack(problem.ply_contact.coupled_nodes()))))
    assert comm.allreduce(patterns[0] != patterns[1], op=MPI.LOR)


def test_a_one_ply_stack_problem_is_todays_membrane_problem(comm):
    """No interface, no coupling: residual and Jacobian action are today's, value for value."""
    from drape.fe.membrane import MembraneProblem
    from drape.fe.mesh import create_blank_mesh
    from drape.law.nested_surface import NestedSurfaceLaw
    from drape.law.parameters import MaterialParameters
    stack = _stack_problem(comm, [SLANTED], (0.4,), [])
    today = MembraneProblem(create_blank_mesh(comm, SLANTED, MeshConfig(size=2.5), centred=True),
                            NestedSurfaceLaw(MaterialParameters()), 0.0, 1e-3)
    vectors = []
    for problem in (stack, today):
        problem.u.interpolate(lambda x: np.vstack([0.05 * np.sin(x[1] / 3), 0.02 * x[0],
                                                   0.1 * np.cos(x[0] / 4)]))
        problem.u.x.scatter_forward()
        x = problem.u.vector.copy()
        direction = x.duplicate()
        direction.array[:] = np.cos(np.arange(len(direction.array)) + comm.rank)
        vectors.append((residual(problem, x).array.copy(),
                        jacobian_action(problem, x, direction).array.copy()))
    assert stack.ply_contact.directions == []
    assert np.array_equal(vectors[0][0], vectors[1][0])
    assert np.array_equal(vectors[0][1], vectors[1][1])


def test_a_stack_problem_from_its_config(comm):
    """create_stack_problem: plies, heights, friction laws and the tools' penalty rule."""
    from drape.fe.stack_problem import create_stack_problem
    from drape.forming.contact import ContactParameters
    from drape.law.nested_surface import NestedSurfaceLaw
    from drape.law.parameters import MaterialParameters
    stack = load_stack({"plies": [{"thickness": 0.3, "length": 20.0, "width": 20.0},
                                  {"thickness": 0.5, "shape": "disc", "radius": 8.0}],
                        "interfaces": [{"friction": 0.25, "rate_exponent": 0.5}]})
    params = MaterialParameters()
    problem = create_stack_problem(comm, stack, MeshConfig(size=2.5), ContactParameters(),
                                   NestedSurfaceLaw(params), 1e-3)
    contact = problem.ply_contact
    assert contact.penalty == params.mu * max(params.K1, params.K2) / 2.5 ** 2
    assert contact.smoothing == 0.05 * 2.5 and contact.regularisation == 0.05
    assert [(d.slave, d.master, d.sign, d.offset) for d in contact.directions] == [
        (0, 1, -1.0, 0.4), (1, 0, 1.0, 0.4)]
    assert contact.directions[0].law.mu0 == 0.25 and contact.directions[0].law.rate_dependent
    heights = contact.nodes.reference[:, 2]
    assert set(heights[contact.nodes.ply == 0]) == {0.0}
    assert set(heights[contact.nodes.ply == 1]) == {0.4}
    assert math.isclose(contact.nodes.area[contact.nodes.ply == 0].sum(), 400.0)
    assert math.isclose(contact.nodes.area[contact.nodes.ply == 1].sum(),
                        problem.comm.allreduce(float(np.sum(
                            problem.cell_areas[problem.blank_mesh.cell_plies()[
                                : problem.n_cells] == 1]))))


def _by_node(problem, vector):
    """{(x, y, ply): values (3,)} of a PETSc vector's owned nodes, from every rank."""
    xy = problem.V.tabulate_dof_coordinates()[: problem.n_owned, :2]
    ply = problem.ply_contact.nodes.ply[problem.global_nodes[: problem.n_owned]]
    values = vector.array.reshape(-1, 3)[: problem.n_owned]
    rows = [(round(a, 9), round(b, 9), int(k), tuple(v)) for (a, b), k, v in zip(xy, ply, values)]
    rows = [r for part in problem.comm.allgather(rows) for r in part]
    return {r[:3]: np.array(r[3]) for r in rows}


def test_one_rank_equals_two(comm):
    """The residual and a Jacobian action of the distributed stack against those of the same
    stack on every rank alone (COMM_SELF), node by node."""
    from mpi4py import MPI
    results = []
    for each in (comm, MPI.COMM_SELF):
        problem = _stack_problem(each, [SQUARE, SLANTED], (0.4, 0.4), [DEPENDENT])
        _pressed_and_shifted(problem)
        x = problem.u.vector.copy()
        direction = x.duplicate()
        xy = problem.V.tabulate_dof_coordinates()[: problem.n_owned]
        direction.array[:] = np.column_stack([np.sin(xy[:, 0]), np.cos(xy[:, 1]),
                                              np.sin(xy[:, 0] + xy[:, 1])]).ravel()
        results.append((_by_node(problem, residual(problem, x)),
                        _by_node(problem, jacobian_action(problem, x, direction)),
                        each.allreduce(problem.ply_contact.counts["pairs"])))
    (r2, j2, pairs2), (r1, j1, pairs1) = results
    assert pairs1 == pairs2 and r1.keys() == r2.keys()
    scale_r = max(np.abs(v).max() for v in r1.values())
    scale_j = max(np.abs(v).max() for v in j1.values())
    for key in r1:
        assert np.allclose(r1[key], r2[key], rtol=0.0, atol=1e-10 * scale_r)
        assert np.allclose(j1[key], j2[key], rtol=0.0, atol=1e-10 * scale_j)


class _PressureOnPly:
    """A uniform pressure p (N/mm², downwards) on one ply's quadrature points."""

    name = "pressure"

    def __init__(self, cell_plies, ply, pressure):
        self.cell_plies, self.ply, self.pressure = cell_plies, ply, pressure

    def setup(self, reference_points):
        per_cell = len(reference_points) // len(self.cell_plies)
        self.on = np.repeat(self.cell_plies == self.ply, per_cell)

    def evaluate(self, positions, displacements):
        f = np.zeros_like(positions)
        f[self.on, 2] = -self.pressure
        return f, np.zeros(positions.shape + (3,))

    def commit(self):
        pass


PRESSURE, AREA, PENALTY = 0.1, 400.0, 100.0      # N/mm², mm², N/mm³


def _pressed_plies(comm, law, smoothing):
    """Two 20 x 20 mm plies 0.4 mm thick on the same 5 mm mesh: the lower one held, the upper
    one pressed on it with PRESSURE, its x and y prescribed (g_x, g_y returned to pull it)."""
    from drape.fe.solver import NewtonSolver
    from drape.fe.stack_mesh import create_stack_mesh
    from drape.fe.stack_problem import StackProblem
    from drape.job import SolverConfig
    from drape.law.nested_surface import NestedSurfaceLaw
    from drape.law.parameters import MaterialParameters
    mesh = create_stack_mesh(comm, [SQUARE, SQUARE], (0.0, 0.4), (0.4, 0.4), MeshConfig(size=5.0),
                             centred=True)
    n_cells = mesh.mesh.topology.index_map(2).size_local
    load = _PressureOnPly(mesh.cell_plies()[:n_cells], 1, PRESSURE)
    problem = StackProblem(mesh, NestedSurfaceLaw(MaterialParameters()), 0.0, 0.0, [law],
                           penalty=PENALTY, smoothing=smoothing, regularisation=0.05,
                           contributions=[load])
    ply = problem.ply_contact.nodes.ply[problem.global_nodes]
    upper = _vertices_of(problem, np.nonzero(ply == 1)[0])
    pulled = [g for g, _ in hold_lower_pull_upper(problem, 0, upper)]
    return problem, NewtonSolver(problem, SolverConfig(), force_scale=PRESSURE * AREA), pulled


def hold_lower_pull_upper(problem, dim, entities):
    """problem.bcs: the lower ply (ply 0) held in place, and the x and y of the upper ply's
    ``entities`` of dimension ``dim`` prescribed; returns, for x and y, the prescribed
    function (zero until the caller sets it) and its dofs in the problem's space."""
    from dolfinx import fem
    V = problem.V
    ply = problem.ply_contact.nodes.ply[problem.global_nodes]
    bcs = [fem.dirichletbc(fem.Function(V), np.nonzero(ply == 0)[0].astype(np.int32))]
    pulled = []
    for i in range(2):
        sub, _ = V.sub(i).collapse()
        g = fem.Function(sub)
        dofs = fem.locate_dofs_topological((V.sub(i), sub), dim, entities)
        bcs.append(fem.dirichletbc(g, dofs, V.sub(i)))
        pulled.append((g, dofs[0]))
    problem.bcs = bcs
    return pulled


def _upper_ply_forces(problem):
    """The contact force on the upper ply (N, 3), summed over the ranks."""
    forces = problem.forces
    on_upper = problem.ply_contact.nodes.ply[forces.nodes] == 1
    total = np.sum(forces.force * on_upper[:, :, None], axis=(0, 1))
    return problem.comm.allreduce(total)


@pytest.mark.parametrize("smoothing", [0.0, 0.05])
def test_pressed_plies_settle_at_the_penalty_gap(comm, smoothing):
    """Plies on the same mesh under a uniform pressure p: every node's gap is the penalty law's
    at p (its inverse, contact.gap_for_pressure), the plies interpenetrate by p / eps_N - g0/2
    (nothing with the smoothing's g0 > 2 p / eps_N), and the contact carries p A."""
    problem, solver, _ = _pressed_plies(comm, CONSTANT, smoothing)
    result = solver.solve()
    solver.close()
    assert result.converged, result
    assert np.allclose(_upper_ply_forces(problem), [0.0, 0.0, PRESSURE * AREA], rtol=0.0,
                       atol=1e-9 * PRESSURE * AREA)
    gaps = problem.ply_contact.last("gap")
    assert np.allclose(gaps, gap_for_pressure(PRESSURE, PENALTY, smoothing), rtol=0.0, atol=1e-12)
    penetration = comm.allreduce(problem.ply_contact.report()[0]["max_penetration"], op=_max())
    assert math.isclose(penetration, max(0.0, PRESSURE / PENALTY - smoothing / 2),
                        abs_tol=1e-12)


def _max():
    from mpi4py import MPI
    return MPI.MAX


def _mu(p, v, law):
    """mu(p, v) written out (the law of docs/plies.md), for the law's parameters."""
    return (law.mu0 * (1.0 + p / law.p_ref) ** -law.a * (1.0 + v / law.v_ref) ** law.b)


@pytest.mark.parametrize("law", [CONSTANT, DEPENDENT], ids=["constant", "dependent"])
@pytest.mark.parametrize("smoothing", [0.0, 0.05])
def test_friction_plateaus_at_mu_p_A(comm, law, smoothing):
    """The upper ply pulled along x in steps of 0.02 mm of 0.1 s each (v = 0.2 mm/s) over the
    held lower one: the friction force is -mu p A min(d / delta, 1), in stick and on the
    plateau, with mu = mu(p, v).

    Once the meshes no longer match, node-to-surface contact spreads the pressure unevenly
    near the plies' edges (the most loaded node carries 1.16 p at d = 0.16 mm), which tilts
    the upper ply slightly: the closed form holds to 1e-4 for a constant mu (measured 2e-6
    with the plain penalty, 1.1e-5 smoothed). A pressure-dependent mu also feels the spread:
    there the force is checked against sum mu(p_i, v) p_i w_i over the nodes (to 1e-4) and
    against mu(p, v) p A to within the spread of mu(p_i) over the nodes (3.3e-3 here).
    Penetration stays below that of twice the pressure, 2 p / eps_N - g0/2."""
    problem, solver, pulled = _pressed_plies(comm, law, smoothing)
    step, duration, delta = 0.02, 0.1, 0.05
    problem.ply_contact.set_step_duration(duration)
    rate = step / duration
    work, closed_form_work = 0.0, 0.0
    for k in range(1, 9):
        pulled[0].x.array[:] = k * step
        result = solver.solve()
        assert result.converged, result
        friction, _, normal = _upper_ply_forces(problem)
        assert math.isclose(normal, PRESSURE * AREA, rel_tol=1e-9)
        engaged = min(k * step / delta, 1.0)
        closed_form = -_mu(PRESSURE, rate, law) * PRESSURE * AREA * engaged
        contact = problem.ply_contact
        p, w = contact.last("pressure"), contact.last("weight")
        pointwise = -comm.allreduce(float(np.sum(_mu(p, rate, law) * p * w))) * engaged
        spread = comm.allreduce(float(np.sum(np.abs(_mu(p, rate, law) - _mu(PRESSURE, rate, law))
                                             * p * w))) * engaged
        assert abs(friction - pointwise) <= 1e-4 * abs(closed_form), (k, friction, pointwise)
        assert abs(friction - closed_form) <= spread + 1e-4 * abs(closed_form), \
            (k, friction, closed_form, spread)
        if law is CONSTANT:
            assert spread == 0.0
        penetration = comm.allreduce(contact.report()[0]["max_penetration"], op=_max())
        assert penetration <= max(0.0, 2 * PRESSURE / PENALTY - smoothing / 2)
        # the pressure times the area each node carries: p A up to the normals' tilt
        assert math.isclose(comm.allreduce(contact.report()[0]["normal_force"]),
                            PRESSURE * AREA, rel_tol=1e-6)
        problem.commit(k)
        # friction work: the force at the step's end over the step's slip (backward Euler)
        work += -friction * step
        closed_form_work += -closed_form * step
        reported = comm.allreduce(contact.report()[0]["friction_work"])
        assert math.isclose(reported, work, rel_tol=1e-4), (k, reported, work)
        if law is CONSTANT:
            assert math.isclose(reported, closed_form_work, rel_tol=1e-4)
    solver.close()
    carrying = contact.last("pressure") > 0.0
    slaves = contact.last("slaves").astype(int)[carrying]
    accumulated = np.concatenate([contact.accumulated_slip[i][slaves[contact.nodes.ply[slaves]
                                                                     == d.slave]]
                                  for i, d in enumerate(contact.directions)])
    assert np.allclose(accumulated, 8 * step, rtol=1e-5)     # up to the normals' tilt


def test_a_ply_pulled_by_its_edge_slides_at_mu_p_A(comm):
    """The upper ply pulled by its right edge only (the membrane carries the friction to it):
    Newton converges with the coupled Jacobian (3 to 9 iterations a step: the longer steps
    cross the stick-slip kink of the friction law), the whole ply ends up sliding, the friction
    reaches mu p A, and the edge's reaction balances the friction on the other nodes."""
    from drape.fe.solver import NewtonSolver
    from drape.job import SolverConfig
    problem, _, _ = _pressed_plies(comm, CONSTANT, 0.05)
    pulled = hold_lower_pull_upper(problem, 1, problem.blank_mesh.facets("ply1.right"))
    solver = NewtonSolver(problem, SolverConfig(), force_scale=PRESSURE * AREA)
    edge_x = pulled[0][1][pulled[0][1] < 3 * problem.n_owned]
    edge_x = edge_x[edge_x % 3 == 0]
    iterations = []
    for k in range(1, 7):
        pulled[0][0].x.array[:] = 0.02 * k
        result = solver.solve()
        assert result.converged, result
        iterations.append(result.iterations)
        problem.commit(k)
    friction = _upper_ply_forces(problem)[0]
    internal = problem.internal_force()
    reaction = comm.allreduce(float(np.sum(internal.array[edge_x])))
    forces = problem.forces
    gathered = np.concatenate(comm.allgather(problem.global_nodes[edge_x // 3]))
    at_edge = np.isin(forces.nodes, gathered)
    edge_friction = comm.allreduce(float(np.sum(forces.force[..., 0] * at_edge)))
    solver.close()
    assert max(iterations) <= 10, iterations
    assert np.all(problem.ply_contact.states()[problem.ply_contact.last("pressure") > 0] == 2)
    assert math.isclose(friction, -0.3 * PRESSURE * AREA, rel_tol=1e-4), friction
    assert math.isclose(reaction, -(friction - edge_friction), rel_tol=1e-6), (reaction, friction)


def _vertices_of(problem, nodes):
    """Mesh vertices at the given (local block) dofs of V: P1, so the dof's own vertex."""
    msh = problem.mesh
    msh.topology.create_connectivity(0, 2)
    vertex_of = np.empty(len(problem.global_nodes), dtype=np.int32)
    cells = problem.V.dofmap.list.array.reshape(-1, 4)
    c_to_v = msh.topology.connectivity(2, 0)
    for c in range(len(cells)):
        vertex_of[cells[c]] = c_to_v.links(c)
    return np.unique(vertex_of[nodes]).astype(np.int32)


def test_a_stacks_result_is_sorted_by_ply_then_coordinates(comm):
    """result.npz's order (drape.io.writer.gather_sorted): two plies on one mesh share every
    (x, y), so the ply is the first key: ply 0's nodes and points, then ply 1's, each in
    (x, y) order, on any number of ranks; u_z = 1 + ply tells the plies' values apart."""
    from drape.io.writer import gather_sorted
    problem = _stack_problem(comm, [SQUARE, SQUARE], (0.4, 0.4), [CONSTANT], size=5.0)
    ply = problem.ply_contact.nodes.ply[problem.global_nodes]
    problem.u.x.array.reshape(-1, 3)[:, 2] = 1.0 + ply
    problem.evaluate()
    data = gather_sorted(problem)
    if comm.rank != 0:
        assert data is None
        return
    for xy, plies in ((data["node_xy"], data["node_ply"]), (data["point_xy"], data["point_ply"])):
        half = len(xy) // 2
        assert np.array_equal(plies, np.repeat([0, 1], half))
        assert np.array_equal(xy[:half], xy[half:])
        key = np.round(xy[:half] / 10.0, 9)
        assert np.array_equal(np.lexsort((key[:, 1], key[:, 0])), np.arange(half))
    assert np.array_equal(data["u"][:, 2], 1.0 + data["node_ply"])
