"""The stack of plies (drape/forming/plies.py, drape/fe/stack_mesh.py): the config read and
checked, and a one-ply stack against today's blank."""

import numpy as np
import pytest

from drape.config import from_mapping
from drape.errors import InputError
from drape.forming.plies import PlyConfig, StackConfig, load_stack, ply_heights, single_ply_stack
from drape.job import BlankConfig, MeshConfig

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
