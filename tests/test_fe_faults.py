"""Faults in batch runs of the forming jobs (issue 30; docs/faults.md): on 2 ranks, a run
stopped by SIGTERM, or by SIGKILL of one rank, and resumed on 2 ranks gives the uninterrupted
run's steps, forces and shear (to 1e-10); a run that fills its disk stops with one line (exit
1, no traceback, no HDF5 diagnostics), keeps a readable checkpoint and files that end with its
last complete step, and resumes, once there is space, to the uninterrupted run's numbers.

The jobs are short and coarse: the hemisphere with a 3 mm stroke in 5 steps on 676 cells (the
die fillet enlarged to 10 mm, which allows 7.8 mm elements), the double dome (with inertia) with
a 2 mm stroke in 4 steps on 1479 cells."""

import csv
import json
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import CONFIGS, REPO
from test_fe_checkpoint import (ENV, check_datasets_exist, children, command, drape, read_steps,
                                xdmf_times_and_datasets)

HEMISPHERE = [CONFIGS / "hemisphere.toml", "--set", "process.stroke=3",
              "--set", "tools.hemisphere.die_fillet_radius=10", "--set", "mesh.size=7.8",
              "--set", "steps.initial=0.2", "--set", "steps.maximum=0.2", "--quiet"]
DOUBLE_DOME = [CONFIGS / "double_dome.toml", "--set", "process.stroke=2",
               "--set", "tools.double_dome.die_entry_radius=11.9",
               "--set", "tools.double_dome.punch_edge_radius=11.9", "--set", "mesh.size=9.3",
               "--set", "steps.initial=0.25", "--set", "steps.maximum=0.25", "--quiet"]
#: steps.csv columns that are not numbers of the run (wall time)
TIMES = {"seconds"}


def every(n):
    return ["--set", f"output.checkpoint_every={n}"]


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    """The uninterrupted 2-rank runs, one per job, made when first asked for."""
    made = {}

    def get(name, job):
        if name not in made:
            folder = tmp_path_factory.mktemp("uninterrupted") / name
            done = drape("run", *job, "--output", folder, ranks=2)
            assert done.returncode == 0, done.stderr
            made[name] = folder
        return made[name]
    return get


def numbers(path):
    with open(path) as stream:
        return list(csv.DictReader(stream))


def check_same_run(resumed: Path, reference: Path):
    """steps.csv and force_stroke.csv (every column but the wall time: steps, Newton
    iterations, forces, work, shear) and result.npz equal to 1e-10; every step's fields once."""
    for name in ("steps.csv", "force_stroke.csv"):
        a, b = numbers(resumed / name), numbers(reference / name)
        assert len(a) == len(b) >= 5, name
        assert list(a[0]) == list(b[0])
        for ra, rb in zip(a, b):
            for key in rb:
                if key in TIMES:
                    continue
                x, y = float(ra[key]), float(rb[key])
                assert abs(x - y) <= 1e-10 * max(1.0, abs(y)), (name, key, x, y)
    rows = read_steps(reference)
    assert float(rows[-1]["punch_force"]) > 1.0      # the punch pushed: a real comparison
    assert float(rows[-1]["max_shear_angle_deg"]) > 0.05
    ra, rb = np.load(resumed / "result.npz"), np.load(reference / "result.npz")
    for key in ("u", "tau", "gamma_t_deg"):
        assert np.abs(ra[key] - rb[key]).max() <= 1e-10 * max(1.0, np.abs(rb[key]).max()), key
    sa = json.loads((resumed / "summary.json").read_text())
    sb = json.loads((reference / "summary.json").read_text())
    for key in ("max_punch_force_N", "max_shear_angle_deg", "steps", "newton_iterations"):
        if key in sb:
            assert abs(sa[key] - sb[key]) <= 1e-10 * max(1.0, abs(sb[key])), key
    times, items = xdmf_times_and_datasets(resumed)
    assert times["displacement"] == [float(r["t"]) for r in rows]
    assert all(series == times["displacement"] for series in times.values())
    check_datasets_exist(resumed, items)


def start(job, folder, *extra, env=None):
    return subprocess.Popen(command("run", *job, "--output", folder, *extra, ranks=2),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO,
                            env={**ENV, **(env or {})})


def wait_for_rows(process, folder, n):
    """Until steps.csv has n rows (steps 0..n-1) or the run ended."""
    while process.poll() is None:
        if (folder / "steps.csv").is_file() and len(read_steps(folder)) >= n:
            return
        time.sleep(0.05)


def one_line(stderr):
    lines = [line for line in stderr.splitlines() if line.startswith("drape run")]
    assert len(lines) == 1, stderr
    assert "Traceback" not in stderr and "HDF5-DIAG" not in stderr, stderr
    return lines[0]


