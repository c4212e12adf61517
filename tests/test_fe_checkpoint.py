"""Reliability of `drape run`: a run stopped by SIGTERM writes a checkpoint and files that hold
every converged step; `--resume` continues it to the same numbers as a run never stopped
(result.npz: u and tau within 1e-10, serially and on 2 ranks; on another number of ranks as
1 rank and 2 agree, 1e-8); a changed config is refused (exit 2); results are never
overwritten silently (run, picture-frame, calibrate); a NaN in the law's output or the
residual fails the attempt, never a result."""

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from conftest import CONFIGS, REPO

#: the bias-extension job, coarse (76 cells), 27 steps
SHORT = ["--set", "mesh.size=10", "--set", "steps.maximum=0.04", "--set",
         "output.checkpoint_every=5", "--quiet"]
ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
           OMPI_MCA_rmaps_base_oversubscribe="1")


def command(*args, ranks=1):
    line = [sys.executable, "-m", "drape.cli", *map(str, args)]
    return ["mpirun", "-n", str(ranks), *line] if ranks > 1 else line


def drape(*args, ranks=1):
    return subprocess.run(command(*args, ranks=ranks), capture_output=True, text=True, cwd=REPO,
                          env=ENV, timeout=600)


def children(pid):
    """Process ids whose parent is pid (Linux /proc)."""
    found = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as stream:
                    fields = stream.read().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                found.append(int(entry))
    return found


def run_and_terminate(folder, ranks=1):
    """Start the short job, SIGTERM it as soon as its first checkpoint exists; returns the
    finished process's return code and stderr. Under mpirun the ranks get the SIGTERM, as from
    a batch system that signals every process of a job: mpirun itself answers a SIGTERM with
    SIGCONT, a SIGTERM to the ranks only after odls_base_sigkill_timeout (1 s) and SIGKILL 1 s
    later (docs/fe-results.md, "Signals")."""
    process = subprocess.Popen(command("run", CONFIGS / "bias_extension.toml", "--output", folder,
                                       *SHORT, ranks=ranks),
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO,
                               env=ENV)
    while not (folder / "checkpoint.npz").exists() and process.poll() is None:
        time.sleep(0.01)
    if ranks == 1:
        process.send_signal(signal.SIGTERM)
    else:
        ranks_found = children(process.pid)
        assert len(ranks_found) == ranks, ranks_found
        for pid in ranks_found:
            os.kill(pid, signal.SIGTERM)
    _, err = process.communicate(timeout=300)
    return process.returncode, err


def read_steps(folder):
    with open(folder / "steps.csv") as stream:
        return list(csv.DictReader(stream))


def xdmf_times_and_datasets(folder):
    """Time values of the displacement series, and (h5 file, dataset path) of every DataItem."""
    root = ET.parse(folder / "fields.xdmf").getroot()
    times = {}
    for collection in root.iter("Grid"):
        if collection.get("GridType") == "Collection":
            times[collection.get("Name")] = [float(g.find("Time").get("Value"))
                                             for g in collection.findall("Grid")]
    items = [item.text.strip().split(":", 1) for item in root.iter("DataItem")]
    return times, items


def check_datasets_exist(folder, items):
    import h5py
    for name, path in items:
        # no file lock: a failed run may still hold fields.h5 open in this process (through
        # DOLFINx's HDF5), and HDF5 reads HDF5_USE_FILE_LOCKING once, when first used
        with h5py.File(folder / name, "r", locking=False) as h5:
            assert path in h5, (name, path)


def check_stopped_folder(folder, rc, err):
    """The state after SIGTERM: exit 1 and one line naming the step, t and the resume command;
    steps.csv = converged steps; fields.xdmf parses and has every step's datasets."""
    assert rc == 1, err
    lines = [line for line in err.splitlines() if line.startswith("drape run")]
    assert len(lines) == 1 and "Traceback" not in err, err
    line = lines[0]
    assert "drape run: stopped: SIGTERM received; stopped after step" in line
    assert "--resume" in line and f"--output {folder}" in line
    step = int(line.split("stopped after step ")[1].split()[0])
    rows = read_steps(folder)
    assert [int(r["step"]) for r in rows] == list(range(step + 1))
    assert f"at t = {float(rows[-1]['t']):.6g}:" in line
    times, items = xdmf_times_and_datasets(folder)
    assert times["displacement"] == [float(r["t"]) for r in rows]
    assert all(len(series) == step + 1 for series in times.values()) and len(times) == 9
    check_datasets_exist(folder, items)
    with np.load(folder / "checkpoint.npz") as data:   # the last converged step, not the 5th
        assert '"step": %d,' % step in str(data["meta"])
    assert step >= 5
    return step


