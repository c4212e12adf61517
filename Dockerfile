# drape on Debian bookworm: Debian's FEniCSx stack (python3-dolfinx 0.5.2, PETSc, Open MPI, gmsh)
# and drape, installed by the same scripts/install.sh as on a machine (README, "Docker").
#
#   docker build -t drape .
#   docker run --rm -v "$PWD/results:/results" drape picture-frame --output /results/pf
#
# No Docker engine runs on the project's machines: tests/test_container.py builds this file with
# Debian's buildah (`buildah bud --isolation chroot`) on a debootstrap'ed bookworm imported as
# debian:bookworm, runs a drape job and an mpirun job in the image and exports it as a
# docker-archive (docs/container.md). Keep to plain Dockerfile syntax that docker builds too.
FROM debian:bookworm

# Open MPI refuses to run as root unless told; containers are small, so allow more ranks than
# cores; Docker's default seccomp/ptrace rules break Open MPI's shared-memory single copy.
ENV LANG=C.UTF-8 \
    OMPI_ALLOW_RUN_AS_ROOT=1 \
    OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 \
    OMPI_MCA_rmaps_base_oversubscribe=1 \
    OMPI_MCA_btl_vader_single_copy_mechanism=none \
    PATH=/opt/drape/venv/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin

# Debian's packages first, from install.sh alone: this layer is rebuilt only when install.sh
# changes, not at every change of the source (the packages are most of the build's time).
COPY scripts/install.sh /opt/drape/src/scripts/install.sh
RUN DRAPE_APT_ONLY=1 /opt/drape/src/scripts/install.sh && rm -rf /var/lib/apt/lists/*

# drape is installed into its own venv, not editable, so that the image does not depend on the
# source tree's state; install.sh finds the packages installed and goes on to the venv. Only what
# the install reads is copied for it (the package's sources, pyproject.toml and the README it
# names, scripts/): a change of tests/, docs/ or configs/ rebuilds only the last COPY's layer.
COPY pyproject.toml README.md /opt/drape/src/
COPY scripts /opt/drape/src/scripts
COPY geometry /opt/drape/src/geometry
COPY drape /opt/drape/src/drape
RUN DRAPE_VENV=/opt/drape/venv DRAPE_EDITABLE=0 DRAPE_LINT=0 DRAPE_WARM_UP=0 \
    /opt/drape/src/scripts/install.sh && rm -rf /var/lib/apt/lists/* /root/.cache/pip

# numba's cache of the compiled kernels (the law's, the contact's) is keyed by their source
# files' mtimes, which an image layer rounds to the second: a cache written in the install layer
# would be stale in the image (every container would compile the kernels at its first job, about
# 25 s), so they are compiled here, on top of the installed layer, and only here.
RUN cd / && python -c "import drape.compiled; drape.compiled.warm_up()"

# The whole source stays in the image (configs/, docs/, tests/).
COPY . /opt/drape/src

VOLUME /results
WORKDIR /results
ENTRYPOINT ["/opt/drape/venv/bin/drape"]
CMD ["--help"]
