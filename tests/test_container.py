"""The Dockerfile, proven without a Docker engine.

No Docker engine runs on the project's machines. This test builds what `docker build` would from
the same recipe: a minimal Debian bookworm root made by Debian's debootstrap (--variant=minbase,
as Docker's official debian images are), into which it executes the Dockerfile's own
instructions (parsed here: ENV, COPY with .dockerignore, RUN, WORKDIR, VOLUME, ENTRYPOINT) with
chroot. Then it runs what `docker run` would:

* ``drape picture-frame --cycles 10,-10 --increment 1 --output /results/pf`` through the image's
  entry point, with a host folder mounted at the /results volume, and compares the CSV with the
  same job run on the host;
* ``mpirun -n 2`` of a small dolfinx/mpi4py program (a mesh distributed over 2 ranks).

Each command runs in its own mount and PID namespace (unshare), where /proc, /dev, /sys and the
volume are mounted; the mounts vanish with the namespace, so nothing stays mounted on the host
even if the test is killed. The root is deleted afterwards (DRAPE_KEEP_CHROOT=1 keeps it).

Cached between runs under build/container/ (git-ignored): the debootstrap'ed base as a tarball
and apt's downloaded packages. Neither changes what is installed: a fresh machine (CI) builds
both from nothing. Needs root, debootstrap (installed with apt if missing) and the Debian mirror.
DRAPE_DEBIAN_MIRROR overrides http://deb.debian.org/debian. Takes minutes: marked slow and serial.
"""

from __future__ import annotations

import csv
import json
import os
import re
import shlex
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO

pytestmark = [pytest.mark.serial, pytest.mark.slow, pytest.mark.timeout(3600)]

CACHE = REPO / "build" / "container"
MIRROR = os.environ.get("DRAPE_DEBIAN_MIRROR", "http://deb.debian.org/debian")
SECURITY_MIRROR = os.environ.get("DRAPE_DEBIAN_SECURITY_MIRROR",
                                 "http://deb.debian.org/debian-security")
#: the environment `docker run` and `docker build` start from (before the Dockerfile's ENV)
DOCKER_BASE_ENV = {"PATH": "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin",
                   "HOME": "/root", "HOSTNAME": "drape-chroot"}

# TODO(lead): when `drape run` lands, set this to the small FE job, e.g.
# FE_JOB = ["run", "/opt/drape/src/configs/<small>.toml", "--output", "/results/run"]
# and the test runs it with `mpirun -n 2` inside the image and checks that it exits 0 and writes
# into /results/run (see test below, "FE job").
FE_JOB: list[str] | None = None

MPI_PROGRAM = """
from mpi4py import MPI
import dolfinx.mesh
comm = MPI.COMM_WORLD
mesh = dolfinx.mesh.create_unit_square(comm, 8, 8)
local = mesh.topology.index_map(2).size_local
total = comm.allreduce(local)
print(f"rank {comm.rank} of {comm.size}: {local} of {total} cells", flush=True)
"""


# --- the Dockerfile ----------------------------------------------------------------------------

def parse_dockerfile(path: Path) -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) in order; comments dropped, continuation lines joined."""
    instructions, pending = [], ""
    for raw in path.read_text().splitlines():
        stripped = raw.strip()
        if not pending and (not stripped or stripped.startswith("#")):
            continue
        if pending and stripped.startswith("#"):
            continue            # a comment inside a continued instruction is dropped by docker
        if stripped.endswith("\\"):
            pending += stripped[:-1] + " "
            continue
        line = pending + stripped
        pending = ""
        keyword, _, rest = line.partition(" ")
        instructions.append((keyword.upper(), rest.strip()))
    assert not pending, "Dockerfile ends inside a continued line"
    return instructions


def expand(text: str, env: dict[str, str]) -> str:
    """Docker's $VAR / ${VAR} substitution in ENV, WORKDIR, COPY, VOLUME."""
    return re.sub(r"\$(?:\{(\w+)\}|(\w+))", lambda m: env.get(m.group(1) or m.group(2), ""), text)


