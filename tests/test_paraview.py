"""ParaView is drape's viewer: every kind of XDMF output `drape run` writes (quadrilaterals,
triangles, written by 1 and by 2 ranks, every step or every N-th) opens in Debian's ParaView
5.11 with both XDMF readers (Xdmf3ReaderS and XDMFReader), with the documented fields, the
written time steps, and values equal to drape's own numbers computed independently: cell
averages of result.npz's point values (area-weighted at the law's points, from ParaView's
mesh), steps.csv's max_shear_angle_deg and load factors, the kinematics of the jobs. The tool
surfaces (.vtu) open too, and `drape view --screenshot` renders a non-trivial shear-angle map
off screen that marks the locking angle.

ParaView is installed here if pvpython is missing (apt-get, as root; skipped otherwise): it is
138 packages and ~800 MB on bookworm, so scripts/install.sh does not install it (docs/viewing.md).
"""

import csv
import json
import math
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from conftest import BIAS_EXTENSION_SHORT, CONFIGS, REPO

pytestmark = [pytest.mark.serial, pytest.mark.slow]

APT_PACKAGES = ["paraview", "python3-paraview", "xvfb"]
FIELDS = {"displacement": "point", "shear_angle_deg": "cell", "plastic_shear_angle_deg": "cell",
          "tau": "cell", "warp_tension": "cell", "weft_tension": "cell", "active_surface": "cell",
          # dolfinx 0.5.2 writes vector DG0 functions node-centred (a value of a neighbouring cell)
          "warp_direction": "point", "weft_direction": "point"}
READERS = ("Xdmf3ReaderS", "XDMFReader")
#: dolfinx 0.5.2's XDMF gives its float data items no Precision attribute, so ParaView reads
#: the HDF5 doubles as the XDMF default, 4-byte floats: values agree to float32's precision
F32 = 4 * 2.0 ** -24
ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
           OMPI_MCA_rmaps_base_oversubscribe="1")

PF_SHORT = ["--set", "mesh.size=25", "--set", "history.angle.values=[0, 30, -10]",
            "--set", "history.angle.t=[0, 0.6, 1]", "--set", "steps.initial=0.05",
            "--set", "steps.maximum=0.1"]
BE_SHORT = BIAS_EXTENSION_SHORT
#: name -> (config, overrides, ranks, xdmf_every)
RUNS = {
    "picture_frame": ("picture_frame.toml", PF_SHORT, 1, 1),
    "bias_quads": ("bias_extension.toml", BE_SHORT, 1, 1),
    "bias_triangles_every_2": ("bias_extension.toml",
                               BE_SHORT + ["--set", "mesh.cell=\"triangle\"",
                                           "--set", "output.xdmf_every=2"], 1, 2),
    "bias_quads_2_ranks": ("bias_extension.toml", BE_SHORT, 2, 1),
}


@pytest.fixture(scope="module")
def paraview():
    if shutil.which("pvpython") is None:
        if os.geteuid() != 0:
            pytest.skip("ParaView missing and not root: apt-get install -y "
                        + " ".join(APT_PACKAGES))
        apt = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
        subprocess.run(["apt-get", "update", "-q"], check=True, env=apt, capture_output=True)
        subprocess.run(["apt-get", "install", "-y", "-q", "--no-install-recommends",
                        "-o", "DPkg::Lock::Timeout=600", *APT_PACKAGES],
                       check=True, env=apt, capture_output=True)
    assert shutil.which("pvpython") and (os.environ.get("DISPLAY") or shutil.which("Xvfb"))
    version = subprocess.run(["pvpython", "--version"], capture_output=True, text=True,
                             stdin=subprocess.DEVNULL).stdout
    assert "paraview version 5." in version, version
    return shutil.which("pvpython")


def drape(*args, ranks=1):
    command = [sys.executable, "-m", "drape.cli", *map(str, args)]
    if ranks > 1:
        command = ["mpirun", "-n", str(ranks), *command]
    done = subprocess.run(command, capture_output=True, text=True, cwd=REPO, env=ENV, timeout=900,
                          stdin=subprocess.DEVNULL)
    return done


