"""Material files: the shipped ones load with the paper's values, bad ones are refused clearly."""

import subprocess
import sys

import pytest

from conftest import CONFIGS
from drape.errors import InputError
from drape.law.parameters import (PAPER_A, PAPER_Q, MaterialParameters, load_material,
                                  material_toml)

# no MPI in these tests: under mpirun each rank would do the same (tests/conftest.py)
pytestmark = pytest.mark.serial

GOOD = CONFIGS / "materials" / "paper_three_surface.toml"


def test_shipped_materials_hold_the_papers_tables():
    three = load_material(GOOD)
    one = load_material(CONFIGS / "materials" / "paper_one_surface.toml")
    assert three == MaterialParameters()          # the code's defaults are the paper's values
    assert three.n == 2 and one.n == 0
    assert three.Q == PAPER_Q and three.A == PAPER_A and one.Q == PAPER_Q
    assert (three.K1, three.K2, three.Ksh, three.Sy) == (10000.0, 10000.0, 142.0,
                                                         (0.0081, 0.006, 0.0025))
    assert three.surfaces.h[4] == (4.0, 10.0) and three.surfaces.a[2] == (0.9, 0.6)
    assert one.Sy == (0.0081,)
    assert load_material(GOOD, surfaces=0).Sy == one.Sy


def test_material_toml_round_trip(tmp_path):
    path = tmp_path / "m.toml"
    params = load_material(GOOD).with_surfaces(1)
    path.write_text(material_toml(params))
    assert load_material(path) == params


BASE = GOOD.read_text()

# (what is wrong, how the file is changed, text the message must contain)
BAD_FILES = [
    ("unknown key", BASE.replace("Ksh = 142.0", "Kshh = 142.0"), ["'Kshh'", "did you mean 'Ksh'"]),
    ("negative stiffness", BASE.replace("K1 = 10000.0", "K1 = -5.0"), ["'K1'", "-5.0", "> 0"]),
    ("wrong type", BASE.replace("Ksh = 142.0", 'Ksh = "soft"'), ["'Ksh'", "'soft'", "a number"]),
    ("surfaces not nested",
     BASE.replace("Sy = [0.0081, 0.006, 0.0025]", "Sy = [0.0081, 0.009, 0.0025]"),
     ["'Sy'", "not nested", "Sy_0 > Sy_1"]),
    ("table rows of the wrong length",
     BASE.replace("a = [[0.9, 0.85], [0.9, 0.75], [0.9, 0.6], [0.9, 0.5], [0.99, 0.45]]",
                  "a = [[0.9, 0.85], [0.9, 0.75], [0.9, 0.6], [0.9, 0.5]]"),
     ["'surfaces.a'", "4 rows", "5 ranges"]),
    ("ranges not increasing",
     BASE.replace("[0.0, 19.0, 28.0, 32.0, 37.0]", "[0.0, 19.0, 32.0, 28.0, 37.0]"),
     ["'surfaces.gamma_max_deg'", "not strictly increasing"]),
    ("radius factors not nested", BASE.replace("[0.9, 0.6]", "[0.6, 0.9]"),
     ["'surfaces.a[2]'", "1 >= a_1 >= a_2"]),
    ("non-positive centre speed", BASE.replace("[1.5, 4.0]", "[1.5, 0.0]"),
     ["'surfaces.h[2]'", "h_k > 0"]),
    ("table narrower than Sy",
     BASE.replace("Sy = [0.0081, 0.006, 0.0025]", "Sy = [0.0081, 0.006, 0.0025, 0.001]"),
     ["'surfaces.a'", "3 columns"]),
    ("not TOML", BASE.replace("K2 = 10000.0", "K2 = = 1"), ["not valid TOML"]),
    ("unknown table key", BASE.replace("[surfaces]", "[surfaces]\nslope = 1.0"),
     ["'surfaces.slope'", "unknown key"]),
]


@pytest.mark.parametrize("problem, text, expected", BAD_FILES, ids=[b[0] for b in BAD_FILES])
def test_bad_material_file_is_refused_with_the_key(tmp_path, problem, text, expected):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(InputError) as error:
        load_material(path)
    message = error.value.message
    assert str(path) in message
    for fragment in expected:
        assert fragment in message, (fragment, message)


@pytest.mark.serial
@pytest.mark.parametrize("problem, text, expected", BAD_FILES[:4] + [BAD_FILES[9]],
                         ids=lambda v: v if isinstance(v, str) and len(v) < 40 else "")
def test_cli_refuses_bad_material_with_exit_code_2(tmp_path, problem, text, expected):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    run = subprocess.run([sys.executable, "-m", "drape.cli", "picture-frame", "--material",
                          str(path),
                          "--output", str(tmp_path / "out")], capture_output=True, text=True)
    assert run.returncode == 2
    assert "Traceback" not in run.stderr
    assert run.stderr.startswith("drape picture-frame: error: ")
    for fragment in expected:
        assert fragment in run.stderr
    assert not (tmp_path / "out").exists()      # nothing computed, nothing written


@pytest.mark.serial
def test_cli_missing_material_file(tmp_path):
    run = subprocess.run([sys.executable, "-m", "drape.cli", "picture-frame", "--material",
                          str(tmp_path / "nope.toml")], capture_output=True, text=True)
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert "nope.toml: file not found; expected the path of an existing TOML file" in run.stderr