def parse_env(arguments: str, env: dict[str, str]) -> dict[str, str]:
    words = shlex.split(arguments)
    if words and "=" not in words[0]:          # legacy form: ENV KEY value with spaces
        return {words[0]: expand(" ".join(words[1:]), env)}
    out = {}
    for word in words:
        key, sep, value = word.partition("=")
        assert sep, f"ENV {arguments!r}: expected KEY=value pairs"
        out[key] = expand(value, {**env, **out})
    return out


def dockerignore_patterns(context: Path) -> list[tuple[bool, re.Pattern]]:
    """(is_exception, regex) per .dockerignore line, in order (the last match decides)."""
    patterns = []
    path = context / ".dockerignore"
    for line in path.read_text().splitlines() if path.exists() else []:
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        exception = line.startswith("!")
        pattern = os.path.normpath(line.lstrip("!").strip()).lstrip("/")
        regex = ""
        i = 0
        while i < len(pattern):
            if pattern.startswith("**/", i):
                regex, i = regex + "(?:.*/)?", i + 3
            elif pattern.startswith("**", i):
                regex, i = regex + ".*", i + 2
            elif pattern[i] == "*":
                regex, i = regex + "[^/]*", i + 1
            elif pattern[i] == "?":
                regex, i = regex + "[^/]", i + 1
            else:
                regex, i = regex + re.escape(pattern[i]), i + 1
        patterns.append((exception, re.compile(regex + r"\Z")))
    return patterns


def ignored(relative: str, patterns) -> bool:
    """Docker excludes a path if it or one of its parent folders matches."""
    parts = relative.split("/")
    prefixes = ["/".join(parts[: i + 1]) for i in range(len(parts))]
    result = False
    for exception, regex in patterns:
        if any(regex.match(p) for p in prefixes):
            result = not exception
    return result


def copy_context(context: Path, source: str, destination: Path) -> int:
    """COPY source destination: a file, or a folder's contents, filtered by .dockerignore."""
    patterns = dockerignore_patterns(context)
    source_path = (context / source).resolve()
    assert source_path == context or context in source_path.parents, \
        f"COPY {source}: outside the context"
    copied = 0
    if source_path.is_file():
        destination.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(source_path, destination)
        return 1
    for folder, dirs, files in os.walk(source_path):
        folder = Path(folder)
        rel_folder = folder.relative_to(context).as_posix()
        dirs[:] = [d for d in dirs
                   if not ignored(f"{rel_folder}/{d}".lstrip("./"), patterns)]
        target_folder = destination / folder.relative_to(source_path)
        target_folder.mkdir(parents=True, exist_ok=True)
        for name in files:
            relative = (folder / name).relative_to(context).as_posix()
            if ignored(relative, patterns):
                continue
            target = target_folder / name
            if (folder / name).is_symlink():
                target.symlink_to(os.readlink(folder / name))
            else:
                shutil.copy2(folder / name, target)
            copied += 1
    return copied


# --- the root ----------------------------------------------------------------------------------

def run_host(command, **kwargs):
    return subprocess.run(command, check=True, text=True, **kwargs)


def ensure_debootstrap():
    if shutil.which("debootstrap"):
        return
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    run_host(["apt-get", "update", "-q"], env=env, stdout=subprocess.DEVNULL)
    run_host(["apt-get", "install", "-y", "-q", "--no-install-recommends", "debootstrap"], env=env,
             stdout=subprocess.DEVNULL)


def base_tarball() -> Path:
    """A minbase bookworm root as a tarball, made once and kept under build/container/."""
    tarball = CACHE / "bookworm-minbase.tar"
    stamp = CACHE / "bookworm-minbase.json"
    wanted = {"suite": "bookworm", "variant": "minbase", "mirror": MIRROR}
    if tarball.is_file() and stamp.is_file() and json.loads(stamp.read_text()) == wanted:
        return tarball
    ensure_debootstrap()
    CACHE.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix="debootstrap-", dir=CACHE))
    try:
        run_host(["debootstrap", "--variant=minbase", "bookworm", str(work / "root"), MIRROR],
                 stdout=subprocess.DEVNULL)
        run_host(["tar", "-C", str(work / "root"), "--numeric-owner", "-cf", str(work / "base.tar"),
                  "."])
        os.replace(work / "base.tar", tarball)
        stamp.write_text(json.dumps(wanted))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return tarball