@pytest.mark.serial
@pytest.mark.parametrize("name", ["hemisphere", "double_dome"])
def test_sigterm_then_resume_on_two_ranks(tmp_path, uninterrupted, name):
    """SIGTERM to the ranks (hemisphere), or to mpirun and the ranks at once as `pkill -f` and
    some batch systems send it (double dome: mpirun may be gone before the ranks' last line
    reaches it; it kills the ranks odls_base_sigkill_timeout after its SIGTERM, set to 10 s as
    docs/fe-results.md advises on a loaded machine, where 1 s was too short here with two busy
    loops beside the run): the run stops after its checkpoint, and its results folder's
    run.log says so as soon as the checkpoint is written and ends with the line that says how
    to resume (the same line as on stderr, where it arrived); the resumed run appends its own
    lines to the log and gives the uninterrupted run's numbers."""
    job = {"hemisphere": HEMISPHERE, "double_dome": DOUBLE_DOME}[name]
    folder = tmp_path / "stopped"
    patience = {"OMPI_MCA_odls_base_sigkill_timeout": "10"} if name == "double_dome" else {}
    process = start(job, folder, *every(1), env=patience)
    while not (folder / "checkpoint.npz").exists() and process.poll() is None:
        time.sleep(0.02)
    targets = children(process.pid) + ([process.pid] if name == "double_dome" else [])
    for pid in targets:
        os.kill(pid, signal.SIGTERM)
    if name == "hemisphere":
        _, err = process.communicate(timeout=600)
        assert process.returncode == 1, err
        assert one_line(err) == log_lines(folder)[-1]
    else:
        # what counts is that the ranks finish their files; mpirun itself, signalled, waits
        # its sigkill timeout twice (20 s) before it exits, with nothing left to do once the
        # ranks are gone
        wait_until_gone(targets[:-1])
        process.kill()
        process.communicate(timeout=600)
    lines = log_lines(folder)
    written = [text for text in lines if "SIGTERM received: the checkpoint of step" in text]
    assert len(written) == 1, lines      # said as soon as the checkpoint is on disk
    stopped_at = int(written[0].split("checkpoint of step ")[1].split()[0])
    line = lines[-1]
    assert "drape run: stopped: SIGTERM received; stopped after step" in line
    resume = line.split("resume with: ")[1]
    assert resume.startswith("mpirun -n 2 drape run ") and "--resume" in resume
    assert int(line.split("stopped after step ")[1].split()[0]) == stopped_at
    assert stopped_at < 4                                       # stopped before the end
    print(f"\n{name}: stopped after step {stopped_at}")
    done = drape("run", *job, "--output", folder, *every(1), "--resume", ranks=2)
    assert done.returncode == 0, done.stderr
    check_same_run(folder, uninterrupted(name, job))
    lines = log_lines(folder)
    headers = [text for text in lines if text.startswith("# ")]
    assert len(headers) == 2 and "--resume" not in headers[0] and "--resume" in headers[1]
    assert headers[1].endswith("(drape 0.1.0)") and "mpirun -n 2 drape run " in headers[1]
    after = lines[lines.index(headers[1]):]
    assert f"drape run: resuming from the checkpoint of step {stopped_at} " in "\n".join(after)
    steps = [int(text.split(":")[0].split()[1]) for text in after if text.startswith("step ")]
    assert steps == list(range(stopped_at + 1, len(read_steps(folder))))
    assert lines[-1].startswith(f"drape run: {steps[-1]} steps to t = 1 in ")


def wait_until_gone(pids, timeout=120.0):
    """Until none of the processes runs (gone, or a zombie: an orphan's parent may not reap)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        running = []
        for pid in pids:
            try:
                with open(f"/proc/{pid}/stat") as stream:
                    state = stream.read().rsplit(")", 1)[1].split()[0]
            except OSError:
                continue
            if state != "Z":
                running.append(pid)
        if not running:
            return
        time.sleep(0.05)
    raise AssertionError(f"processes {pids} still run after {timeout:g} s")


def log_lines(folder):
    """The lines of the run's log (drape.io.run_log) in its results folder."""
    return (folder / "run.log").read_text().splitlines()


@pytest.mark.serial
def test_sigkill_of_one_rank_then_resume(tmp_path, uninterrupted):
    """One rank killed by SIGKILL after step 3 (the checkpoint is of step 2): mpirun ends the
    job; the resume on 2 ranks drops step 3, computes it again and ends as the uninterrupted
    run."""
    folder = tmp_path / "killed"
    process = start(HEMISPHERE, folder, *every(2))
    wait_for_rows(process, folder, 4)
    ranks = children(process.pid)
    assert len(ranks) == 2 and process.poll() is None
    os.kill(ranks[1], signal.SIGKILL)
    process.communicate(timeout=300)
    assert process.returncode != 0
    rows = read_steps(folder)
    with np.load(folder / "checkpoint.npz") as data:
        saved = json.loads(str(data["meta"]))["step"]
    print(f"\nkilled after {len(rows) - 1} steps, checkpoint of step {saved}")
    assert saved == 2 and len(rows) - 1 in (3, 4)
    done = drape("run", *HEMISPHERE, "--output", folder, *every(2), "--resume", ranks=2)
    assert done.returncode == 0, done.stderr
    check_same_run(folder, uninterrupted("hemisphere", HEMISPHERE))


