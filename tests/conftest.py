"""Shared test setup: MPI awareness, paths and the forming run several files check.

The suite runs twice (scripts/run-tests.sh): serially and under `mpirun -n 2`. Tests marked
``serial`` run only in the serial pass: command-line runs that start their own processes,
comparisons of 1 and 2 ranks, and the in-process forming runs of tens of seconds whose checks
do not depend on the number of ranks (one rank each on the serial pass's two workers costs
about half the processor time of two ranks on a run of a few thousand unknowns). What runs on
2 ranks in the 2-rank pass is drape's parallel code: the unit tests with MPI in them, the
stack's 1-rank-against-2 and resumed-on-other-ranks runs; the shipped jobs on 1 and 2 ranks
are tests/test_fe_cli.py's, stopped and resumed on 2 ranks tests/test_fe_faults.py's.
Tests marked ``full_stroke`` (the shipped double domes pressed to their full 58 mm, minutes
each) are part of the suite: the shipped tools allow no coarser mesh (two elements over the
10 mm fillets: 7.85 mm at most), so they cannot be made cheaper without becoming another job,
and what they check (the full stroke, the inertia's share, the kinematic peak) is not seen 3 mm
down. They are also marked ``serial``: one rank each, since two ranks factor these 6 200
unknowns hardly faster than one and cost more processor time in all (docs/fe-results.md,
"The suite's time"). DRAPE_FULL_STROKE=0 leaves them out, for a quicker loop while working.

The serial pass runs on two pytest-xdist workers (``-n 2 --dist loadgroup``,
scripts/run-tests.sh). A module- or session-scoped fixture is made once per worker that uses it,
so the tests that share one are kept on one worker (an ``xdist_group``); the others are dealt out
one by one. The full strokes come first, so that the two workers start one each at once and the
other tests fill in beside them.
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
    config.addinivalue_line("markers", "full_stroke: a shipped forming job to its full stroke, "
                            "left out when DRAPE_FULL_STROKE=0")


def shared_fixtures(item) -> list[str]:
    """The suite's own module- and session-scoped fixtures that a test uses (directly or through
    other fixtures), as keys: a module fixture by module and name, a session one by name."""
    keys = []
    for name, definitions in item._fixtureinfo.name2fixturedefs.items():
        fixture = definitions[-1]
        module = getattr(fixture.func, "__module__", "")
        if fixture.scope in ("module", "session") and (
                module == "conftest" or module.startswith("test_")):
            keys.append(f"{module}::{name}" if fixture.scope == "module" else name)
    return sorted(keys)


def group_shared_fixtures(items) -> None:
    """One ``xdist_group`` for the tests that share a module or session fixture, directly or
    through a chain of tests each sharing one with the next: each is made once, on one worker."""
    parent = {}

    def root(key):
        while parent.setdefault(key, key) != key:
            key = parent[key]
        return key

    keys = {item: shared_fixtures(item) for item in items}
    for found in keys.values():
        for key in found[1:]:
            parent[root(key)] = root(found[0])
    for item, found in keys.items():
        if found:
            item.add_marker(pytest.mark.xdist_group(root(found[0])))


@pytest.hookimpl(tryfirst=True)   # before pytest-xdist reads the groups
def pytest_collection_modifyitems(config, items):
    # the full strokes first: the serial pass's two workers take one each at once and run
    # them side by side while the other tests fill in around the shorter one
    items.sort(key=lambda item: "full_stroke" not in item.keywords)
    if os.environ.get("DRAPE_FULL_STROKE") == "0":
        skip = pytest.mark.skip(reason="a shipped job to full stroke (minutes), left out by "
                                "DRAPE_FULL_STROKE=0")
        for item in items:
            if "full_stroke" in item.keywords:
                item.add_marker(skip)
    if config.pluginmanager.hasplugin("xdist"):
        group_shared_fixtures(items)
    if comm_size() > 1:
        skip = pytest.mark.skip(reason="serial-only test, skipped under mpirun")
        for item in items:
            if "serial" in item.keywords:
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


#: the hemisphere's tools scaled down (punch R 30 mm, die fillet 8 mm, so 6 mm elements are
#: allowed) for checks that need a forming run but not the shipped 2601-cell mesh: with a
#: 120 mm square blank (SMALL_SQUARE) 400 cells, a seventh of the shipped job's time per step
#: (tests/test_blanks.py, the resumed forming runs of tests/test_forming.py)
SMALL_HEMISPHERE = ["tools.hemisphere.punch_radius=30", "tools.hemisphere.die_opening_radius=35",
                    "tools.hemisphere.die_fillet_radius=8",
                    "tools.hemisphere.holder_inner_radius=45",
                    "tools.hemisphere.holder_outer_radius=100", "process.holder_force=100",
                    "mesh.size=6"]
SMALL_SQUARE = ["blank.length=120", "blank.width=120"]


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


#: the shipped double-dome jobs made short: the punch 3 mm down in 0.3-0.6 mm steps (a first
#: step lifting the blank off the die, then the blank's inertia from rest), no fields written
DOUBLE_DOME_SHORT = ["process.stroke=3", "steps.initial=0.1", "steps.maximum=0.2",
                     "output.xdmf=false"]


@pytest.fixture(scope="session")
def double_dome_short(tmp_path_factory):
    """Runs of configs/double_dome.toml and double_dome_45.toml with DOUBLE_DOME_SHORT, each made
    once for the session: the 0/90 one is both the built-in tools' side of the STEP tools'
    comparison (tests/test_step_tools.py) and, with the +-45 one, the run whose symmetries and
    contact tests/test_forming.py checks. get(config) -> (job, RunSummary, folder); every rank
    sees rank 0's folder."""
    from mpi4py import MPI

    from drape.job import load_job
    from drape.run import run_job
    comm = MPI.COMM_WORLD
    made = {}

    def get(config):
        if config not in made:
            folder = tmp_path_factory.mktemp(config.split(".")[0]) if comm.rank == 0 else None
            folder = comm.bcast(folder, root=0)
            job = load_job(CONFIGS / config, overrides=list(DOUBLE_DOME_SHORT))
            summary = run_job(job, comm, output=str(folder))
            comm.barrier()
            made[config] = job, summary, folder
        return made[config]
    return get
