"""The job config of `drape run` (drape.job, drape.fe.loading) and the step logic (drape.fe.solver):
validation with clear errors, formulas, histories, load steps and cutbacks. No DOLFINx here."""

import math
import textwrap

import numpy as np
import pytest

from conftest import CONFIGS
from drape.errors import InputError, RunFailed
from drape.job import StepsConfig, key_table, load_job
from drape.fe.loading import Formula, Loading, VARIABLES
from drape.fe.solver import SolveResult, next_load, parse_option, run_load_steps

# no MPI in these tests: under mpirun each rank would do the same (tests/conftest.py)
pytestmark = pytest.mark.serial


def write(tmp_path, text, name="job.toml"):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


MINIMAL = """
    [history.d]
    values = [0.0, 1.0]

    [[boundary]]
    on = "left"
    ux = "0"
    uy = "0"
    uz = "0"

    [[boundary]]
    on = "right"
    ux = "d"
"""


# --- loading the shipped configs --------------------------------------------------------------

@pytest.mark.parametrize("name", ["picture_frame.toml", "bias_extension.toml"])
def test_shipped_configs_load(name):
    job = load_job(CONFIGS / name)
    assert job.params.n == 2                     # the paper's three-surface material
    assert job.config.boundary


# --- bad input: file, key, value and what was expected -----------------------------------------

def error_of(tmp_path, text, overrides=None):
    with pytest.raises(InputError) as caught:
        load_job(write(tmp_path, text), overrides=overrides)
    return caught.value


def test_unknown_key_is_named_with_a_suggestion(tmp_path):
    error = error_of(tmp_path, "[mesh]\nsise = 2.0\n" + MINIMAL)
    assert error.key == "mesh.sise" and "did you mean 'size'" in error.message
    assert "job.toml" in error.message


def test_out_of_range_value(tmp_path):
    error = error_of(tmp_path, "[mesh]\nsize = -1.0\n" + MINIMAL)
    assert error.key == "mesh.size" and error.value == -1.0 and "> 0" in error.expected


def test_missing_file_and_missing_material(tmp_path):
    with pytest.raises(InputError, match="file not found"):
        load_job(tmp_path / "nope.toml")
    error = error_of(tmp_path, 'material = "no/such.toml"\n' + MINIMAL)
    assert error.key == "material" and "looked for" in error.expected


def test_unknown_name_in_a_formula_names_the_key(tmp_path):
    error = error_of(tmp_path, MINIMAL.replace('ux = "d"', 'ux = "2 * dd"'))
    assert error.key == "boundary[1].ux" and "unknown name 'dd'" in error.message


@pytest.mark.parametrize("formula, problem", [
    ("__import__('os')", "unknown function"),
    ("x.real", "not allowed"),                    # attribute access
    ("sin(x", "not an expression"),
    ("open(1)", "unknown function"),
    ("1 / (t - t)", "not finite"),                # evaluated at the breakpoints on load
])
def test_formulas_are_restricted(tmp_path, formula, problem):
    error = error_of(tmp_path, MINIMAL.replace('ux = "d"', f'ux = "{formula}"'))
    assert problem in error.message and error.key == "boundary[1].ux"


def test_history_and_boundary_rules(tmp_path):
    error = error_of(tmp_path,
                     MINIMAL.replace("values = [0.0, 1.0]", "values = [0.0, 1.0]\nt = [0.0, 0.5]"))
    assert error.key == "history.d.t" and "increasing from 0 to 1" in error.message
    error = error_of(tmp_path, MINIMAL.replace('on = "right"', 'on = "edge"'))
    assert error.key == "boundary[1].on" and "left, right, bottom, top, boundary" in error.expected
    error = error_of(tmp_path, "[history.sin]\nvalues = [0, 1]\n" + MINIMAL)
    assert error.key == "history.sin"
    error = error_of(tmp_path, MINIMAL.split("[[boundary]]")[0])
    assert error.key == "boundary"
    error = error_of(tmp_path, '[picture_frame]\nangle = "angle"\n' + MINIMAL)
    assert error.key == "picture_frame.angle"


