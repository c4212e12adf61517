"""`drape run` as users run it: every shipped job config (its short version) gives serially and
under `mpirun -n 2` the same results (displacement within 1e-8 mm and tau within 1e-8 relative,
from the partition-independent result.npz) and prints nothing under --quiet; bad input is exit
code 2 and a failed run exit code 1, each with a one-line message and no traceback (every bad
input: tests/test_bad_inputs.py)."""

import os
import shlex
import subprocess
import sys

import numpy as np
import pytest

from conftest import CONFIGS, REPO

pytestmark = pytest.mark.serial

NO_FIELDS = ["--set", "output.xdmf=false", "--quiet"]

COARSE_HEMISPHERE = ["tools.hemisphere.die_fillet_radius=10", "mesh.size=7.8"]
COARSE_DOUBLE_DOME = ["tools.double_dome.die_entry_radius=11.9",
                      "tools.double_dome.punch_edge_radius=11.9", "mesh.size=9.3"]

#: the short version of each shipped job config (top-level configs/*.toml): --set overrides
#: giving a coarse mesh and a truncated history, a run of seconds that still yields (plastic
#: shear, tau != 0). A new job config in configs/ needs an entry here (a test says so).
SHORT_OVERRIDES = {
    # 4 x 4 elements, one cycle 0 -> 10 -> 0 deg in 20 steps
    "picture_frame.toml": ["mesh.size=25", "history.angle.values=[0, 10, 0]",
                           "history.angle.t=[0, 0.5, 1]", "steps.initial=0.05",
                           "steps.maximum=0.05"],
    # the +-45 deg lattice at 10 mm, the clamp pulled 6 mm (about 10 deg of shear)
    "bias_extension.toml": ["mesh.size=10", "history.d.values=[0, 6]", "steps.initial=0.1",
                            "steps.maximum=0.2"],
    # forming: the punch 0.5 mm down in 2 steps (the double dome 1.5 mm in three: its first
    # step lifts the blank off the die, the next two have the blank's inertia, from rest and
    # then moving), the fillets enlarged so that coarser meshes are allowed (as in
    # tests/test_fe_faults.py): the hemisphere's 676 cells instead of 2601, the double dome's
    # 1479 instead of 2040 (the partition's independence needs no finer mesh)
    "hemisphere.toml": ["process.stroke=0.5", "steps.initial=0.5", "steps.maximum=0.5",
                        *COARSE_HEMISPHERE],
    "hemisphere_45.toml": ["process.stroke=0.5", "steps.initial=0.5", "steps.maximum=0.5",
                           *COARSE_HEMISPHERE],
    "double_dome.toml": ["process.stroke=1.5", "steps.initial=0.3334", "steps.maximum=0.3334",
                         *COARSE_DOUBLE_DOME],
    "double_dome_45.toml": ["process.stroke=1.5", "steps.initial=0.3334",
                            "steps.maximum=0.3334", *COARSE_DOUBLE_DOME],
    # stacks of plies (docs/plies.md), made short and coarse as the single plies
    "hemisphere_2ply.toml": ["process.stroke=0.5", "steps.initial=0.5", "steps.maximum=0.5",
                             *COARSE_HEMISPHERE],
    "double_dome_4ply.toml": ["process.stroke=1.5", "steps.initial=0.3334",
                              "steps.maximum=0.3334", *COARSE_DOUBLE_DOME],
}
#: shipped configs whose short version does not run yet (an expected failure, strict: the test
#: says when it starts to work)
KNOWN_FAILING: dict[str, str] = {}
#: shipped configs whose short run is too long for every suite (name -> why): skipped unless
#: DRAPE_ALL_SHIPPED=1
TOO_LONG: dict[str, str] = {
    "double_dome_4ply.toml": "4 plies: 5.5 minutes on 1 and 2 ranks (passes, "
                             "docs/plies-forming.md); DRAPE_ALL_SHIPPED=1 runs it"}
#: top-level configs/*.toml files that are not `drape run` jobs (name -> why); materials and
#: tools live in configs/materials and configs/tools
NOT_JOBS: dict[str, str] = {}


def shipped_jobs() -> list[str]:
    return sorted(p.name for p in CONFIGS.glob("*.toml") if p.name not in NOT_JOBS)


def drape(*args, ranks=1, cwd=None):
    command = [sys.executable, "-m", "drape.cli", *map(str, args)]
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1")
    if ranks > 1:
        command = ["mpirun", "-n", str(ranks), "--oversubscribe", *command]
    return subprocess.run(command, capture_output=True, text=True, cwd=cwd or REPO, env=env,
                          timeout=900)


def test_every_shipped_job_has_a_short_version():
    assert shipped_jobs(), "no job config found in configs/"
    missing = [name for name in shipped_jobs() if name not in SHORT_OVERRIDES]
    assert not missing, (f"configs/{missing} have no short version: add SHORT_OVERRIDES entries "
                         "(or NOT_JOBS) in tests/test_fe_cli.py")


