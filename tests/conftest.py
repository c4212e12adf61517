"""Shared test setup: MPI awareness, paths and the forming run several files check.

The suite runs twice (scripts/run-tests.sh): serially and under `mpirun -n 2`. Tests marked
``serial`` (command-line runs that start their own processes, comparisons of 1 and 2 ranks)
run only in the serial pass. Tests marked ``two_ranks`` (in-process forming runs of tens of
seconds or minutes whose checks do not depend on the number of ranks; that 1 rank gives what
2 give is tests/test_fe_cli.py's) run in the 2-rank pass, where they use both cores, and are
skipped in the serial pass when DRAPE_TWO_RANK_PASS=1 says that a 2-rank pass follows (as
scripts/run-tests.sh does); run alone, e.g. `pytest tests/test_forming.py`, they run serially.
"""

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
CONFIGS = REPO / "configs"


def comm_size() -> int:
    if "OMPI_COMM_WORLD_SIZE" in os.environ or "PMI_SIZE" in os.environ:
        from mpi4py import MPI
        return MPI.COMM_WORLD.size
    return 1


def pytest_configure(config):
    config.addinivalue_line("markers", "serial: run only in the serial pass (not under mpirun)")
    config.addinivalue_line("markers", "two_ranks: run in the 2-rank pass only, when the suite "
                            "has one (DRAPE_TWO_RANK_PASS=1 in the serial pass)")


def pytest_collection_modifyitems(config, items):
    if comm_size() > 1:
        skip = pytest.mark.skip(reason="serial-only test, skipped under mpirun")
        for item in items:
            if "serial" in item.keywords:
                item.add_marker(skip)
    elif os.environ.get("DRAPE_TWO_RANK_PASS") == "1":
        skip = pytest.mark.skip(reason="run in the 2-rank pass (DRAPE_TWO_RANK_PASS=1)")
        for item in items:
            if "two_ranks" in item.keywords:
                item.add_marker(skip)


@pytest.fixture
def comm():
    from mpi4py import MPI
    return MPI.COMM_WORLD


@pytest.fixture
def shared_tmp(tmp_path, comm):
    """A temporary folder that every rank sees (rank 0's tmp_path)."""
    return Path(comm.bcast(str(tmp_path), root=0))


#: the bias-extension job made short (12.5 mm mesh, the clamp pulled 10 mm in 5-10 steps)
BIAS_EXTENSION_SHORT = ["--set", "mesh.size=12.5", "--set", "history.d.values=[0, 10]",
                        "--set", "steps.initial=0.1", "--set", "steps.maximum=0.2"]


@pytest.fixture(scope="session")
def bias_extension_short(tmp_path_factory):
    """`drape run configs/bias_extension.toml` with BIAS_EXTENSION_SHORT (progress on, fields
    written) on 1 or 2 ranks, each run once for the session and shared by the tests of its
    progress lines (tests/test_cli_help.py) and of its XDMF in ParaView (tests/test_paraview.py):
    get(ranks) -> (subprocess.CompletedProcess, folder)."""
    import subprocess
    import sys
    made = {}
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1")

    def get(ranks):
        if ranks not in made:
            folder = tmp_path_factory.mktemp(f"bias_extension_short_{ranks}") / "run"
            command = [sys.executable, "-m", "drape.cli", "run",
                       str(CONFIGS / "bias_extension.toml"), "--output", str(folder),
                       *BIAS_EXTENSION_SHORT]
            if ranks > 1:
                command = ["mpirun", "-n", str(ranks), *command]
            made[ranks] = subprocess.run(command, capture_output=True, text=True, cwd=REPO,
                                         env=env, timeout=900, stdin=subprocess.DEVNULL), folder
        return made[ranks]
    return get


#: the default hemisphere job made short: the punch 5 mm down on the coarsest mesh its tools
#: allow (tests/test_forming.py, tests/test_step_tools.py)
HEMISPHERE_SHORT = ["process.stroke=5", "steps.initial=0.05", "steps.maximum=0.2"]


@pytest.fixture(scope="session")
def hemisphere_5mm(tmp_path_factory):
    """One run of configs/hemisphere.toml with HEMISPHERE_SHORT, shared by the tests that check
    its outputs, forces, penetration and symmetry (tests/test_forming.py) and compare it with
    the same tools from STEP files (tests/test_step_tools.py): (job, RunSummary, folder, the
    lines it logged); every rank sees rank 0's folder."""
    from mpi4py import MPI

    from drape.job import load_job
    from drape.run import run_job
    comm = MPI.COMM_WORLD
    folder = tmp_path_factory.mktemp("hemisphere_5mm") if comm.rank == 0 else None
    folder = comm.bcast(folder, root=0)
    job = load_job(CONFIGS / "hemisphere.toml", overrides=list(HEMISPHERE_SHORT))
    said = []
    summary = run_job(job, comm, output=str(folder), log=said.append)
    comm.barrier()
    return job, summary, folder, said