def test_overrides_are_validated_like_the_file(tmp_path):
    path = write(tmp_path, MINIMAL)
    job = load_job(path, overrides=["mesh.size=2.5", "mesh.cell=triangle", "output.xdmf=false"])
    assert job.config.mesh.size == 2.5 and job.config.mesh.cell == "triangle"
    assert job.config.output.xdmf is False
    error = error_of(tmp_path, MINIMAL, overrides=["mesh.cell=hexagon"])
    assert error.key == "mesh.cell" and error.value == "hexagon"


def test_petsc_options_table_and_command_line(tmp_path):
    job = load_job(write(tmp_path, '[solver.petsc]\nsnes_monitor = ""\nksp_max_it = 5\n' + MINIMAL))
    assert job.config.solver.petsc == {"snes_monitor": "", "ksp_max_it": 5}
    assert parse_option("-drape_ksp_type=gmres") == ("ksp_type", "gmres")
    assert parse_option("snes_monitor") == ("snes_monitor", "")
    with pytest.raises(InputError):
        parse_option("=3")


def test_key_table_lists_every_table():
    table = key_table()
    for key in ("blank.yarn_angle", "mesh.pattern", "steps.cutback", "solver.petsc",
                "regularisation.out_of_plane_damping", "history.<name>.values", "boundary[].ux",
                "output.snapshot", "picture_frame.angle"):
        assert f"`{key}`" in table


# --- formulas and histories ---------------------------------------------------------------------

def test_picture_frame_formulas_are_eq_25():
    """u = (F - I) X with F = cos(g/2) I + sin(g/2)(G1 G2 + G2 G1), any yarn angle."""
    job = load_job(CONFIGS / "picture_frame.toml", overrides=["blank.yarn_angle=30"])
    loading = Loading.from_config(job.config)
    xy = np.array([[0.0, 0.0], [100.0, 0.0], [37.0, 100.0]])
    theta = math.radians(30.0)
    G1 = np.array([math.cos(theta), math.sin(theta)])
    G2 = np.array([-math.sin(theta), math.cos(theta)])
    for t in (0.02, 0.3, 0.9):
        g = math.radians(loading.histories["angle"](t))
        F = math.cos(g / 2) * np.eye(2) + math.sin(g / 2) * (np.outer(G1, G2) + np.outer(G2, G1))
        expected = xy @ (F - np.eye(2)).T
        entry = loading.prescribed[0]
        for i in range(2):
            assert np.allclose(loading.evaluate(entry.components[i], xy, t), expected[:, i],
                               atol=1e-12)
        assert np.all(loading.evaluate(entry.components[2], xy, t) == 0.0)


def test_history_is_piecewise_linear_and_breakpoints_are_its_waypoints():
    job = load_job(CONFIGS / "picture_frame.toml")
    loading = Loading.from_config(job.config)
    angle = loading.histories["angle"]
    t = np.asarray(job.config.history["angle"].t)
    assert np.allclose(angle(t), job.config.history["angle"].values)
    assert angle(0.5 * (t[1] + t[2])) == pytest.approx(5.0)
    assert np.array_equal(loading.breakpoints(), t[1:])


def test_formula_namespace():
    formula = Formula("x + 2 * y + t + theta + pi", set(VARIABLES), key="k")
    value = formula({"x": np.array([1.0]), "y": np.array([2.0]), "t": 0.5, "theta": 1.0})
    assert value[0] == pytest.approx(1 + 4 + 0.5 + 1 + math.pi)


# --- load steps -----------------------------------------------------------------------------------

def test_next_load_lands_on_breakpoints_in_equal_steps():
    points = np.array([0.25, 0.5, 1.0])
    assert next_load(0.0, 0.1, points) == pytest.approx(0.25 / 3)
    assert next_load(0.2, 0.1, points) == 0.25
    assert next_load(0.25, 1.0, points) == 0.5
    assert next_load(0.9, 0.5, points) == 1.0


def _steps(**kw):
    base = dict(initial=0.25, minimum=0.01, maximum=0.5, growth=2.0, cutback=0.5, easy_iterations=3)
    base.update(kw)
    return StepsConfig(**base)