def check_same_as_uninterrupted(resumed, uninterrupted, tolerance=1e-10):
    """result.npz's u and tau, steps.csv's counts (exactly) and values, the XDMF series (each
    step once, every dataset there) and its last displacement (result.npz's)."""
    a, b = np.load(resumed / "result.npz"), np.load(uninterrupted / "result.npz")
    assert np.abs(a["u"]).max() > 10.0 and np.abs(a["tau"]).max() > 1.0
    assert np.abs(a["u"] - b["u"]).max() <= tolerance * max(1.0, np.abs(b["u"]).max())
    assert np.abs(a["tau"] - b["tau"]).max() <= tolerance * max(1.0, np.abs(b["tau"]).max())
    rows_a, rows_b = read_steps(resumed), read_steps(uninterrupted)
    assert len(rows_a) == len(rows_b) > 20
    for ra, rb in zip(rows_a, rows_b):
        for key in ("step", "t", "dt", "newton_iterations", "cutbacks"):
            assert ra[key] == rb[key]
        for key in ("right_Fx", "external_work", "tau_mean"):
            assert abs(float(ra[key]) - float(rb[key])) <= tolerance * max(1.0,
                                                                             abs(float(rb[key])))
    times, items = xdmf_times_and_datasets(resumed)
    assert times["displacement"] == [float(r["t"]) for r in rows_b]   # each step exactly once
    assert all(series == times["displacement"] for series in times.values())
    check_datasets_exist(resumed, items)
    xy, u = last_xdmf_displacement(resumed)
    order = np.lexsort((xy[:, 1], xy[:, 0]))
    assert np.abs(xy[order] - a["node_xy"]).max() < 1e-9
    assert np.abs(u[order] - a["u"]).max() <= 1e-12 * np.abs(a["u"]).max()


def last_xdmf_displacement(folder):
    """The last displacement of fields.xdmf at the coordinates of the mesh it refers to (its
    xi:include's grid), read as ParaView reads it: (points (N, 2), values (N, 3)), in the
    file's order."""
    import h5py
    root = ET.parse(folder / "fields.xdmf").getroot()
    series = next(g for g in root.iter("Grid") if g.get("Name") == "displacement"
                  and g.get("GridType") == "Collection")
    last = series.findall("Grid")[-1]
    pointer = last.find("{http://www.w3.org/2001/XInclude}include").get("xpointer")
    meshes = [g for g in root.find("Domain").findall("Grid") if g.get("GridType") == "Uniform"]
    if "@Name=" in pointer:
        name = pointer.split("@Name='")[1].split("'")[0]
        mesh = next(g for g in meshes if g.get("Name") == name)
    else:
        mesh = meshes[int(pointer.split("[@GridType='Uniform'][")[1].split("]")[0]) - 1]

    def read(item):
        file, path = item.text.strip().split(":", 1)
        with h5py.File(folder / file, "r", locking=False) as h5:
            return np.asarray(h5[path])
    return read(mesh.find("Geometry/DataItem")), read(last.find("Attribute/DataItem"))


def forget_setting(path, key):
    """Remove ``key`` from the config signature a checkpoint file keeps, as a drape older than
    the setting would have written it."""
    with np.load(path) as data:
        arrays = {name: data[name] for name in data.files}
    meta = json.loads(str(arrays["meta"]))
    assert key in meta["signature"]
    del meta["signature"][key]
    arrays["meta"] = np.array(json.dumps(meta))
    np.savez(path, **arrays)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    """The short job run uninterrupted, once per number of ranks and extra arguments (the
    reference of the resume tests), made when first asked for: get(ranks, extra) -> folder."""
    made = {}

    def get(ranks=1, extra=()):
        key = (ranks, tuple(extra))
        if key not in made:
            folder = tmp_path_factory.mktemp("uninterrupted") / "run"
            full = drape("run", CONFIGS / "bias_extension.toml", "--output", folder, *SHORT,
                         *extra, ranks=ranks)
            assert full.returncode == 0, full.stderr
            # a finished run's fields.h5 is whole: the copy is removed
            assert not (folder / "checkpoint.h5").exists()
            made[key] = folder
        return made[key]
    return get


