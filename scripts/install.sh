#!/usr/bin/env bash
# Install drape on Debian bookworm (a machine, a CI runner or the Docker image).
#
#  1. Debian's packages with apt: the FEniCSx stack (python3-dolfinx 0.5.2 and its PETSc,
#     MPI and gmsh) and the Python libraries drape uses. Skipped when all are installed.
#  2. A virtual environment that sees Debian's packages (--system-site-packages; Debian's
#     dolfinx belongs to /usr/bin/python3) holding drape itself, editable, with no download.
#
# Idempotent: a second run checks and returns in about a second.
#  3. The linter of the test command (scripts/run-tests.sh): ruff, pinned, from PyPI into the
#     virtual environment (ruff is not a Debian package in bookworm).
#
# Environment: DRAPE_VENV (default: <repo>/.venv), DRAPE_EDITABLE=0 for a plain install,
# DRAPE_LINT=0 to leave the linter out (an image that only runs jobs),
# DRAPE_APT_ONLY=1 to stop after the Debian packages (the Dockerfile's first, cached layer),
# DRAPE_WARM_UP=0 to leave the numba kernels uncompiled (the Dockerfile compiles them in a later
# layer, where numba's cache stays valid),
# DRAPE_PARAVIEW=1 to add Debian's ParaView 5.11 and Xvfb for `drape view` (138 packages, about 800 MB
# more, so not by default; tests/test_paraview.py installs them itself when missing).
set -euo pipefail

repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
venv=${DRAPE_VENV:-$repo/.venv}

apt_packages=(
  python3-dolfinx python3-petsc4py python3-mpi4py python3-gmsh
  python3-numpy python3-scipy python3-matplotlib python3-h5py
  python3-numba   # the compiled kernels: the law (drape/law/kernel.py), the tools' contact
  python3-pytest python3-pytest-timeout python3-hypothesis
  python3-pytest-xdist   # the serial pass of scripts/run-tests.sh on both cores (-n 2)
  python3-venv python3-pip python3-setuptools python3-wheel
  openmpi-bin
  # an optimised BLAS/LAPACK for MUMPS's dense fronts (Debian's alternatives switch libblas.so.3
  # to it; the reference BLAS made a factorisation 3 times slower, docs/benchmarks.md). The
  # serial build: under mpirun every rank is a process, and BLAS threads would oversubscribe.
  libopenblas0-serial
)
if [ "${DRAPE_PARAVIEW:-0}" = 1 ]; then
  apt_packages+=(paraview python3-paraview xvfb)
fi

missing=()
for pkg in "${apt_packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$pkg")
  fi
done

if ((${#missing[@]})); then
  echo "drape install: installing Debian packages: ${missing[*]}"
  sudo=()
  if [ "$(id -u)" -ne 0 ]; then
    command -v sudo >/dev/null || { echo "drape install: need root or sudo for apt-get" >&2; exit 1; }
    sudo=(sudo)
  fi
  "${sudo[@]}" apt-get update -q
  "${sudo[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends "${missing[@]}"
fi
[ "${DRAPE_APT_ONLY:-0}" = 1 ] && exit 0

if [ ! -x "$venv/bin/python" ]; then
  echo "drape install: creating $venv (sees Debian's packages)"
  /usr/bin/python3 -m venv --system-site-packages "$venv"
fi

# Reinstall drape only when its packaging changed (or it is not importable).
stamp="$venv/.drape-installed"
if [ ! -f "$stamp" ] || [ "$repo/pyproject.toml" -nt "$stamp" ] \
   || ! (cd / && "$venv/bin/python" -c "import drape, drape.geometry" 2>/dev/null); then
  echo "drape install: installing drape into $venv"
  mode=(-e)
  [ "${DRAPE_EDITABLE:-1}" = 0 ] && mode=()
  "$venv/bin/python" -m pip install -q --no-deps --no-build-isolation --no-index "${mode[@]}" "$repo"
  touch "$stamp"
fi

# The linter, pinned: the same rules give the same verdict on every machine.
ruff_version=0.16.9
if [ "${DRAPE_LINT:-1}" = 1 ] \
   && [ "$("$venv/bin/ruff" --version 2>/dev/null)" != "ruff $ruff_version" ]; then
  echo "drape install: installing ruff $ruff_version into $venv"
  "$venv/bin/python" -m pip install -q "ruff==$ruff_version"
fi

# Compile the law's kernel and the tools' contact kernels now (numba caches them beside their
# modules: about 20 s once), so that the first job does not pay for it.
if [ "${DRAPE_WARM_UP:-1}" = 1 ]; then
  (cd / && "$venv/bin/python" -c "import drape.compiled; drape.compiled.warm_up()")
fi
(cd / && "$venv/bin/python" -c "import dolfinx, drape; print('drape install: ok, dolfinx', dolfinx.__version__, 'in', '$venv')")
