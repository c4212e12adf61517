"""Shared test setup: MPI awareness and paths.

The suite runs twice (scripts/run-tests.sh): serially and under `mpirun -n 2`. Tests marked
``serial`` (command-line runs that start their own processes, comparisons of 1 and 2 ranks)
run only in the serial pass.
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


def pytest_collection_modifyitems(config, items):
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