#: runs of RUNS that are the session's bias_extension_short (tests/conftest.py), by ranks
SHARED = {"bias_quads": 1, "bias_quads_2_ranks": 2}


@pytest.fixture(scope="module")
def runs(tmp_path_factory, bias_extension_short):
    root = tmp_path_factory.mktemp("paraview_runs")
    folders = {}
    for name, (config, overrides, ranks, _) in RUNS.items():
        if name in SHARED:                  # made once, with tests/test_cli_help.py
            done, folders[name] = bias_extension_short(SHARED[name])
            assert done.returncode == 0, done.stderr
            continue
        folder = root / name
        done = drape("run", CONFIGS / config, "--output", folder, "--quiet", *overrides,
                     ranks=ranks)
        assert done.returncode == 0, done.stderr
        folders[name] = folder
    return folders


def dump(pvpython, target, kind, path):
    done = subprocess.run([pvpython, str(REPO / "tests" / "paraview_dump.py"), str(target), kind,
                           str(path)], capture_output=True, text=True, stdin=subprocess.DEVNULL,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(target.read_text())


def steps_csv(folder):
    with (folder / "steps.csv").open() as stream:
        rows = list(csv.DictReader(stream))
    return [{k: float(v) for k, v in row.items()} for row in rows]


def law_points(points, cells):
    """The law's points of each cell and their area weights, from the cell's nodes: 2x2 Gauss
    points on quadrilaterals (VTK node order), the centroid on triangles."""
    xy = np.asarray(points)[:, :2]
    out = []
    g = 1.0 / math.sqrt(3.0)
    for cell in cells:
        p = xy[cell]
        if len(cell) == 3:
            out.append((p.mean(axis=0)[None, :], np.ones(1)))
            continue
        gauss, weights = [], []
        for s, r in ((-g, -g), (g, -g), (-g, g), (g, g)):
            n = 0.25 * np.array([(1 - s) * (1 - r), (1 + s) * (1 - r), (1 + s) * (1 + r),
                                 (1 - s) * (1 + r)])
            dn_ds = 0.25 * np.array([-(1 - r), 1 - r, 1 + r, -(1 + r)])
            dn_dr = 0.25 * np.array([-(1 - s), -(1 + s), 1 + s, 1 - s])
            jac = np.column_stack([dn_ds @ p, dn_dr @ p])
            gauss.append(n @ p)
            weights.append(np.linalg.det(jac))
        out.append((np.array(gauss), np.array(weights)))
    return out


def match(xy, reference):
    """Indices of ``reference`` rows at the coordinates ``xy`` (to 1e-4 mm)."""
    distance = np.linalg.norm(xy[:, None, :] - reference[None, :, :], axis=2)
    index = distance.argmin(axis=1)
    assert distance[np.arange(len(xy)), index].max() < 1e-4   # float32 coordinates
    return index


def kinematic_shear_deg(d, length=100.0, width=50.0):
    D = length - width
    return math.degrees(math.pi / 2 - 2 * math.acos((D + d) / (math.sqrt(2) * D)))


@pytest.mark.parametrize("name", list(RUNS))
def test_xdmf_opens_in_paraview_with_drape_numbers(paraview, runs, tmp_path, name):
    folder = runs[name]
    every = RUNS[name][3]
    seen = dump(paraview, tmp_path / "dump.json", "xdmf", folder / "fields.xdmf")
    rows = steps_csv(folder)
    snapshot = np.load(folder / "result.npz")
    written = [row for i, row in enumerate(rows)
               if int(row["step"]) % every == 0 or i == len(rows) - 1]
    for reader in READERS:
        view = seen[reader]
        # the written steps, as ParaView's time steps
        assert np.allclose(view["times"], [row["t"] for row in written], rtol=0, atol=1e-12), reader
        for step, row in zip(view["steps"], written):
            fields = step["fields"]
            assert {k: c for k, (c, _) in fields.items()} == FIELDS, reader
            shear = np.array(fields["shear_angle_deg"][1])
            # cell averages <= the largest value at the law's points (steps.csv)
            assert np.abs(shear).max() <= row["max_shear_angle_deg"] * (1 + F32) + 1e-12
            for direction in ("warp_direction", "weft_direction"):
                assert np.allclose(np.linalg.norm(fields[direction][1], axis=1), 1.0, atol=4 * F32)
            if name == "picture_frame":   # homogeneous: every cell at the frame angle
                assert np.allclose(shear, row["angle"], rtol=F32, atol=1e-12)
                assert abs(row["max_shear_angle_deg"] - abs(row["angle"])) < 1e-8
        # the last step against result.npz, computed independently from ParaView's mesh
        mesh = view["mesh"]
        last = view["steps"][-1]["fields"]
        nodes = np.asarray(mesh["points"])[:, :2]
        u = np.asarray(last["displacement"][1])
        u_npz = snapshot["u"][match(nodes, snapshot["node_xy"])]
        assert np.abs(u - u_npz).max() <= F32 * np.abs(u_npz).max() + 1e-12
        assert np.abs(u_npz).max() > 1.0
        for field, key in (("shear_angle_deg", "gamma_t_deg"), ("tau", "tau"),
                           ("plastic_shear_angle_deg", "gamma_p_deg")):
            expected = []
            for xy, weights in law_points(mesh["points"], mesh["cells"]):
                values = snapshot[key][match(xy, snapshot["point_xy"])]
                expected.append(weights @ values / weights.sum())
            scale = max(1.0, np.abs(expected).max())
            # float32 of the values; float32 coordinates move the law's points by ~1e-5 mm
            error = np.abs(np.asarray(last[field][1]) - expected).max()
            assert error <= 4 * F32 * scale, (reader, field)
        largest = np.abs(snapshot["gamma_t_deg"]).max()
        assert np.abs(last["shear_angle_deg"][1]).max() <= largest * (1 + F32)
        assert abs(largest - written[-1]["max_shear_angle_deg"]) < 1e-12
        if name.startswith("bias"):
            # the central cell shears as the three-zone kinematics says (d = 10 mm: 26.05 deg)
            centroids = np.array([nodes[c].mean(axis=0) for c in mesh["cells"]])
            centre = np.linalg.norm(centroids - [50.0, 25.0], axis=1).argmin()
            assert abs(abs(last["shear_angle_deg"][1][centre]) - kinematic_shear_deg(10.0)) < 1.0
    # both readers see the same values
    for a, b in zip(seen[READERS[0]]["steps"], seen[READERS[1]]["steps"]):
        for field in FIELDS:
            assert np.array_equal(a["fields"][field][1], b["fields"][field][1]), field


def test_tool_surfaces_open_in_paraview(paraview, tmp_path):
    from drape.geometry.tools import analytic_tools, build_tools, load_tools_config, \
        write_tool_surfaces  # noqa: F401
    config = load_tools_config(CONFIGS / "tools" / "hemisphere.toml", "tools")
    surfaces = build_tools(config)
    path = write_tool_surfaces(tmp_path / "tools.vtu", surfaces, offsets={"punch": (0, 0, -20.0)})
    seen = dump(paraview, tmp_path / "tools.json", "vtu", path)
    nodes = np.concatenate([s.nodes for s in surfaces.values()])
    triangles = sum(len(s.triangles) for s in surfaces.values())
    points = np.asarray(seen["mesh"]["points"])
    assert points.shape == nodes.shape and len(seen["mesh"]["cells"]) == triangles
    assert set(seen["mesh"]["cell_types"]) == {5}                        # VTK_TRIANGLE
    assert seen["fields"]["normal"][0] == "point" and seen["fields"]["tool"][0] == "cell"
    assert np.allclose(np.linalg.norm(seen["fields"]["normal"][1], axis=1), 1.0, atol=1e-6)
    assert sorted(set(seen["fields"]["tool"][1])) == list(range(len(surfaces)))
    # the punch moved down by the stroke: its lowest point at gap - 20 mm
    punch = np.asarray(seen["fields"]["tool"][1]) == 0
    cells = np.asarray(seen["mesh"]["cells"])[punch]
    assert abs(points[cells.ravel(), 2].min() - (config.hemisphere.gap - 20.0)) < 1e-6


def pixels(path):
    import matplotlib.image as image
    return (image.imread(path)[..., :3] * 255).round().astype(int)


def test_drape_view_screenshot_marks_the_locking_angle(paraview, runs, tmp_path):
    folder = runs["bias_quads"]
    largest = max(abs(r["max_shear_angle_deg"]) for r in steps_csv(folder))
    assert 25.0 < largest < 40.0
    counts = {}
    for angle in (25.0, 40.0):
        png = tmp_path / f"shear_{angle:g}.png"
        done = drape("view", folder, "--screenshot", png, "--locking-angle", angle)
        assert done.returncode == 0, done.stderr
        assert f"locking angle {angle:g} deg" in done.stdout
        image = pixels(png)
        assert image.shape == (900, 1200, 3) and png.stat().st_size > 20_000
        colours = np.unique(image.reshape(-1, 3), axis=0)
        assert len(colours) > 100                                 # not one colour: a map
        assert 0.1 < (image != 255).any(axis=2).mean() < 0.9      # the blank fills the picture
        plot = image[:, :1000]                                    # left of the colour bar
        # cells past -locking angle are drawn in the below-range colour (0, 0, 0.4), shaded
        counts[angle] = int(((plot[..., 0] < 30) & (plot[..., 1] < 30) & (plot[..., 2] > 60)
                             & (plot[..., 2] < 140)).sum())
    assert counts[25.0] > 5000 and counts[40.0] == 0, counts


def test_drape_view_draws_a_run_resumed_on_other_ranks(paraview, tmp_path):
    """A run stopped on 1 rank and resumed on 2 writes its later steps in the 2-rank order of
    nodes, on the mesh written again (grid mesh-r2): `drape view` draws the displacement at the
    points it belongs to. Its merged grid at the last step: points and displacement equal
    result.npz's (float32). With the steps referred to the first grid's mesh (1 rank's order
    of nodes) the view's displacement was 16.5 mm off."""
    from test_fe_checkpoint import SHORT, check_stopped_folder, run_and_terminate
    folder = tmp_path / "moved"
    rc, err = run_and_terminate(folder, 1)
    check_stopped_folder(folder, rc, err)
    done = drape("run", CONFIGS / "bias_extension.toml", "--output", folder, *SHORT, "--resume",
                 ranks=2)
    assert done.returncode == 0, done.stderr
    assert "Grid Name=\"mesh-r2\"" in (folder / "fields.xdmf").read_text()
    seen = dump(paraview, tmp_path / "view.json", "view", folder)
    result = np.load(folder / "result.npz")
    assert seen["t"] == pytest.approx(1.0)
    points, u = np.array(seen["points"])[:, :2], np.array(seen["displacement"])
    order = np.lexsort((points[:, 1], points[:, 0]))
    scale = np.abs(result["u"]).max()
    assert np.abs(points[order] - result["node_xy"]).max() < 1e-4
    assert np.abs(u[order] - result["u"]).max() < F32 * scale


def test_drape_view_bad_input(tmp_path, monkeypatch, capsys):
    from drape import cli, view
    assert cli.main(["view", str(tmp_path / "missing")]) == 2
    assert "no such results folder" in capsys.readouterr().err
    assert cli.main(["view", str(tmp_path)]) == 2
    assert "no fields.xdmf" in capsys.readouterr().err
    (tmp_path / "fields.xdmf").write_text("<?xml version=\"1.0\"?><Xdmf/>")
    (tmp_path / "fields.h5").write_bytes(b"")
    (tmp_path / "summary.json").write_text('{"locking_angle_deg": 95}')
    assert cli.main(["view", str(tmp_path)]) == 2
    assert "locking_angle_deg" in capsys.readouterr().err
    (tmp_path / "summary.json").write_text('{"locking_angle_deg": 33.5}')
    assert view.locking_angle(tmp_path, None) == 33.5
    assert view.locking_angle(tmp_path, 20.0) == 20.0
    (tmp_path / "summary.json").unlink()
    assert view.locking_angle(tmp_path, None) == view.DEFAULT_LOCKING_ANGLE
    monkeypatch.setattr(view.shutil, "which", lambda name: None)
    assert cli.main(["view", str(tmp_path), "--screenshot", str(tmp_path / "x.png")]) == 2
    message = capsys.readouterr().err
    assert "ParaView is not installed" in message and "apt-get install -y paraview" in message
