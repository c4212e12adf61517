"""Every bad input of tests/bad_inputs.py through the ``drape`` command line: exit code 2, one
message naming the file (or option), the key, the value and what was expected, no traceback,
nothing written; under ``mpirun -n 2`` the same, printed by rank 0 alone and without a hang;
and docs/bad-inputs.md is the table of what drape prints today.

The cases run bundled: one process (one ``mpirun``) runs them all through drape.cli.main, which
is what the ``drape`` script calls; each case in its own folder. A few cases also run as their
own ``python -m drape.cli`` process, serially and under mpirun, for the process's real exit code
and stderr.
"""

import json
import os
import subprocess
import sys

import pytest

from bad_inputs import CASES, DOC, RUNNER_TIMEOUT, table
from conftest import REPO

pytestmark = pytest.mark.serial

ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
           OMPI_MCA_rmaps_base_oversubscribe="1")
ENV.pop("DRAPE_DEBUG", None)
BY_ID = {case.id: case for case in CASES}


def mpirun(ranks: int) -> list[str]:
    return ["mpirun", "-n", str(ranks), "--oversubscribe"] if ranks > 1 else []


def run_bundled(root, ranks=1) -> list[dict]:
    """Run every case in one process (per rank); the results of each rank."""
    out = root / "results.json"
    command = mpirun(ranks) + [sys.executable, str(REPO / "tests" / "bad_inputs.py"), str(root),
                               str(out)]
    try:
        done = subprocess.run(command, capture_output=True, text=True, env=ENV, cwd=root,
                              timeout=RUNNER_TIMEOUT)
    except subprocess.TimeoutExpired:
        progress = out.with_suffix(".progress")
        started = progress.read_text().split() if progress.exists() else []
        pytest.fail(f"no answer in {RUNNER_TIMEOUT} s on {ranks} rank(s): a hang in case "
                    f"{started[-1] if started else '(none started)'}")
    assert done.returncode == 0, done.stderr[-3000:]
    return [json.loads((out if r == 0 else out.with_suffix(f".rank{r}.json")).read_text())
            for r in range(ranks)]


def check_message(case, code, stderr):
    """Exit code 2 and one line naming the file, key, value and what was expected."""
    assert code == 2, (case.id, code, stderr)
    assert "Traceback" not in stderr, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith(f"drape {case.args[0]}: error: "), lines[0]
    missing = [f for f in case.fragments() if f not in lines[0]]
    assert not missing, f"{case.id}: {missing} not in the message: {lines[0]}"


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    return run_bundled(tmp_path_factory.mktemp("bad-serial"))[0]


def test_the_cases_are_many_and_named_once():
    ids = [case.id for case in CASES]
    assert len(ids) == len(set(ids)) and len(ids) >= 25
    commands = {case.args[0] for case in CASES}
    assert commands == {"run", "tools", "picture-frame", "calibrate"}


@pytest.mark.parametrize("case", CASES, ids=lambda case: case.id)
def test_bad_input(serial, case):
    result = serial[case.id]
    check_message(case, result["code"], result["stderr"])
    assert result["left"] == [], f"{case.id} left {result['left']} behind"


def test_docs_table_is_what_drape_prints(serial):
    assert DOC.read_text() == table(serial), \
        "docs/bad-inputs.md is out of date: .venv/bin/python tests/bad_inputs.py --write-docs"


def test_bad_inputs_under_mpirun(serial, tmp_path):
    """Every case on 2 ranks: no hang, exit code 2 on both, rank 0 prints the serial message,
    rank 1 nothing."""
    rank0, rank1 = run_bundled(tmp_path, ranks=2)
    for case in CASES:
        for result in (rank0[case.id], rank1[case.id]):
            assert result["code"] == 2, (case.id, result)
            assert "Traceback" not in result["stderr"], (case.id, result["stderr"])
            assert result["left"] == [], (case.id, result["left"])
        assert rank0[case.id]["stderr"] == serial[case.id]["stderr"], case.id
        assert rank1[case.id]["stderr"] == "", (case.id, rank1[case.id]["stderr"])


@pytest.mark.parametrize("case_id", ["run-misspelt-key", "run-mesh-too-coarse",
                                     "run-yarn-angle-not-aligned", "tools-not-nested",
                                     "pf-cycles", "cal-rows"])
@pytest.mark.parametrize("ranks", [1, 2])
def test_one_process_per_case(serial, tmp_path, case_id, ranks):
    """The drape process itself: its exit code (mpirun's under MPI) and its stderr."""
    case = BY_ID[case_id]
    for name, text in case.files.items():
        (tmp_path / name).write_text(text)
    before = sorted(tmp_path.rglob("*"))
    command = mpirun(ranks) + [sys.executable, "-m", "drape.cli", *case.args]
    done = subprocess.run(command, capture_output=True, text=True, env=ENV, cwd=tmp_path,
                          timeout=300)
    # mpirun adds its own notice ("Primary job terminated normally, but 1 process returned a
    # non-zero exit code ..."); drape's lines are those starting "drape "
    ours = "".join(line + "\n" for line in done.stderr.splitlines() if line.startswith("drape "))
    assert "Traceback" not in done.stderr, done.stderr
    check_message(case, done.returncode, ours)
    assert ours == serial[case.id]["stderr"]       # the same line, once
    assert sorted(tmp_path.rglob("*")) == before


@pytest.mark.parametrize("name", ["hemisphere.toml", "double_dome.toml"])
def test_drape_tools_accepts_the_shipped_tool_configs(name):
    done = subprocess.run([sys.executable, "-m", "drape.cli", "tools",
                           str(REPO / "configs" / "tools" / name), "--check"],
                          capture_output=True, text=True, env=ENV, timeout=300)
    assert done.returncode == 0 and done.stderr == "", done.stderr
    assert "tools, valid" in done.stdout