@pytest.mark.serial
@pytest.mark.parametrize("ranks", [1, 2])
def test_sigterm_then_resume_gives_the_uninterrupted_result(tmp_path, uninterrupted, ranks):
    stopped = tmp_path / "stopped"
    rc, err = run_and_terminate(stopped, ranks)
    step = check_stopped_folder(stopped, rc, err)
    print(f"\n{ranks} rank(s): stopped after step {step}")

    # a changed config: refused, naming what differs
    changed = drape("run", CONFIGS / "bias_extension.toml", "--output", stopped, *SHORT,
                    "--set", "regularisation.out_of_plane_damping=0.01", "--resume", ranks=ranks)
    assert changed.returncode == 2, changed.stderr
    assert "regularisation.out_of_plane_damping (0.001 -> 0.01)" in changed.stderr
    moved = tmp_path / "moved"
    shutil.copytree(stopped, moved)
    if ranks == 1:
        # a checkpoint of an older drape, without a setting added since: resumed where the
        # setting is at its default (the behaviour before it), refused where it is not
        forget_setting(stopped / "checkpoint.npz", "contact.die_friction")
        newer = drape("run", CONFIGS / "bias_extension.toml", "--output", stopped, *SHORT,
                      "--set", "contact.die_friction=0.1", "--resume")
        assert newer.returncode == 2, newer.stderr
        assert "contact.die_friction (unset -> 0.1)" in newer.stderr

    done = drape("run", CONFIGS / "bias_extension.toml", "--output", stopped, *SHORT, "--resume",
                 ranks=ranks)
    assert done.returncode == 0, done.stderr
    check_same_as_uninterrupted(stopped, uninterrupted(ranks))

    # on the other number of ranks: as that run, which 1 rank and 2 give alike to round-off
    # (test_fe_cli.py: 1e-8); its fields refer to the mesh as this partition writes it
    other = 2 if ranks == 1 else 1
    done = drape("run", CONFIGS / "bias_extension.toml", "--output", moved, *SHORT, "--resume",
                 ranks=other)
    assert done.returncode == 0, done.stderr
    check_same_as_uninterrupted(moved, uninterrupted(ranks), tolerance=1e-8)
    assert "mesh-r%d" % other in (moved / "fields.xdmf").read_text()


@pytest.mark.serial
@pytest.mark.parametrize("torn, surfaces", [(False, []), (True, []),
                                            (False, ["--set", "surfaces=0"])],
                         ids=["whole", "torn", "outer-surface-only"])