def prepare_root(root: Path) -> None:
    """Unpack the base and make it look like the debian:bookworm image where it matters."""
    run_host(["tar", "-C", str(root), "--numeric-owner", "-xpf", str(base_tarball())])
    sources = root / "etc/apt/sources.list"
    sources.unlink(missing_ok=True)
    (root / "etc/apt/sources.list.d/debian.sources").write_text(
        f"Types: deb\nURIs: {MIRROR}\nSuites: bookworm bookworm-updates\nComponents: main\n"
        "Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg\n\n"
        f"Types: deb\nURIs: {SECURITY_MIRROR}\nSuites: bookworm-security\nComponents: main\n"
        "Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg\n")
    # what docker provides at run time
    shutil.copy2("/etc/resolv.conf", root / "etc/resolv.conf")
    (root / "etc/hostname").write_text("drape-chroot\n")
    # a chroot shares the host's network and IPC: no package may start a daemon here
    policy = root / "usr/sbin/policy-rc.d"
    policy.write_text("#!/bin/sh\nexit 101\n")
    policy.chmod(0o755)


def mounts_under(root: Path) -> list[str]:
    prefix = str(root.resolve())
    with open("/proc/self/mountinfo") as stream:
        points = [line.split()[4] for line in stream]
    return [p for p in points if p == prefix or p.startswith(prefix + "/")]


def in_root(root: Path, argv: list[str], env: dict[str, str], workdir: str, *,
            binds: dict[str, Path] | None = None, log: Path, check=True):
    """Run argv inside root (chroot) in fresh mount and PID namespaces; binds: {path in root:
    host folder}. Output goes to log (appended); returns the CompletedProcess."""
    binds = binds or {}
    script = ['set -e', 'root="$1"; shift',
              'mount -t proc proc "$root/proc"',
              'mount --rbind /dev "$root/dev"',
              'mount --rbind /sys "$root/sys"']
    for inside, host in binds.items():
        (root / inside.lstrip("/")).mkdir(parents=True, exist_ok=True)
        script.append(f'mount --bind {shlex.quote(str(host))} "$root"{shlex.quote(inside)}')
    script.append('exec chroot "$root" /usr/bin/env -i "$@"')
    command = (["unshare", "--mount", "--propagation", "private", "--pid", "--fork", "--",
                "/bin/sh", "-c", "\n".join(script), "in-root", str(root)]
               + [f"{k}={v}" for k, v in env.items()]
               + ["/bin/sh", "-c", 'cd "$0" && exec "$@"', workdir] + argv)
    with log.open("a") as stream:
        stream.write(f"\n$ {shlex.join(argv)}   (in {workdir})\n")
        stream.flush()
        result = subprocess.run(command, stdout=stream, stderr=subprocess.STDOUT, text=True,
                                stdin=subprocess.DEVNULL)
    assert not mounts_under(root), "a mount escaped the namespace"
    if check and result.returncode != 0:
        tail = "".join(log.read_text().splitlines(keepends=True)[-40:])
        pytest.fail(f"{shlex.join(argv)} exited {result.returncode} in the chroot; log "
                    f"{log}:\n{tail}")
    return result


