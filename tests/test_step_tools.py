"""STEP tools give the built-in tools' answer (issue 31): the default hemisphere's tools written
as STEP files with gmsh's OpenCASCADE kernel (tests/cad_helpers.py), a force-controlled STEP
holder found on the tools' flat faces, a position-controlled one reporting its measured force,
the holder warning, and the meshed tools' candidate lists against the plain search.

The forming comparisons are slow: the hemisphere (the punch 5 mm down on the coarsest mesh
its die fillet allows) and the double dome (3 mm, its shipped 7.5 mm mesh), 20-50 s a run on
one rank. They are marked ``serial`` (tests/conftest.py): the suite runs them once, on one
rank; the built-in runs are the session's (tests/conftest.py), which tests/test_forming.py
checks too. test_a_position_controlled_step_holder_reports_the_force_it_measured (one step)
runs in both passes: a forming run with STEP tools on 2 ranks.
"""

import json
from types import SimpleNamespace

import numpy as np
import pytest

from cad_helpers import step_job, write_hemisphere_step
from conftest import CONFIGS, DOUBLE_DOME_SHORT, HEMISPHERE_SHORT
from tool_helpers import brute_force, wavy_sheet

SHORT = HEMISPHERE_SHORT


@pytest.fixture(scope="module")
def cad(tmp_path_factory):
    """STEP files of the default hemisphere's tools and a job file using them (every rank
    sees rank 0's folder)."""
    from mpi4py import MPI
    comm = MPI.COMM_WORLD
    folder = tmp_path_factory.mktemp("cad") if comm.rank == 0 else None
    folder = comm.bcast(folder, root=0)
    if comm.rank == 0:
        paths = write_hemisphere_step(folder)
        step_job(CONFIGS / "hemisphere.toml", folder, paths)
        (folder / "position").mkdir()
        step_job(CONFIGS / "hemisphere.toml", folder / "position", paths, control="position")
    comm.barrier()
    return folder


def load(path, overrides=()):
    from drape.job import load_job
    return load_job(path, overrides=list(overrides))


# --- configuration --------------------------------------------------------------------------

def test_a_bad_holder_control_is_refused_with_the_key_and_the_choices(cad):
    from drape.errors import InputError
    with pytest.raises(InputError) as caught:
        load(cad / "hemisphere_step.toml", ["tools.step.holder.control=\"pressure\""])
    message = str(caught.value)
    assert "tools.step.holder.control" in message and "'pressure'" in message
    assert "'force', 'position'" in message


def test_a_force_controlled_step_holder_needs_a_die(cad):
    from drape.errors import InputError
    from drape.forming.checks import check_forming, holder_mode
    job = load(cad / "hemisphere_step.toml")
    assert holder_mode(job.config) == "force"                  # the default
    assert holder_mode(load(cad / "position" / "hemisphere_step.toml").config) == "position"
    assert holder_mode(load(cad / "hemisphere_step.toml",
                            ["process.holder_force=0"]).config) is None
    with pytest.raises(InputError) as caught:
        load(cad / "hemisphere_step.toml", ["tools.step.die.file=\"\""])
    assert "tools.step.holder.control" in str(caught.value)
    assert "die" in str(caught.value)
    check_forming(job.config)                                  # with its die: fine


# --- the holder's flat face found on the tools ------------------------------------------------

def test_the_step_holders_flat_face_is_the_built_in_holders_ring(cad, comm):
    """pinch_region on the meshed STEP tools against holder_region of the built-in hemisphere
    (r >= holder_inner_radius + holder_fillet_radius = 70 mm, to the die's edge): the same
    points but for a band of the fillet's own tolerance (1 degree of its 5 mm radius: r from
    69.91 to 70 mm, and the points at 70 mm by round-off); the opening between holder and die
    is 0 (both faces at z = 0)."""
    from drape.forming.holder import holder_region, pinch_region
    from drape.geometry.tools import build_tools, load_tools_config
    from drape.forming.surfaces import MeshedSurface
    tools = load_tools_config(cad / "hemisphere_step.toml", "tools")
    surfaces = {name: MeshedSurface(s) for name, s in build_tools(tools, comm=comm).items()}
    rng = np.random.default_rng(3)
    points = np.column_stack([rng.uniform(-100, 100, (20000, 2)), np.zeros(20000)])
    mask, opening = pinch_region(surfaces["holder"], surfaces["die"], points, comm)
    builtin = holder_region(load(CONFIGS / "hemisphere.toml").config)(points)
    r = np.hypot(points[:, 0], points[:, 1])
    differ = mask != builtin
    assert differ.sum() < 40           # the band holds about 19 of the 20 000 points
    assert np.all((r[differ] > 70.0 - 5.0 * np.sin(np.radians(1.0)) - 1e-9)
                  & (r[differ] < 70.0 + 1e-9))
    assert opening == pytest.approx(0.0, abs=1e-12)
    # lifted by 0.3 mm (the holder's face above the blank): the same ring, opening 0.3 mm
    lifted = SimpleNamespace(query=lambda p, offset=None, cutoff=None: surfaces["holder"].query(
        p, (0.0, 0.0, 0.3), cutoff))
    mask_lifted, opening = pinch_region(lifted, surfaces["die"], points, comm)
    assert opening == pytest.approx(0.3, abs=1e-12)
    assert (mask_lifted != mask).sum() < 5


