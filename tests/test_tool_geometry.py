"""The gmsh tool builders (drape.geometry.tools) against exact geometry.

The meshed hemisphere tools against their analytic twins (nodes on the surface, normals, gaps
within the chord error of the mesh); the double dome against the closed form of its
construction (domes, saddle, depth, footprint) and the clearance between punch and die at full
stroke; STEP tools; configuration checks; the tool files.
"""

import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from conftest import CONFIGS, comm_size
from drape.config import from_mapping
from drape.errors import InputError
from drape.geometry.tools import (DoubleDomeTools, HemisphereTools, StepTool, StepTools,
                                  ToolMeshing, ToolsConfig, analytic_tools, build_tools,
                                  double_dome_height, hemisphere_profiles,
                                  load_tools_config, write_tool_surfaces)
from drape.forming.surfaces import MeshedSurface
from tool_helpers import chord_bound

COARSE = ToolMeshing(chord_tolerance=0.2, max_size=20.0, elements_per_radius=2.0)
RNG = np.random.default_rng(11)


@pytest.fixture(scope="module")
def hemisphere():
    cfg = HemisphereTools(gap=0.5)
    return cfg, build_tools(cfg, COARSE), analytic_tools(cfg)


@pytest.fixture(scope="module")
def double_dome():
    cfg = DoubleDomeTools()
    return cfg, build_tools(cfg, COARSE)


def curvature(tool):
    return lambda x: np.max(tool.principal_curvatures(x), axis=0)


# --- hemisphere -------------------------------------------------------------------------------

@pytest.mark.serial
def test_hemisphere_nodes_and_normals_are_exact(hemisphere):
    """Every node lies on the analytic surface; vertex normals are the exact outward normals
    except on the solids' sharp edges, where they are the mean of the faces' normals."""
    cfg, meshed, exact = hemisphere
    for name, surface in meshed.items():
        q = exact[name].query(surface.nodes)
        assert np.abs(q.gap).max() < 1e-9, name
        r = np.hypot(surface.nodes[:, 0], surface.nodes[:, 1])
        corners = hemisphere_profiles(cfg)[name].sharp_corners()
        d_corner = np.min(np.hypot(r[:, None] - corners[:, 0], surface.nodes[:, 2, None]
                                   - corners[:, 1]), axis=1)
        smooth = d_corner > 1e-6
        agree = np.sum(surface.normals * q.normal, axis=1)
        assert np.all(agree[smooth] > 1 - 1e-9), name
        assert np.all(agree[~smooth] > 0.5), name           # averaged across the edge
        assert np.count_nonzero(~smooth) > 10


@pytest.mark.serial
def test_hemisphere_meshed_gaps_within_chord_error(hemisphere):
    """Points within 3 mm of each tool's surface: the meshed gap differs from the exact gap by
    at most the mesh's chord bound (its largest triangle-to-surface distance; twice that in
    the thin shell between the two surfaces, where the signs may differ). Normals agree within
    the normal's turn over a triangle, away from sharp edges."""
    cfg, meshed, exact = hemisphere
    for name, surface in meshed.items():
        bound = chord_bound(surface, curvature(exact[name]))
        assert 0.01 < bound < 0.5, (name, bound)
        seeds = surface.nodes[RNG.integers(0, len(surface.nodes), 3000)]
        seeds = seeds + RNG.normal(size=seeds.shape) * 2.0
        on = exact[name].query(seeds)
        points = on.closest + on.normal * RNG.uniform(-3.0, 3.0, (len(seeds), 1))
        ref = exact[name].query(points)
        got = MeshedSurface(surface).query(points)
        error = np.abs(got.gap - ref.gap)
        shell = np.abs(ref.gap) < bound
        assert np.all(error[~shell] <= bound), (name, error.max(), bound)
        assert np.all(error[shell] <= 2 * bound)
        assert error.max() > 0.2 * bound                  # the bound is of the right size
        r = np.hypot(ref.closest[:, 0], ref.closest[:, 1])
        corners = hemisphere_profiles(cfg)[name].sharp_corners()
        edge = surface.edge_lengths().max()
        far_from_edges = np.min(np.hypot(r[:, None] - corners[:, 0],
                                         ref.closest[:, 2, None] - corners[:, 1]), axis=1) > edge
        kappa_h = np.max(curvature(exact[name])(surface.nodes)) * edge
        turn = np.linalg.norm(got.normal - ref.normal, axis=1)[far_from_edges]
        assert turn.max() <= max(kappa_h, 1e-9), (name, turn.max(), kappa_h)


