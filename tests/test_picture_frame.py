"""`drape picture-frame`: histories, one increment per row, outputs, bad input."""

import csv
import subprocess
import sys

import numpy as np
import pytest

from drape.errors import InputError
from drape.law.parameters import MaterialParameters
from drape.picture_frame import cyclic_history, drive, parse_cycles, read_history

# no MPI in these tests: under mpirun each rank would do the same (tests/conftest.py)
pytestmark = pytest.mark.serial

COLUMNS = ["gamma_t_deg", "tau", "gamma_p_deg", "active_surface", "branch_surface",
           "branch_direction", "table_row"]


def read_columns(path):
    with open(path, newline="") as stream:
        rows = list(csv.DictReader(stream))
    return {key: np.array([float(r[key]) for r in rows]) for key in rows[0]}


def test_cyclic_history_goes_to_each_amplitude_and_back_in_equal_increments():
    history = cyclic_history([10, -4], 1.5)
    legs = [np.linspace(0, 10, 8)[1:], np.linspace(10, 0, 8)[1:],
            np.linspace(0, -4, 4)[1:],
            np.linspace(-4, 0, 4)[1:]]   # ceil(10/1.5) = 7, ceil(4/1.5) = 3
    np.testing.assert_allclose(history, np.concatenate(legs), rtol=0, atol=1e-12)
    assert parse_cycles("10, 20,-40") == [10.0, 20.0, -40.0]
    for bad in ("10,abc", "0", "95", ""):
        with pytest.raises(InputError):
            parse_cycles(bad)


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "drape.cli", "picture-frame", *map(str, args)],
                          capture_output=True, text=True)


@pytest.mark.serial
def test_history_file_rows_are_exactly_the_increments(tmp_path):
    angles = np.concatenate([np.linspace(0, 25, 11)[1:], [24.0, 12.5, -3.0],
                             np.linspace(-3, 35, 7)[1:]])
    history = tmp_path / "history.csv"
    history.write_text("gamma_t_deg\n" + "\n".join(repr(a) for a in angles) + "\n")
    run = run_cli("--history", history, "--output", tmp_path / "out")
    assert run.returncode == 0, run.stderr
    out = read_columns(tmp_path / "out" / "picture_frame.csv")
    assert set(COLUMNS) <= set(out)
    np.testing.assert_array_equal(out["gamma_t_deg"], angles)          # one row per increment
    reference = drive(MaterialParameters(), angles)                    # the same law, in-process
    np.testing.assert_array_equal(out["tau"], reference["tau"])
    np.testing.assert_array_equal(out["active_surface"], reference["active_surface"])
    # the state's branch: the direction follows the increments' signs (10 up, 3 down, 6 up),
    # the row is latched when a branch starts: row 0 at first yield, then row 1 (gamma_max 25
    # deg, in [19, 28)) at both reversals
    steps = np.sign(np.diff(np.r_[0.0, angles]))
    np.testing.assert_array_equal(out["branch_direction"], steps)
    np.testing.assert_array_equal(out["table_row"], [0] * 10 + [1] * 3 + [1] * 6)
    assert np.all(out["branch_surface"] <= 2) and out["branch_surface"][-1] == 0
    single = read_columns(tmp_path / "out" / "picture_frame_one_surface.csv")
    np.testing.assert_array_equal(single["tau"],
                                  drive(MaterialParameters().with_surfaces(0), angles)["tau"])
    png = (tmp_path / "out" / "picture_frame.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20000


@pytest.mark.serial
def test_cycles_equal_the_same_history_given_as_a_file(tmp_path):
    run = run_cli("--cycles", "10,-15", "--increment", "0.5", "--surfaces", "0", "--output",
                  tmp_path / "a")
    assert run.returncode == 0, run.stderr
    assert not (tmp_path / "a" / "picture_frame_one_surface.csv").exists()   # nothing to compare
    a = read_columns(tmp_path / "a" / "picture_frame.csv")
    assert a["gamma_t_deg"].size == 20 + 20 + 30 + 30
    (tmp_path / "h.csv").write_text("gamma_t_deg\n" + "\n".join(repr(v) for v in a["gamma_t_deg"]))
    run = run_cli("--history", tmp_path / "h.csv", "--surfaces", "0", "--output", tmp_path / "b")
    b = read_columns(tmp_path / "b" / "picture_frame.csv")
    np.testing.assert_array_equal(a["tau"], b["tau"])
    # the one-surface model: the stress always lies on or inside q +- (Sy0 + alpha)
    assert np.all(a["active_surface"] <= 0)


def test_read_history_refuses_bad_files(tmp_path):
    cases = {
        "angle\n1\n2\n": "no 'gamma_t_deg' column",
        "gamma_t_deg\n1\nx\n": "line 3: not a shear angle",
        "gamma_t_deg\n1\n95\n": "line 3: not a shear angle",
        "gamma_t_deg\n": "no rows",
    }
    for text, problem in cases.items():
        path = tmp_path / "h.csv"
        path.write_text(text)
        with pytest.raises(InputError) as error:
            read_history(path)
        assert problem in error.value.message and str(path) in error.value.message
    with pytest.raises(InputError, match="file not found"):
        read_history(tmp_path / "missing.csv")


@pytest.mark.serial
def test_cli_bad_history_and_cycles_exit_2(tmp_path):
    (tmp_path / "h.csv").write_text("gamma_t_deg\n1\nnan\n")
    for args in (["--history", tmp_path / "h.csv"], ["--cycles", "10,x"], ["--increment", "-1"],
                 ["--surfaces", "5"]):
        run = run_cli(*args, "--output", tmp_path / "out")
        assert run.returncode == 2, (args, run.stderr)
        assert "Traceback" not in run.stderr and "error:" in run.stderr
    assert not (tmp_path / "out").exists()


def test_reversal_points_and_cycles_of_the_plots():
    from drape.picture_frame import cycle_starts, reversal_indices
    history = np.concatenate([[0.0], cyclic_history([10, 20, -40], 5.0)])
    # 0 5 10 5 0 5 10 15 20 15 10 5 0 -5 ... -40 ... 0
    turns = reversal_indices(history)
    assert history[turns].tolist() == [10.0, 0.0, 20.0, -40.0]   # 20 -> 0 -> -40 goes on
    assert turns.tolist() == [2, 4, 8, 20]
    assert cycle_starts(history).tolist() == [0, 4, 12]
    assert reversal_indices([0.0, 1.0, 1.0, 2.0]).size == 0          # no turn, plateaus skipped
    assert reversal_indices([0.0, 1.0, 1.0, 0.5]).tolist() == [2]    # the last point of the peak