# --- a full disk ------------------------------------------------------------------------------

def mount_tmpfs(path: Path, size: str):
    path.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                          capture_output=True, text=True)
    return done.returncode == 0, done.stderr.strip()


class SmallDisk:
    """A tmpfs of a given size at ``path`` (rank 0 mounts it; every rank gets its path)."""

    def __init__(self, path, comm):
        self.path, self.comm, self.mounted = path, comm, False

    def mount(self, size):
        """Mount it, or skip the test with the reason."""
        ok, reason = mount_tmpfs(self.path, size) if self.comm.rank == 0 else (None, None)
        ok, reason = self.comm.bcast((ok, reason), root=0)
        if not ok:
            pytest.skip(f"cannot mount a small filesystem here (mount -t tmpfs: {reason})")
        self.mounted = True
        return self.path

    def grow(self, size):
        """Space freed: the filesystem made larger."""
        if self.comm.rank == 0:
            subprocess.run(["mount", "-o", f"remount,size={size}", str(self.path)], check=True)
        self.comm.barrier()


@pytest.fixture
def small_disk(tmp_path, comm):
    disk = SmallDisk(Path(comm.bcast(str(tmp_path / "small"), root=0)), comm)
    yield disk
    comm.barrier()
    if comm.rank == 0 and disk.mounted:    # lazily: a failed HDF5 file stays open here
        subprocess.run(["umount", "-l", str(disk.path)], check=False)


def check_folder_at_last_step(folder):
    """steps.csv ends with a complete row, fields.xdmf has exactly its steps (each dataset
    there), the checkpoint is readable and of a step in steps.csv."""
    rows = read_steps(folder)
    assert [int(r["step"]) for r in rows] == list(range(len(rows)))
    times, items = xdmf_times_and_datasets(folder)
    assert times["displacement"] == [float(r["t"]) for r in rows]
    check_datasets_exist(folder, items)
    with np.load(folder / "checkpoint.npz") as data:
        saved = json.loads(str(data["meta"]))["step"]
        assert all(data[k].size >= 0 for k in data.files)
    assert 1 <= saved <= int(rows[-1]["step"])
    assert not list(folder.glob(".*.tmp"))
    return int(rows[-1]["step"]), saved


@pytest.mark.serial
def test_a_full_disk_stops_with_one_line_and_resumes(small_disk, uninterrupted):
    """drape run checks the free space before each step: the hemisphere on 2 ranks (about
    0.1 MB of fields a step, a checkpoint of 0.62 MB plus its copy of fields.h5) into 1.18 MB."""
    folder = small_disk.mount("1180k") / "run"
    failed = drape("run", *HEMISPHERE, "--output", folder, *every(2), ranks=2)
    assert failed.returncode == 1, failed.stderr
    line = one_line(failed.stderr)
    print("\n" + line)
    assert line.startswith("drape run: run failed: could not write step ")
    assert f"in {folder}: No space left on device (" in line
    assert " free; a step writes about " in line and "a checkpoint about" in line
    assert "drape run: warning" not in line
    last, saved = check_folder_at_last_step(folder)
    assert f"results up to step {last} " in line and f"checkpoint of step {saved}" in line
    resume = line.split("resume (once there is space) with: ")[1]
    assert resume.startswith("mpirun -n 2 drape run ") and "--resume" in resume
    assert last < 5
    small_disk.grow("20m")
    done = drape("run", *HEMISPHERE, "--output", folder, *every(2), "--resume", ranks=2)
    assert done.returncode == 0, done.stderr
    check_same_run(folder, uninterrupted("hemisphere", HEMISPHERE))