@pytest.mark.serial
def test_meshed_search_on_a_graded_gmsh_mesh_equals_brute_force(hemisphere):
    """The die's mesh mixes 1 mm triangles (fillet) and 20 mm ones (flat faces): the indexed
    search finds what a loop over all its triangles finds, near and far."""
    from tool_helpers import brute_force
    _, meshed, _ = hemisphere
    die = meshed["die"]
    seeds = die.nodes[RNG.integers(0, len(die.nodes), 150)]
    points = np.concatenate([seeds + RNG.normal(size=seeds.shape) * 2.0,
                             seeds + RNG.normal(size=seeds.shape) * 60.0])
    gap = MeshedSurface(die).query(points).gap
    dist, _ = brute_force(die, points)
    np.testing.assert_allclose(np.abs(gap), dist, atol=1e-9)


@pytest.mark.serial
def test_hemisphere_tools_positions(hemisphere):
    """Blank plane z = 0: die top at -gap, holder bottom and punch tip at +gap; down to full
    stroke the punch keeps the radial clearance from the die, reached when the shank passes
    the die's wall."""
    cfg, meshed, exact = hemisphere
    assert meshed["punch"].nodes[:, 2].min() == pytest.approx(cfg.gap, abs=1e-9)
    assert meshed["die"].nodes[:, 2].max() == pytest.approx(-cfg.gap, abs=1e-9)
    assert meshed["holder"].nodes[:, 2].min() == pytest.approx(cfg.gap, abs=1e-9)
    r_holder = np.hypot(*meshed["holder"].nodes[:, :2].T)
    assert r_holder.min() == pytest.approx(cfg.holder_inner_radius, abs=1e-6)
    clearance = cfg.die_opening_radius - cfg.punch_radius
    for stroke in np.linspace(0.0, cfg.full_stroke, 12):     # the die's offset is the punch's move
        gap = exact["die"].query(meshed["punch"].nodes, offset=(0.0, 0.0, stroke)).gap
        assert gap.min() >= clearance - 1e-9
    # with the equator 10 mm below the entry fillet's start, the shank faces the die's wall
    stroke = 2 * cfg.gap + cfg.punch_radius + cfg.die_fillet_radius + 10.0
    gap = exact["die"].query(meshed["punch"].nodes, offset=(0.0, 0.0, stroke)).gap
    assert gap.min() == pytest.approx(clearance, abs=1e-9)


# --- double dome ------------------------------------------------------------------------------