# --- the warning -------------------------------------------------------------------------------

def test_a_holder_force_more_than_five_percent_off_is_a_warning_with_the_step():
    """Forming.control_holder after converged steps measuring 200, 209.9 (4.95 % off) and
    211 N (5.5 %) of F = 200 N: one warning, naming step 3 and both forces."""
    from drape.forming.holder import HolderControl
    from drape.forming.press import Forming
    from drape.step_record import StepRecord
    said = []
    holder = HolderControl(200.0, area=1000.0, penalty=1.0, smoothing=0.1)
    forming = SimpleNamespace(holder=holder, process=SimpleNamespace(holder_force=200.0),
                              holder_warnings=[], say=said.append)
    for step, force in enumerate((200.0, 209.9, 211.0), start=1):
        Forming.control_holder(forming, StepRecord(step, 0.1 * step, columns={
            "stroke": 0.5 * step, "holder_force": force}))
    assert forming.holder_warnings == [(3, 211.0)]
    assert len(said) == 1
    assert "step 3" in said[0] and "211 N" in said[0] and "200 N" in said[0]
    assert "+5.5 %" in said[0]


# --- candidate lists ------------------------------------------------------------------------

@pytest.mark.serial   # no MPI in it: under mpirun each rank would do the same
@pytest.mark.parametrize("cutoff", [None, 3.0])
def test_candidate_lists_give_the_exact_closest_points_as_points_move(cutoff):
    """MeshedSurface with candidate lists (margin 0.5 mm) on an irregular sheet, 2000 points
    moved 12 times by small (0.15 mm) and large (1 mm) random steps: every answer within the
    cutoff is the brute-force closest point over all triangles (distance and point) and the
    plain search's answer (gap, normal), farther ones stay above the cutoff; most points are
    answered from their lists."""
    from drape.forming.surfaces import MeshedSurface
    sheet = wavy_sheet()
    tool, plain = MeshedSurface(sheet, margin=0.5), MeshedSurface(sheet)
    rng = np.random.default_rng(7)
    p = rng.uniform(-15.0, 15.0, (2000, 3)) * [1.0, 1.0, 0.3]
    for move in range(12):
        p = p + rng.normal(0.0, 1.0 if move % 4 == 0 else 0.15, p.shape)
        offset = (0.0, 0.0, 0.1 * move)
        got = tool.query(p, offset=offset, cutoff=cutoff)
        distance, closest = brute_force(sheet, p - offset)
        near = distance <= (np.inf if cutoff is None else cutoff)
        assert near.sum() > 500
        np.testing.assert_allclose(np.abs(got.gap[near]), distance[near], atol=1e-12)
        np.testing.assert_allclose(got.closest[near], closest[near] + offset, atol=1e-12)
        want = plain.query(p, offset=offset, cutoff=cutoff)
        np.testing.assert_allclose(got.gap[near], want.gap[near], atol=1e-12)
        np.testing.assert_allclose(got.normal[near], want.normal[near], atol=1e-12)
        if cutoff is not None:
            assert np.all(np.abs(got.gap[~near]) > cutoff)
    assert tool.searched < 0.5 * 12 * len(p)


# --- the same job with STEP and built-in tools -------------------------------------------

def run(path, folder, overrides=(), short=SHORT):
    from mpi4py import MPI

    from drape.run import run_job
    said = []
    summary = run_job(load(path, list(short) + list(overrides)), MPI.COMM_WORLD,
                      output=str(folder), log=said.append)
    MPI.COMM_WORLD.barrier()
    return summary, json.loads((folder / "summary.json").read_text()), said


@pytest.fixture(scope="module")
def both(cad, hemisphere_5mm, tmp_path_factory):
    """The built-in tools' run (the session's, tests/conftest.py) and the STEP tools' one, each
    (RunSummary, summary.json, the lines it logged)."""
    from mpi4py import MPI
    folder = tmp_path_factory.mktemp("runs") if MPI.COMM_WORLD.rank == 0 else None
    folder = MPI.COMM_WORLD.bcast(folder, root=0)
    _, summary, builtin, said = hemisphere_5mm
    return {"builtin": (summary, json.loads((builtin / "summary.json").read_text()), said),
            "step": run(cad / "hemisphere_step.toml", folder / "step")}