def test_resume_after_a_hard_kill_drops_the_steps_after_the_checkpoint(tmp_path, uninterrupted,
                                                                      torn, surfaces):
    """SIGKILL leaves steps after the last periodic checkpoint in steps.csv and fields.xdmf/h5:
    the resume drops them and writes them again, once. ``torn``: the kill came while a step's
    fields were being written and left fields.h5 unreadable (here: cut to two thirds of its
    length); the resume takes the checkpointed steps' fields from the checkpoint's copy.
    ``surfaces = 0`` (the outer surface alone: the law has no centres to keep) once failed
    writing its first checkpoint."""
    folder = tmp_path / "killed"
    short = [*SHORT, *surfaces]
    process = subprocess.Popen(command("run", CONFIGS / "bias_extension.toml", "--output", folder,
                                       *short), cwd=REPO, env=ENV, stderr=subprocess.DEVNULL)
    while not (folder / "checkpoint.npz").exists() and process.poll() is None:
        time.sleep(0.01)
    while len(read_steps(folder)) < 9 and process.poll() is None:   # past the checkpoint
        time.sleep(0.01)
    process.kill()
    process.wait()
    assert len(read_steps(folder)) > 6
    assert (folder / "checkpoint.h5").is_file()
    if torn:
        h5 = folder / "fields.h5"
        os.truncate(h5, 2 * h5.stat().st_size // 3)
    done = drape("run", CONFIGS / "bias_extension.toml", "--output", folder, *short, "--resume")
    assert done.returncode == 0, done.stderr
    check_same_as_uninterrupted(folder, uninterrupted(1, surfaces))
    # a finished run's fields.h5 is whole: the copy is removed (and from the uninterrupted
    # run's: the fixture checks it)
    assert not (folder / "checkpoint.h5").exists()


@pytest.mark.serial
def test_results_are_not_overwritten_silently(tmp_path):
    folder = tmp_path / "run"
    args = ["run", CONFIGS / "bias_extension.toml", "--output", folder, *SHORT,
            "--set", "steps.maximum=0.25"]
    assert drape(*args).returncode == 0
    for ranks in (1, 2):
        again = drape(*args, ranks=ranks)
        assert again.returncode == 2, again.stderr
        lines = [line for line in again.stderr.splitlines() if line.startswith("drape")]
        assert len(lines) == 1 and "Traceback" not in again.stderr
        assert ("already holds results (checkpoint.npz, fields.xdmf, result.npz, steps.csv)"
                in lines[0])
        assert "--overwrite" in lines[0] and "--resume" in lines[0]
    over = drape(*args, "--overwrite")
    assert over.returncode == 0, over.stderr
    assert len(read_steps(folder)) == 15
    # nothing to resume in an empty folder
    empty = drape("run", CONFIGS / "bias_extension.toml", "--output", tmp_path / "empty",
                  "--resume")
    assert empty.returncode == 2 and "nothing to resume" in empty.stderr

    pf = ["picture-frame", "--cycles", "5", "--increment", "1", "--output", tmp_path / "pf"]
    assert drape(*pf).returncode == 0
    again = drape(*pf)
    assert again.returncode == 2 and "picture_frame.csv" in again.stderr
    assert "--overwrite" in again.stderr
    assert drape(*pf, "--overwrite").returncode == 0


#: the ranks' wait for each other in the test (drape's is 20 s, drape.step_loop.ALONE_WAIT)
WAIT = 5.0
#: run_job on the short job under mpirun, rank 1 alone raising in its on_step hook at step 3
ONE_RANK_FAILS = f"""
import sys
from mpi4py import MPI
import drape.step_loop
from drape.job import load_job
from drape.run import run_job
drape.step_loop.ALONE_WAIT = {WAIT}
job = load_job(sys.argv[1], overrides=["mesh.size=10", "steps.maximum=0.04",
                                       "output.checkpoint_every=1"])
def on_step(record, problem):
    if record.step == 3 and MPI.COMM_WORLD.rank in map(int, sys.argv[3].split(",")):
        raise RuntimeError(f"a fault on ranks {{sys.argv[3]}}")
run_job(job, output=sys.argv[2], on_step=on_step)
"""


@pytest.mark.serial
@pytest.mark.parametrize("ranks", ["1", "0,1"])
def test_an_error_on_one_rank_aborts_the_run_instead_of_hanging(tmp_path, ranks):
    """An unexpected exception on one rank only (a bug, a hook): the other rank waits in a
    collective, and the run's collective clean-up hung both until the job's time limit. Now
    the rank prints its traceback and, the other not raising it within ALONE_WAIT, aborts all
    ranks: a non-zero exit, the steps up to the fault and their checkpoint on disk. Raised on
    both ranks (a hook stopping a run on purpose), the run ends in order as before: the
    exception's traceback, the files closed (fields.xdmf parses), no abort. The wait is
    shortened to WAIT here."""
    folder = tmp_path / "run"
    line = ["mpirun", "-n", "2", sys.executable, "-c", ONE_RANK_FAILS,
            str(CONFIGS / "bias_extension.toml"), str(folder), ranks]
    started = time.monotonic()
    failed = subprocess.run(line, capture_output=True, text=True, cwd=REPO, env=ENV,
                            timeout=300, stdin=subprocess.DEVNULL)
    assert failed.returncode != 0
    assert f"RuntimeError: a fault on ranks {ranks}" in failed.stderr
    alone = ranks == "1"
    assert ("drape: rank 1: unexpected error (above), not raised on the other ranks within "
            f"{WAIT:g} s; aborting all 2 ranks" in failed.stderr) == alone
    if alone:
        assert time.monotonic() - started > WAIT
    assert [row["step"] for row in read_steps(folder)] == ["0", "1", "2", "3"]
    assert (folder / "checkpoint.npz").exists()
    if not alone:
        times, _ = xdmf_times_and_datasets(folder)
        assert times and all(len(series) == 4 for series in times.values())


def test_calibrate_refuses_an_occupied_folder(comm, tmp_path, capsys):
    from drape.cli import main
    out = tmp_path / "cal"
    out.mkdir()
    (out / "material.toml").write_text("# an earlier fit\n")
    data = tmp_path / "data.csv"
    cycle = [*range(0, 20), *range(20, -20, -1), *range(-20, 1)]
    data.write_text("gamma_t_deg,tau\n" + "".join(f"{g},{0.01 * g}\n" for g in cycle))
    assert main(["calibrate", str(data), "--surfaces", "0", "--output", str(out)]) == 2
    err = capsys.readouterr().err
    if comm.rank == 0:      # under mpirun rank 0 alone reports
        assert "already holds results (material.toml)" in err and "--overwrite" in err
    else:
        assert err == ""
    assert (out / "material.toml").read_text() == "# an earlier fit\n"


# --- NaN / Inf ---------------------------------------------------------------------------------

NAN_JOB = ["output.xdmf=false", "mesh.size=10", "steps.maximum=0.1", "steps.minimum=0.01"]


def run_with_nan(comm, folder, monkeypatch, *, law_calls=None, residual_calls=None):
    """Run the short job with NaN in tau (law) or in the residual vector on the given calls
    (counted on rank 0 only: the other rank sees nothing)."""
    from dolfinx.fem import petsc as fpetsc

    from drape.job import load_job
    from drape.law.nested_surface import NestedSurfaceLaw
    from drape.run import run_job

    count = {"law": 0, "residual": 0}
    forms = {}
    law_calls = law_calls or (lambda n: False)
    residual_calls = residual_calls or (lambda n: False)
    update, assemble = NestedSurfaceLaw.update, fpetsc.assemble_vector

    def poisoned_update(self, *args):
        response = update(self, *args)
        count["law"] += 1
        if comm.rank == 0 and law_calls(count["law"]) and response.tau.size:
            response.tau[0] = np.nan
        return response

    def poisoned_assemble(*args, **kwargs):
        result = assemble(*args, **kwargs)
        if args[-1] is forms.get("residual"):   # Newton's residual, not the internal force
            count["residual"] += 1
            if comm.rank == 0 and residual_calls(count["residual"]):
                args[0].array[:] = np.inf
        return result

    monkeypatch.setattr(NestedSurfaceLaw, "update", poisoned_update)
    monkeypatch.setattr(fpetsc, "assemble_vector", poisoned_assemble)
    return run_job(load_job(CONFIGS / "bias_extension.toml", overrides=NAN_JOB), comm,
                   output=folder, on_start=lambda run: forms.update(
                       residual=run.problem.residual_form))


@pytest.mark.parametrize("where", ["law", "residual"])
def test_a_nan_once_is_a_cutback_not_a_result(comm, shared_tmp, monkeypatch, where):
    summary = run_with_nan(comm, shared_tmp / where, monkeypatch,
                           **{f"{where}_calls": lambda n: n == 40})
    rows = summary.rows
    assert rows[-1].t == 1.0
    assert sum(r.cutbacks for r in rows) == 1
    assert all(np.isfinite(float(v)) for r in rows for v in r.row().values())
    if comm.rank == 0:
        result = np.load(shared_tmp / where / "result.npz")
        assert np.isfinite(result["u"]).all() and np.isfinite(result["tau"]).all()


@pytest.mark.parametrize("where, text", [("law", "a NaN/Inf appeared in the law's output"),
                                         ("residual", "a NaN/Inf appeared in the residual")])
def test_a_persistent_nan_fails_the_run_naming_it(comm, shared_tmp, monkeypatch, where, text):
    from drape.errors import RunFailed
    folder = shared_tmp / f"always_{where}"
    with pytest.raises(RunFailed) as caught:
        run_with_nan(comm, folder, monkeypatch, **{f"{where}_calls": lambda n: n > 40})
    message = str(caught.value)
    assert text in message and "Newton did not converge at load factor t = " in message
    assert "steps.minimum = 0.01" in message and "(with a checkpoint)" in message
    if comm.rank == 0:
        rows = read_steps(folder)
        step = int(rows[-1]["step"])
        assert message.startswith(f"step {step + 1}: ") and f"(step {step})" in message
        assert all(np.isfinite(float(v)) for r in rows for v in r.values())
        with np.load(folder / "checkpoint.npz") as data:
            assert '"step": %d,' % step in str(data["meta"])


def test_a_signal_during_a_newton_attempt_ends_it_there(comm, shared_tmp, monkeypatch):
    """A SIGTERM noted in the middle of a Newton attempt (on rank 0 only) ends the attempt on
    every rank before the next residual evaluation, not after the line search and the attempt's
    remaining iterations; the run stops after the last converged step (Interrupted)."""
    from drape.errors import Interrupted
    from drape.job import load_job
    from drape.fe.membrane import MembraneProblem
    from drape.run import run_job

    calls = []
    original = MembraneProblem.residual

    def residual(self, snes, x, b):
        original(self, snes, x, b)
        calls.append(len(calls))
        if len(calls) == 40 and comm.rank == 0:
            os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(MembraneProblem, "residual", residual)
    job = load_job(CONFIGS / "bias_extension.toml", overrides=[
        "mesh.size=10", "steps.maximum=0.04", "output.xdmf=false"])
    with pytest.raises(Interrupted) as stopped:
        run_job(job, comm, output=shared_tmp / "run")
    assert "SIGTERM received; stopped after step" in str(stopped.value)
    print(f"residual evaluations: {len(calls)} (signal at the 40th)")
    assert len(calls) == 40
    rows = read_steps(shared_tmp / "run")
    assert 3 <= len(rows) - 1 < 20