def test_steps_cut_back_on_failure_and_grow_when_easy():
    attempts, accepted, rejected = [], [], []

    def attempt(t):
        attempts.append(t)
        ok = not (len(attempts) == 2)        # the second attempt fails
        return SolveResult(ok, 2, "CONVERGED" if ok else "DIVERGED_MAX_IT", 1e-12, 0.0)

    run_load_steps(_steps(), np.array([1.0]), attempt, accepted.append,
                   lambda: rejected.append(True))
    # 0.25 ok; the step grows to 0.5, taken as two equal pieces to the breakpoint 1: 0.625
    # fails; cut back to 0.1875 (four pieces): 0.4375 ok; then growing: 0.71875, 1.0
    assert attempts == pytest.approx([0.25, 0.625, 0.4375, 0.71875, 1.0])
    assert [s.t for s in accepted] == pytest.approx([0.25, 0.4375, 0.71875, 1.0])
    assert [s.cutbacks for s in accepted] == [0, 1, 0, 0]
    assert len(rejected) == 1


def test_a_resume_starts_with_its_saved_step_size_at_most_the_maximum():
    """A resume continues with the checkpoint's next step size (dt0), unless its config lowered
    steps.maximum below it (drape.io.checkpoint.CONTROL_KEYS); no dt0: steps.initial."""
    def steps_from(t0, dt0, **kw):
        attempts = []

        def attempt(t):
            attempts.append(t)
            return SolveResult(True, 5, "CONVERGED", 1e-12, 0.0)     # not easy: no growth
        run_load_steps(_steps(**kw), np.array([1.0]), attempt, lambda step: None,
                       lambda: None, t0=t0, step0=3, dt0=dt0)
        return np.diff([t0] + attempts)

    assert steps_from(0.2, 0.4) == pytest.approx([0.4, 0.4])
    assert steps_from(0.2, 0.4, maximum=0.2) == pytest.approx([0.2] * 4)
    assert steps_from(0.2, None, initial=0.3) == pytest.approx([0.8 / 3] * 3)  # landing on 1


def test_steps_below_the_minimum_raise_run_failed_naming_step_load_and_residual():
    accepted = []

    def attempt(t):
        ok = t <= 0.25
        return SolveResult(ok, 2, "CONVERGED" if ok else "DIVERGED_LINE_SEARCH", 0.123, 0.0)

    with pytest.raises(RunFailed) as caught:
        run_load_steps(_steps(), np.array([1.0]), attempt, accepted.append, lambda: None)
    message = str(caught.value)
    # every attempt beyond t = 0.25 fails: the step is halved until it would be below 0.01
    assert "step 2" in message and "from t = 0.25" in message and "1.230e-01" in message
    assert "DIVERGED_LINE_SEARCH" in message
    assert [s.t for s in accepted] == [0.25]


def test_the_docs_list_every_key():
    from conftest import REPO
    assert key_table() in (REPO / "docs" / "fe-solver.md").read_text()


def test_the_resume_command_repeats_the_run_with_the_changed_overrides_in_place():
    """drape.run.resume_command: the run's config, --output, --set and --petsc-option words
    with --resume, under mpirun on more than one rank; an override it is given replaces the
    run's own for the same key (a failed run suggests a smaller steps.minimum) instead of
    following it."""
    import argparse
    import shlex

    from drape.run import resume_command
    args = argparse.Namespace(config="jobs/my part.toml", output="out",
                              petsc_option=["snes_monitor"],
                              set=["steps.minimum=0.01", "output.xdmf=false"])
    assert shlex.split(resume_command(args, 1)) == [
        "drape", "run", "jobs/my part.toml", "--resume", "--output", "out", "--set",
        "steps.minimum=0.01", "--set", "output.xdmf=false", "--petsc-option", "snes_monitor"]
    assert shlex.split(resume_command(args, 2, ["steps.minimum=0.001"])) == [
        "mpirun", "-n", "2", "drape", "run", "jobs/my part.toml", "--resume", "--output", "out",
        "--set", "output.xdmf=false", "--set", "steps.minimum=0.001", "--petsc-option",
        "snes_monitor"]