@pytest.mark.serial   # on 2 ranks a failure inside HDF5's collective write can deadlock
def test_a_failed_hdf5_write_keeps_the_last_step(comm, small_disk, monkeypatch):
    """The write itself fails (free space not checked first, as on a quota the filesystem
    does not report): HDF5 runs out of space inside the fields of a step. Every rank raises the
    same WriteFailed; steps.csv and fields.xdmf end with the step before; the checkpoint of an
    earlier step is readable; after space is freed the resume ends as the run never stopped
    (in this process, on this pass's ranks)."""
    from drape.io.disk import Disk
    from drape.errors import WriteFailed
    from drape.job import load_job
    from drape.run import run_job

    overrides = [a for a in HEMISPHERE[1:] if a not in ("--set", "--quiet")]
    # 1.38 MB: after step 2 and its checkpoint (fields.h5 and its copy 0.33 MB each, the
    # checkpoint 0.62 MB) about 80 kB are left, and step 3's fields need about 100 kB
    folder = small_disk.mount("1380k") / "run"
    job = load_job(CONFIGS / "hemisphere.toml", overrides=[*overrides,
                                                          "output.checkpoint_every=2"])
    check = Disk.check
    monkeypatch.setattr(Disk, "check", lambda self, *args, **kwargs: None)
    # this process keeps the failed fields.h5 open (drape.io.writer._abandon), locked for h5py
    monkeypatch.setenv("HDF5_USE_FILE_LOCKING", "FALSE")
    with pytest.raises(WriteFailed) as caught:
        run_job(job, comm, output=folder)
    message = str(caught.value)
    assert "\n" not in message and "could not write" in message and " free; " in message
    if comm.rank == 0:
        print("\n" + message)
        last, saved = check_folder_at_last_step(folder)
        assert f"results up to step {last} " in message
    monkeypatch.setattr(Disk, "check", check)
    small_disk.grow("20m")
    resumed = run_job(job, comm, output=folder, resume=True)
    reference = run_job(job, comm, output=small_disk.path / "reference")
    assert len(resumed.rows) == len(reference.rows) >= 5
    for ra, rb in zip(resumed.rows, reference.rows):
        ra, rb = ra.row(), rb.row()
        for key, value in rb.items():
            if key not in TIMES:
                assert abs(ra[key] - value) <= 1e-10 * max(1.0, abs(value)), key
    if comm.rank == 0:
        check_same_run(folder, small_disk.path / "reference")


def test_resume_onto_another_partition(comm, shared_tmp, monkeypatch):
    """The checkpoint is keyed by gmsh's node and cell numbers: a resume whose mesh is
    partitioned otherwise (here every cell sent to the other rank) restores every node and
    quadrature point and ends as the uninterrupted run, to 1e-10 (run-to-run noise on 2 ranks
    is ~5e-12). Meaningful under mpirun -n 2 (serially the partition is the same)."""
    import dolfinx.cpp as cpp
    import dolfinx.io.gmshio as gmshio

    from drape.io import checkpoint
    from drape.errors import Interrupted
    from drape.job import load_job
    from drape.run import run_job

    overrides = [a for a in HEMISPHERE[1:] if a not in ("--set", "--quiet")]
    job = load_job(CONFIGS / "hemisphere.toml", overrides=[*overrides, "output.xdmf=false",
                                                          "output.checkpoint_every=2"])
    owned = []
    layout = checkpoint.Layout.__init__

    def record(self, problem):
        layout(self, problem)
        owned.append(set(self.cell_key[: self.n_cells].tolist()))
    monkeypatch.setattr(checkpoint.Layout, "__init__", record)

    step_done = checkpoint.Checkpoints.step_done

    def stop_after_step_2(self, step):      # SIGTERM on rank 0 once step 2 is checkpointed
        step_done(self, step)
        if step.number == 2 and comm.rank == 0:
            os.kill(os.getpid(), signal.SIGTERM)
    monkeypatch.setattr(checkpoint.Checkpoints, "step_done", stop_after_step_2)
    with pytest.raises(Interrupted):
        run_job(job, comm, output=shared_tmp / "stopped")
    monkeypatch.setattr(checkpoint.Checkpoints, "step_done", step_done)

    default = cpp.mesh.create_cell_partitioner()

    def swapped(comm_, parts, tdim, cells, ghost_mode):
        destinations = default(comm_, parts, tdim, cells, ghost_mode)
        return cpp.graph.AdjacencyList_int32(
            (parts - 1 - destinations.array).astype(np.int32), destinations.offsets)
    create_mesh = gmshio.create_mesh
    monkeypatch.setattr(gmshio, "create_mesh", lambda *args: create_mesh(
        *args, partitioner=swapped))
    resumed = run_job(job, comm, output=shared_tmp / "stopped", resume=True)
    monkeypatch.setattr(gmshio, "create_mesh", create_mesh)
    if comm.size > 1:
        assert owned[1] != owned[0]          # another partition indeed
    reference = run_job(job, comm, output=shared_tmp / "reference")
    assert owned[2] == owned[0]              # and the same one again without the swap
    assert resumed.rows[2].step == 2 and len(resumed.rows) == len(reference.rows) >= 5
    for ra, rb in zip(resumed.rows, reference.rows):
        step, ra, rb = rb.step, ra.row(), rb.row()
        for key, value in rb.items():
            if key not in TIMES:
                assert abs(ra[key] - value) <= 1e-10 * max(1.0, abs(value)), (step, key)
    assert reference.rows[-1].columns["punch_force"] > 1.0