class Image:
    """The state `docker build` accumulates: env, workdir, volumes, entrypoint, cmd."""

    def __init__(self, root: Path):
        self.root = root
        self.env = dict(DOCKER_BASE_ENV)
        self.workdir = "/"
        self.volumes: list[str] = []
        self.entrypoint: list[str] = []
        self.cmd: list[str] = []

    def build(self, dockerfile: Path, context: Path, log: Path,
              apt_cache: Path) -> dict[str, float]:
        seconds = {}
        instructions = parse_dockerfile(dockerfile)
        assert instructions[0] == ("FROM", "debian:bookworm"), instructions[0]
        for keyword, arguments in instructions[1:]:
            started = time.perf_counter()
            if keyword == "ENV":
                self.env.update(parse_env(arguments, self.env))
            elif keyword == "WORKDIR":
                path = expand(arguments, self.env)
                self.workdir = (path if path.startswith("/")
                                else f"{self.workdir.rstrip('/')}/{path}")
                (self.root / self.workdir.lstrip("/")).mkdir(parents=True, exist_ok=True)
            elif keyword == "COPY":
                words = shlex.split(expand(arguments, self.env))
                assert len(words) == 2 and not words[0].startswith("--"), \
                    f"COPY {arguments}: only 'COPY <source> <destination>' is understood here"
                count = copy_context(context, words[0], self.root / words[1].lstrip("/"))
                with log.open("a") as stream:
                    stream.write(f"\nCOPY {arguments}: {count} files\n")
            elif keyword == "RUN":
                assert not arguments.startswith("["), "RUN: only the shell form is understood here"
                in_root(self.root, ["/bin/sh", "-c", arguments], self.env, self.workdir,
                        binds={"/var/cache/apt/archives": apt_cache}, log=log)
            elif keyword == "VOLUME":
                words = json.loads(arguments) if arguments.startswith("[") else arguments.split()
                self.volumes += [expand(w, self.env) for w in words]
                for volume in self.volumes:
                    (self.root / volume.lstrip("/")).mkdir(parents=True, exist_ok=True)
            elif keyword in ("ENTRYPOINT", "CMD"):
                assert arguments.startswith("["), \
                    f"{keyword}: only the exec (JSON) form is understood"
                setattr(self, keyword.lower(), json.loads(arguments))
            elif keyword == "LABEL":
                pass
            else:
                pytest.fail(f"Dockerfile instruction {keyword} is not understood by this test: "
                            "teach tests/test_container.py what docker does with it")
            seconds[f"{keyword} {arguments[:40]}"] = time.perf_counter() - started
        return seconds

    def run(self, args: list[str], log: Path, volumes: dict[str, Path], entrypoint=None,
            check=True):
        """`docker run [--entrypoint E] -v host:volume image args`."""
        argv = (self.entrypoint if entrypoint is None else [entrypoint]) + (args or self.cmd)
        return in_root(self.root, argv, self.env, self.workdir, binds=volumes, log=log, check=check)


# --- the test ----------------------------------------------------------------------------------

def read_columns(path: Path) -> dict[str, np.ndarray]:
    with path.open() as stream:
        rows = list(csv.DictReader(stream))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