@pytest.mark.serial
def test_step_tools_give_the_built_in_tools_answer(both):
    """The default hemisphere job, 5 mm, with its built-in tools and with the same tools from
    STEP files (meshed by gmsh, chord error <= 0.05 mm against the smoothing's 0.195 mm):
    peak shear, the four mid-side draw-ins and the punch force at the end within 2 %; the
    holder force within 1 % of its 200 N at every converged step of both runs (the STEP
    holder force-controlled like the built-in one), and the summaries say so."""
    (_, builtin, _), (step_summary, step, said) = both["builtin"], both["step"]
    assert step["stroke_mm"] == builtin["stroke_mm"] == 5.0
    assert step["max_shear_angle_deg"] == pytest.approx(builtin["max_shear_angle_deg"], rel=0.02)
    assert builtin["max_shear_angle_deg"] > 0.5
    for side in ("mid_right", "mid_top", "mid_left", "mid_bottom"):
        assert step["draw_in_mm"][side] == pytest.approx(builtin["draw_in_mm"][side], rel=0.02)
    assert builtin["draw_in_mm"]["mid_right"] > 0.1
    assert step["punch_force_at_end_N"] == pytest.approx(builtin["punch_force_at_end_N"],
                                                         rel=0.02)
    for report in (builtin, step):
        assert report["holder_control"] == "force"
        assert report["holder_force_N"] == 200.0
        assert report["holder_force_steps_off_5pct"] == 0
        low, high = report["holder_force_measured_N"]
        assert 198.0 <= low <= high <= 202.0
    for row in step_summary.rows[1:]:
        assert row.columns["holder_force"] == pytest.approx(200.0, rel=0.01), row.step
    assert any("holder force 200 N (force-controlled)" in line for line in said)


def test_a_position_controlled_step_holder_reports_the_force_it_measured(cad, shared_tmp):
    # both passes: a forming run with meshed STEP tools on 2 ranks
    """With control = "position" the holder stays at z = 0 where the die's top is: the blank
    between them is squeezed by the smoothed penalty of both (thousands of N, not the config's
    200 N), and the log and summary.json state the measured force, not process.holder_force."""
    summary, report, said = run(cad / "position" / "hemisphere_step.toml",
                                shared_tmp / "position",
                                ["process.stroke=0.25", "steps.initial=1", "steps.maximum=1"])
    measured = summary.rows[-1].columns["holder_force"]
    assert measured > 1000.0
    assert report["holder_control"] == "position"
    assert report["holder_force_N"] == pytest.approx(measured, rel=1e-12)
    assert report["holder_force_measured_N"] == pytest.approx([measured, measured], rel=1e-12)
    assert "holder_force_steps_off_5pct" not in report
    assert not any("200 N" in line for line in said)
    assert any("position-controlled" in line and "not applied" in line for line in said)
    assert any(f"{measured:.5g}" in line for line in said)


@pytest.mark.serial
def test_step_tools_give_the_built_in_double_domes_answer(shared_tmp, comm, double_dome_short):
    """The shipped 0/90 double-dome job (h = 7.5 mm, with the blank's inertia), 3 mm in steps
    of 0.3-0.6 mm, with its exact tools (the session's run, tests/conftest.py) and with the same
    tools written as STEP by gmsh (die and holder plates 50 mm wider all round: the exact ones
    are unbounded outward): peak shear, the mid-side draw-ins and the punch force within 2 %,
    the holder within 1 % of its 500 N at every converged step (measured 2026-12-05: +1.0 %,
    -0.9 %, -0.3 %; 498.0-501.8 N)."""
    from cad_helpers import write_double_dome_step
    folder = shared_tmp / "double_dome"
    if comm.rank == 0:
        step_job(CONFIGS / "double_dome.toml", folder, write_double_dome_step(folder / "cad"))
    comm.barrier()
    _, _, builtin_folder = double_dome_short("double_dome.toml")
    builtin = json.loads((builtin_folder / "summary.json").read_text())
    step_summary, step, _ = run(folder / "double_dome_step.toml", folder / "step",
                                short=DOUBLE_DOME_SHORT)
    assert step["max_shear_angle_deg"] == pytest.approx(builtin["max_shear_angle_deg"], rel=0.02)
    for side in ("mid_right", "mid_left"):
        assert builtin["draw_in_mm"][side] > 0.3
        assert step["draw_in_mm"][side] == pytest.approx(builtin["draw_in_mm"][side], rel=0.02)
    assert step["punch_force_at_end_N"] == pytest.approx(builtin["punch_force_at_end_N"],
                                                         rel=0.02)
    for report in (builtin, step):
        low, high = report["holder_force_measured_N"]
        assert 495.0 <= low <= high <= 505.0
        assert report["holder_force_steps_off_5pct"] == 0
    for row in step_summary.rows[1:]:
        assert row.columns["holder_force"] == pytest.approx(500.0, rel=0.01), row.step
