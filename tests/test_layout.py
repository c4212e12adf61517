"""The package layout: the gmsh builders of the top-level geometry/ import as drape.geometry
from a plain checkout (no install), as they do when installed."""

import os
import subprocess
import sys

import pytest

from conftest import REPO

pytestmark = pytest.mark.serial


def test_geometry_imports_from_a_plain_checkout(tmp_path):
    """A Python that has only the checkout on its path finds drape.geometry in geometry/."""
    code = ("import drape, drape.geometry.blank as b, drape.geometry.tools as t; "
            "print(b.__file__); print(t.__file__); print(drape.__file__)")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["PYTHONPATH"] = str(REPO)
    out = subprocess.run([sys.base_prefix + "/bin/python3", "-c", code], cwd=tmp_path,
                         env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    blank, tools, package = out.stdout.split()
    assert blank == str(REPO / "geometry" / "blank.py")
    assert tools == str(REPO / "geometry" / "tools.py")
    assert package == str(REPO / "drape" / "__init__.py")


def test_loading_a_config_imports_no_physics():
    """The config layer (drape.job) checks a forming job without the forming process, the
    membrane problem or DOLFINx: loading a job stays quick and sits below the physics."""
    code = ("import sys; from drape.job import load_job; "
            "load_job('configs/hemisphere.toml'); load_job('configs/double_dome.toml'); "
            "print(sorted(m for m in sys.modules if m.startswith(('dolfinx', 'ufl', "
            "'drape.forming.press', 'drape.fe.membrane', 'drape.step_loop'))))")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"