def test_dockerfile_builds_and_runs_drape_in_a_bookworm_chroot(tmp_path):
    if os.geteuid() != 0:
        pytest.skip("needs root (debootstrap, chroot, mount namespaces); CI runs as root")
    timings = {}
    started = time.perf_counter()
    base_tarball()
    timings["base root (debootstrap, or the cached tarball)"] = time.perf_counter() - started

    CACHE.mkdir(parents=True, exist_ok=True)
    apt_cache = CACHE / "apt-archives"
    (apt_cache / "partial").mkdir(parents=True, exist_ok=True)
    root = Path(tempfile.mkdtemp(prefix="root-", dir=CACHE))
    log = tmp_path / "chroot.log"
    results = tmp_path / "results"
    results.mkdir()
    try:
        t = time.perf_counter()
        prepare_root(root)
        timings["unpack the base"] = time.perf_counter() - t

        image = Image(root)
        t = time.perf_counter()
        steps = image.build(REPO / "Dockerfile", REPO, log, apt_cache)
        timings["docker build steps"] = time.perf_counter() - t
        timings.update({f"  {k}": v for k, v in steps.items()})
        assert image.entrypoint and image.entrypoint[0].startswith("/"), image.entrypoint
        assert "/results" in image.volumes and image.workdir == "/results"
        # the image's installation is a plain (not editable) one, in its own venv
        venv_python = root / "opt/drape/venv/bin/python"
        assert venv_python.exists()
        site_packages = root / "opt/drape/venv/lib/python3.11/site-packages"
        assert not (site_packages / "__editable__.drape-0.1.0.pth").exists()
        assert list((site_packages / "drape").glob("calibrate.py"))

        # `docker run --rm -v results:/results drape picture-frame ...`
        t = time.perf_counter()
        job = ["picture-frame", "--cycles", "10,-10", "--increment", "1", "--output", "/results/pf"]
        image.run(job, log, {"/results": results})
        timings["drape picture-frame in the image"] = time.perf_counter() - t
        produced = results / "pf" / "picture_frame.csv"
        assert produced.is_file(), log.read_text()[-3000:]
        assert (results / "pf" / "picture_frame.png").stat().st_size > 10_000

        from drape.cli import main
        host_output = tmp_path / "host-pf"
        assert main(job[:-1] + [str(host_output)]) == 0
        inside, host = read_columns(produced), read_columns(host_output / "picture_frame.csv")
        assert inside.keys() == host.keys() and inside["tau"].size == 40
        for name in host:
            np.testing.assert_allclose(inside[name], host[name], rtol=1e-12, atol=1e-15,
                                       err_msg=name)
        assert np.ptp(inside["tau"]) > 0.01

        # `docker run --rm drape --help` (the default CMD) works through the entry point
        result = image.run([], log, {"/results": results})
        assert result.returncode == 0 and "picture-frame" in log.read_text().split("$ ")[-1]

        # `docker run --rm --entrypoint mpirun drape -n 2 python -c ...`
        t = time.perf_counter()
        (results / "mpi_check.py").write_text(MPI_PROGRAM)
        image.run(["-n", "2", "/opt/drape/venv/bin/python", "/results/mpi_check.py"], log,
                  {"/results": results}, entrypoint="mpirun")
        timings["mpirun -n 2 dolfinx in the image"] = time.perf_counter() - t
        out = log.read_text().split("$ mpirun")[-1]
        ranks = re.findall(r"rank (\d) of 2: (\d+) of (\d+) cells", out)
        assert sorted(r[0] for r in ranks) == ["0", "1"], out[-3000:]
        assert all(int(total) == 128 for _, _, total in ranks)
        assert (sum(int(local) for _, local, _ in ranks) == 128
                and all(int(l) > 0 for _, l, _ in ranks))

        # FE job: `docker run --rm -v results:/results --entrypoint mpirun drape -n 2 drape run ...`
        if FE_JOB is not None:
            t = time.perf_counter()
            image.run(["-n", "2", image.entrypoint[0]] + FE_JOB, log, {"/results": results},
                      entrypoint="mpirun")
            timings["mpirun -n 2 drape run in the image"] = time.perf_counter() - t
            output = FE_JOB[FE_JOB.index("--output") + 1] if "--output" in FE_JOB else None
            if output:
                assert any((results / Path(output).relative_to("/results")).iterdir())
    finally:
        timings["total"] = time.perf_counter() - started
        report = "\n".join(f"{v:8.1f} s  {k}" for k, v in timings.items())
        print("\nchroot proof of the Dockerfile:\n" + report)
        (CACHE / "last-proof-timings.txt").write_text(report + "\n")
        if mounts_under(root):
            pytest.fail(f"mounts left under {root}; not deleting it: {mounts_under(root)}")
        if os.environ.get("DRAPE_KEEP_CHROOT") == "1":
            print(f"kept {root}")
        else:
            shutil.rmtree(root, ignore_errors=True)


# --- fast checks of the parser ---------------------------------------------------------------
# (not slow, but serial with the rest of this module: they need no root)

def test_dockerignore_matches_like_docker():
    patterns = dockerignore_patterns(REPO)
    assert ignored(".git", patterns) and ignored(".venv/bin/python", patterns)
    assert ignored("drape/__pycache__/cli.cpython-311.pyc", patterns)
    assert ignored("drape.egg-info/PKG-INFO", patterns) and ignored("build/container/x", patterns)
    assert not ignored("drape/cli.py", patterns) and not ignored("scripts/install.sh", patterns)
    assert not ignored("tests/results_helpers.py", patterns)   # 'results' only at the top
    assert not ignored("configs/materials/paper_one_surface.toml", patterns)


def test_dockerfile_is_understood():
    instructions = parse_dockerfile(REPO / "Dockerfile")
    keywords = [k for k, _ in instructions]
    assert keywords[0] == "FROM" and "RUN" in keywords and "ENTRYPOINT" in keywords
    env = dict(DOCKER_BASE_ENV)
    for keyword, arguments in instructions:
        if keyword == "ENV":
            env.update(parse_env(arguments, env))
    assert env["OMPI_ALLOW_RUN_AS_ROOT"] == "1" and env["PATH"].startswith("/opt/drape/venv/bin:")
    run = [a for k, a in instructions if k == "RUN"]
    assert any("scripts/install.sh" in a for a in run)