@pytest.mark.serial
def test_double_dome_dimensions(double_dome):
    """Die footprint 470 x 270, cavity 60 deep, punch footprint and tips as configured."""
    cfg, tools = double_dome
    die, punch = tools["die"].nodes, tools["punch"].nodes
    np.testing.assert_allclose(die.min(axis=0), [-235.0, -135.0, -80.0], atol=1e-6)
    np.testing.assert_allclose(die.max(axis=0), [235.0, 135.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(punch.min(axis=0), [-190.0, -90.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(punch.max(axis=0), [190.0, 90.0, 100.0], atol=1e-6)
    die_tool = MeshedSurface(tools["die"])
    a = cfg.dome_offset
    # straight below a point 30 mm over the cavity's dome bottoms: 60 deep
    q = die_tool.query(np.array([[a, 0.0, -30.0], [-a, 0.0, -30.0]]))
    np.testing.assert_allclose(q.gap, 30.0, atol=0.05)
    np.testing.assert_allclose(q.closest[:, 2], -60.0, atol=0.05)


@pytest.mark.serial
def test_double_dome_follows_its_construction(double_dome):
    """Nodes of the domes and the saddle lie on the closed form (two spheres and the torus of
    the rolling-ball blend); the saddle point is a saddle (curving up along x, down along y)."""
    cfg, tools = double_dome
    a, half = cfg.dome_offset, 0.5 * cfg.punch_width
    for name, which, rim in (("punch", "punch", half - 2 * cfg.punch_edge_radius),
                             ("die", "cavity", half - 2 * cfg.punch_edge_radius)):
        x, y, z = tools[name].nodes.T
        inside = np.hypot(np.maximum(np.abs(x) - a, 0.0), y) < rim
        h = double_dome_height(cfg, x, y, which)
        shaped = inside & (np.abs(z - h) < 5.0)
        assert np.count_nonzero(shaped) > 100
        assert np.count_nonzero(shaped & (np.abs(x) < 0.5 * a * cfg.saddle_radius /
                                          (cfg.dome_radius + cfg.saddle_radius))) > 5
        assert np.abs(z - h)[shaped].max() < 1e-4, name
    h = lambda x, y: float(double_dome_height(cfg, x, y))
    d = 5.0
    assert h(d, 0) + h(-d, 0) - 2 * h(0, 0) < 0       # the punch's lower face dips along x
    assert h(0, d) + h(0, -d) - 2 * h(0, 0) > 0       # and rises across
    sag = h(0, 0) - h(a, 0)
    major = math.sqrt((cfg.dome_radius + cfg.saddle_radius) ** 2 - a ** 2)
    assert sag == pytest.approx(cfg.dome_radius + cfg.saddle_radius - major, rel=1e-12)
    q = MeshedSurface(tools["punch"]).query(np.array([[0.0, 0.0, h(0, 0) - 5.0]]))
    assert q.gap[0] == pytest.approx(5.0, abs=0.05)


@pytest.mark.serial
def test_double_dome_clearance_at_full_stroke(double_dome):
    """The cavity is the punch offset by the clearance: at full stroke every punch node is at
    least the clearance from the die, less the die mesh's chord error, and the tips touch it."""
    cfg, tools = double_dome
    gap = MeshedSurface(tools["die"]).query(tools["punch"].nodes,
                                            offset=(0.0, 0.0, cfg.full_stroke)).gap
    tolerance = 2.5 * COARSE.chord_tolerance
    assert gap.min() >= cfg.clearance - tolerance
    assert gap.min() <= cfg.clearance + 1e-6
    holder = MeshedSurface(tools["holder"]).query(tools["punch"].nodes).gap
    assert holder.min() >= cfg.holder_margin + cfg.die_entry_radius + cfg.clearance - tolerance


@pytest.mark.serial
def test_tool_surfaces_are_closed_and_outward(hemisphere, double_dome):
    for tools in (hemisphere[1], double_dome[1]):
        for name, surface in tools.items():
            tri = surface.triangles
            edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
            edges = np.sort(edges, axis=1)
            _, counts = np.unique(edges, axis=0, return_counts=True)
            assert np.all(counts == 2), name                # watertight
            a, b, c = (surface.nodes[tri[:, k]] for k in range(3))
            volume = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0
            assert volume > 0, name                          # triangles face outwards
            agree = np.einsum("ij,ij->i", surface.triangle_normals(),
                              surface.normals[tri].mean(axis=1))
            assert np.all(agree > 0), name                   # and so do vertex normals


# --- STEP tools -------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def step_files(tmp_path_factory):
    from drape.geometry._gmsh import scratch_model
    folder = tmp_path_factory.mktemp("step")
    with scratch_model() as gmsh:
        gmsh.model.occ.addBox(0, 0, 0, 10, 20, 5)
        gmsh.model.occ.synchronize()
        gmsh.write(str(folder / "box.step"))
    with scratch_model() as gmsh:
        gmsh.model.occ.addRectangle(-5, -5, 0, 10, 10)
        gmsh.model.occ.synchronize()
        gmsh.write(str(folder / "plate.step"))
    (folder / "notes.step").write_text("not a STEP file\n")
    return folder


@pytest.mark.serial
def test_step_tools(step_files):
    box, plate = str(step_files / "box.step"), str(step_files / "plate.step")
    tools = build_tools(StepTools(punch=StepTool(box, scale=2.0, translate=(1.0, 2.0, 3.0)),
                                  die=StepTool(plate, side="up"),
                                  holder=StepTool(plate, side="down")), COARSE)
    punch = tools["punch"]
    np.testing.assert_allclose(punch.nodes.min(axis=0), [1.0, 2.0, 3.0], atol=1e-9)
    np.testing.assert_allclose(punch.nodes.max(axis=0), [21.0, 42.0, 13.0], atol=1e-9)
    q = MeshedSurface(punch).query(np.array([[11.0, 22.0, 20.0], [11.0, 22.0, 8.0]]))
    np.testing.assert_allclose(q.gap, [7.0, -5.0], atol=1e-9)      # outside above, inside
    np.testing.assert_allclose(q.normal[0], [0.0, 0.0, 1.0], atol=1e-9)
    np.testing.assert_allclose(tools["die"].normals[:, 2], 1.0)
    np.testing.assert_allclose(tools["holder"].normals[:, 2], -1.0)


@pytest.mark.serial
@pytest.mark.parametrize("name, side, problem", [
    ("notes.step", "solid", "gmsh cannot read it"),
    ("plate.step", "solid", "no closed solid"),
    ("missing.step", "solid", "file not found"),
])
def test_bad_step_files_are_refused(step_files, name, side, problem):
    path = str(step_files / name)
    with pytest.raises(InputError, match=problem) as error:
        from_mapping(ToolsConfig, {"kind": "step", "step": {"die": {"file": path, "side": side}}},
                     source="job.toml")
    assert error.value.key == "step.die.file" and error.value.value == path
    assert error.value.source == "job.toml"


# --- configuration ----------------------------------------------------------------------------

def test_shipped_tool_configs_hold_the_defaults():
    hemi = load_tools_config(CONFIGS / "tools" / "hemisphere.toml", "tools")
    dd = load_tools_config(CONFIGS / "tools" / "double_dome.toml", "tools")
    assert hemi == ToolsConfig(kind="hemisphere")
    assert dd == ToolsConfig(kind="double_dome")
    assert (dd.double_dome.die_length, dd.double_dome.die_width, dd.double_dome.depth) == \
        (470.0, 270.0, 60.0)


@pytest.mark.parametrize("table, changes, key", [
    ("hemisphere", {"die_opening_radius": 50.5}, "die_opening_radius"),
    ("hemisphere", {"die_fillet_radius": 60.0}, "die_fillet_radius"),
    ("hemisphere", {"holder_inner_radius": 58.0}, "holder_inner_radius"),
    ("hemisphere", {"holder_outer_radius": 160.0}, "holder_outer_radius"),
    ("hemisphere", {"holder_fillet_radius": 25.0}, "holder_fillet_radius"),
    ("hemisphere", {"punch_radius": -1.0}, "punch_radius"),
    ("double_dome", {"punch_length": 170.0}, "punch_length"),
    ("double_dome", {"dome_radius": 120.0}, "dome_radius"),
    ("double_dome", {"depth": 35.0, "die_thickness": 80.0}, "depth"),
    ("double_dome", {"die_width": 214.0}, "die_width"),
    ("double_dome", {"saddle_radius": 1.5}, "saddle_radius"),
    ("mesh", {"min_size": 20.0}, "min_size"),
])
def test_bad_dimensions_are_refused(table, changes, key):
    with pytest.raises(InputError) as error:
        from_mapping(ToolsConfig, {table: changes}, source="job.toml", prefix="tools")
    assert error.value.key == f"tools.{table}.{key}", error.value.message
    assert "expected" in error.value.message


def test_defaults_validate_and_double_dome_rim_is_deep_enough():
    HemisphereTools().validate()
    cfg = DoubleDomeTools()
    cfg.validate()
    depths = cfg.rim_depths()
    assert depths.max() <= cfg.depth and depths.min() > cfg.die_entry_radius + cfg.punch_edge_radius
    with pytest.raises(InputError, match="no STEP file"):
        from_mapping(ToolsConfig, {"kind": "step"})


# --- output -----------------------------------------------------------------------------------

@pytest.mark.serial
def test_tool_files(hemisphere, tmp_path):
    cfg, tools, _ = hemisphere
    path = write_tool_surfaces(tmp_path / "tools.vtu", tools, offsets={"punch": (0.0, 0.0, -20.0)})
    piece = ET.parse(path).getroot().find("UnstructuredGrid/Piece")
    n_nodes = sum(len(s.nodes) for s in tools.values())
    n_tri = sum(len(s.triangles) for s in tools.values())
    assert (int(piece.get("NumberOfPoints")), int(piece.get("NumberOfCells"))) == (n_nodes, n_tri)
    points = np.array(piece.find("Points/DataArray").text.split(), dtype=float).reshape(-1, 3)
    np.testing.assert_allclose(points[:len(tools["punch"].nodes)],
                               tools["punch"].nodes - [0.0, 0.0, 20.0], rtol=1e-8, atol=1e-8)
    tool_ids = np.array(piece.find("CellData/DataArray").text.split(), dtype=int)
    per_tool = [len(tools[n].triangles) for n in ("punch", "die", "holder")]
    assert np.bincount(tool_ids).tolist() == per_tool

    from drape.geometry._gmsh import scratch_model
    msh = write_tool_surfaces(tmp_path / "tools.msh", tools)
    with scratch_model() as gmsh:
        gmsh.merge(str(msh))
        names = {gmsh.model.getPhysicalName(2, tag) for _, tag in gmsh.model.getPhysicalGroups(2)}
        assert names == {"punch", "die", "holder"}
        assert len(gmsh.model.mesh.getNodes()[0]) == n_nodes
    with pytest.raises(InputError, match=".vtu or .msh"):
        write_tool_surfaces(tmp_path / "tools.stl", tools)


def test_tools_are_the_same_on_every_rank():
    """Under MPI, rank 0 builds and broadcasts: every rank holds identical arrays."""
    from mpi4py import MPI
    comm = MPI.COMM_WORLD
    tools = build_tools(HemisphereTools(), ToolMeshing(chord_tolerance=1.0, max_size=40.0,
                                                       elements_per_radius=1.0), comm=comm)
    digest = sum(float(np.sum(s.nodes * np.arange(1, 4))) + float(s.triangles.sum())
                 for s in tools.values())
    assert len(set(comm.allgather(digest))) == 1
    assert comm_size() == comm.size
    # a tool OpenCASCADE cannot build (dimensions not validated): an InputError on every rank
    with pytest.raises(InputError, match="could not build"):
        build_tools(HemisphereTools(die_fillet_radius=60.0), ToolMeshing(size=40.0), comm=comm)


@pytest.mark.serial
def test_builders_leave_other_gmsh_models_alone():
    """A model another part of drape has open (the blank) stays current, with its options, and
    gmsh finalized by someone else is started again."""
    import gmsh
    from drape.geometry._gmsh import ensure_initialized
    ensure_initialized()
    gmsh.model.add("someone-elses-blank")
    gmsh.model.occ.addRectangle(0, 0, 0, 10, 10)
    gmsh.model.occ.synchronize()
    gmsh.option.setNumber("Mesh.MeshSizeMax", 3.5)
    tools = build_tools(HemisphereTools(), ToolMeshing(chord_tolerance=1.0, max_size=40.0,
                                                       elements_per_radius=1.0))
    assert set(tools) == {"punch", "die", "holder"}
    assert gmsh.model.getCurrent() == "someone-elses-blank"
    assert gmsh.model.getEntities(2) == [(2, 1)]
    assert gmsh.option.getNumber("Mesh.MeshSizeMax") == 3.5
    gmsh.model.remove()
    gmsh.finalize()
    again = build_tools(HemisphereTools(), ToolMeshing(chord_tolerance=1.0, max_size=40.0,
                                                       elements_per_radius=1.0))
    np.testing.assert_array_equal(again["punch"].triangles, tools["punch"].triangles)
