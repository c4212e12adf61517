#!/usr/bin/env bash
# Install what is needed (idempotent), lint (ruff, config in pyproject.toml; a finding fails
# the command) and run the whole test suite: serially, then under `mpirun -n 2` (tests marked
# `serial`, among them the in-process forming runs whose checks do not depend on the number of
# ranks, are skipped there: tests/conftest.py). The serial pass runs its tests on two
# pytest-xdist workers, one per core (tests sharing a module or session fixture on the same
# one: tests/conftest.py). Extra arguments go to pytest (both passes).
# DRAPE_FULL_STROKE=0 leaves out the shipped double domes pressed to their full 58 mm (minutes
# each, on one rank each, first in the serial pass; the shipped tools allow no coarser mesh),
# for a quicker loop while working; CI and the README's command run them.
set -euo pipefail
repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
"$repo/scripts/install.sh"
cd "$repo"
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
export OMPI_MCA_rmaps_base_oversubscribe=1
# a rank waiting for the other gives its core up instead of spinning: on the shared 2-core
# machine a spinning rank took the core the other rank needed (a 2-rank test, load 5: 48-53 s
# spinning, 30 s yielding)
export OMPI_MCA_mpi_yield_when_idle=1
python=.venv/bin/python

echo "== lint (ruff check)"
.venv/bin/ruff check --no-cache .

echo "== tests, serial, on 2 workers"
"$python" -m pytest -q -n 2 --dist loadgroup "$@"

echo "== tests, mpirun -n 2 (rank 0 shown; rank 1 shown if it fails)"
log=$(mktemp)
trap 'rm -f "$log"' EXIT
if ! mpirun -n 2 bash -c '
    if [ "${OMPI_COMM_WORLD_RANK:-0}" = 0 ]; then
      exec "$0" -m pytest -q -p no:cacheprovider "${@:2}"
    else
      exec "$0" -m pytest -q -p no:cacheprovider "${@:2}" >"$1" 2>&1
    fi' "$python" "$log" "$@"; then
  echo "== rank 1 output:"
  cat "$log"
  exit 1
fi