def job_param(name: str):
    """A shipped job as the 1-vs-2-rank test's parameter: plain, a strict xfail if it is known
    to fail, skipped if its run is too long for every suite (TOO_LONG) and DRAPE_ALL_SHIPPED
    is not 1."""
    if name in TOO_LONG and os.environ.get("DRAPE_ALL_SHIPPED") != "1":
        return pytest.param(name, marks=pytest.mark.skip(reason=TOO_LONG[name]))
    if name in KNOWN_FAILING:
        return pytest.param(name, marks=pytest.mark.xfail(strict=True, reason=KNOWN_FAILING[name]))
    return name


@pytest.mark.parametrize("config", [job_param(name) for name in shipped_jobs()])
def test_one_and_two_ranks_give_the_same_results(tmp_path, config):
    assert config in SHORT_OVERRIDES, f"no short version of configs/{config} in SHORT_OVERRIDES"
    short = [arg for text in SHORT_OVERRIDES[config] for arg in ("--set", text)]
    results = {}
    for ranks in (1, 2):
        folder = tmp_path / f"ranks{ranks}"
        done = drape("run", CONFIGS / config, "--output", folder, *short, *NO_FIELDS,
                     ranks=ranks)
        assert done.returncode == 0, done.stderr
        assert done.stdout == "", done.stdout                  # --quiet: no progress
        results[ranks] = np.load(folder / "result.npz")
        steps = (folder / "steps.csv").read_text().splitlines()
        results[ranks, "steps"] = [line.split(",")[:2] for line in steps]
    one, two = results[1], results[2]
    assert results[1, "steps"] == results[2, "steps"]          # the same load steps
    assert np.allclose(one["node_xy"], two["node_xy"], rtol=0, atol=1e-12)
    assert np.allclose(one["point_xy"], two["point_xy"], rtol=0, atol=1e-12)
    for key in ("node_ply", "point_ply"):                      # a stack's: sorted by ply first
        assert (key in one) == (key in two)
        assert key not in one or np.array_equal(one[key], two[key])
    # displacement within 1e-8 mm (the picture frame ends back at angle 0: u ~ 0 there), tau
    # within 1e-8 of its largest value (not 0: the cycles leave plastic shear behind)
    assert np.abs(one["u"] - two["u"]).max() <= 1e-8
    assert np.abs(one["tau"]).max() > 1e-3
    assert np.abs(one["tau"] - two["tau"]).max() <= 1e-8 * np.abs(one["tau"]).max()


def test_bad_input_is_exit_code_2_with_one_line(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text((CONFIGS / "bias_extension.toml").read_text()
                   .replace("[mesh]", "[mesh]\nsise = 3"))
    cases = [
        (["run", bad], "key 'mesh.sise'", "did you mean 'size'"),
        (["run", tmp_path / "missing.toml"], "missing.toml", "file not found"),
        (["run", CONFIGS / "bias_extension.toml", "--set", "blank.length=141"],
         "key 'blank.length'",
         "does not fit a +-45 deg yarn lattice"),
        (["run", CONFIGS / "bias_extension.toml", "--set", "mesh.size=0.01"], "key 'mesh.size'",
         "elements"),
        (["run", CONFIGS / "bias_extension.toml", "--set", "steps.cutback=1.5"],
         "key 'steps.cutback'",
         "(0.0, 1.0)"),
    ]
    for args, where, what in cases:
        done = drape(*args, "--output", tmp_path / "out")
        assert done.returncode == 2, (args, done.stderr)
        message = done.stderr.strip()
        assert len(message.splitlines()) == 1 and "Traceback" not in message
        assert where in message and what in message, message


def test_a_failed_run_is_exit_code_1_under_mpi_too(tmp_path):
    from test_fe_divergence import write_jump
    config = write_jump(tmp_path)
    for ranks in (1, 2):
        folder = tmp_path / f"jump{ranks}"
        done = drape("run", config, "--output", folder, "--quiet", ranks=ranks)
        assert done.returncode == 1, done.stderr
        lines = [line for line in done.stderr.splitlines() if line.startswith("drape run")]
        assert len(lines) == 1 and "Traceback" not in done.stderr
        assert "run failed: step" in lines[0] and f"are in {folder}" in lines[0]
        assert len((folder / "steps.csv").read_text().splitlines()) > 10
        # the printed command resumes it (and fails at the jump again, after more cutbacks;
        # with more iterations it goes on: test_fe_divergence.py)
        head, command = lines[0].split("settings: ")
        assert "--set steps.minimum=0.0001 (or other steps.* and solver.* values)" in command
        words = shlex.split(command.split(" (or other")[0])
        mpirun = ["mpirun", "-n", "2"] if ranks > 1 else []
        assert words == mpirun + ["drape", "run", str(config), "--resume", "--output",
                                  str(folder), "--set", "steps.minimum=0.0001"]
        again = drape(*words[len(mpirun) + 1:], ranks=ranks)
        assert again.returncode == 1, again.stderr
        assert "resuming with other numerical controls: steps.minimum (0.001 -> 0.0001)" in \
            again.stdout
        assert "a smaller step" in again.stderr and "below steps.minimum = 0.0001" in again.stderr
