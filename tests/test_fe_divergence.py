"""Divergence handling: a step that does not converge is cut back and retried from the committed
state (the failed attempts leave no trace), and below the minimum step the run fails with a
message naming step, load factor and residual, keeping what converged."""

import csv
import textwrap

import numpy as np
import pytest

from conftest import CONFIGS
from drape.errors import RunFailed
from drape.job import load_job
from drape.run import run_job

FAST = ["output.xdmf=false", "solver.max_iterations=6", "steps.initial=1.0", "steps.maximum=1.0"]


def test_cutbacks_leave_no_trace(comm, shared_tmp):
    """Run A tries the whole 15 mm stroke of the bias-extension test in one step with at most
    6 Newton iterations (it needs 8): it fails and is cut back. Run B is given exactly A's
    converged load factors as history waypoints, so it never fails. If a failed attempt had
    changed the committed state (law, displacement), A and B would differ."""
    a = run_job(load_job(CONFIGS / "bias_extension.toml", overrides=FAST), comm,
                output=shared_tmp / "a")
    rows_a = a.rows
    assert rows_a[1].cutbacks >= 1
    assert sum(r.cutbacks for r in rows_a) >= 1 and rows_a[-1].t == 1.0
    t = [r.t for r in rows_a]
    d = [r.histories["d"] for r in rows_a]
    waypoints = [f"history.d.t={t!r}", f"history.d.values={d!r}"]
    b = run_job(load_job(CONFIGS / "bias_extension.toml", overrides=FAST + waypoints), comm,
                output=shared_tmp / "b")
    assert [r.t for r in b.rows] == t
    assert all(r.cutbacks == 0 for r in b.rows)
    if comm.rank == 0:
        ra, rb = np.load(shared_tmp / "a" / "result.npz"), np.load(shared_tmp / "b" / "result.npz")
        assert np.abs(ra["u"] - rb["u"]).max() <= 1e-12 * np.abs(ra["u"]).max()
        assert np.abs(ra["tau"] - rb["tau"]).max() <= 1e-12 * np.abs(ra["tau"]).max()


JUMP = """
    # the bias-extension blank with a clamp that jumps 10 mm at t = 0.5: no step is small
    # enough for Newton (at most 6 iterations) to follow the jump
    material = "{material}"
    [blank]
    length = 100.0
    width = 50.0
    yarn_angle = 45.0
    [mesh]
    size = 4.5
    [steps]
    minimum = 1e-3
    [solver]
    max_iterations = 6
    [output]
    xdmf = false
    [history.d]
    values = [0.0, 15.0]
    [[boundary]]
    on = "left"
    ux = "0"
    uy = "0"
    uz = "0"
    [[boundary]]
    on = "right"
    ux = "d + where(t > 0.5, 10.0, 0.0)"
    uy = "0"
    uz = "0"
"""


def write_jump(folder):
    path = folder / "jump.toml"
    material = (CONFIGS / "materials" / "paper_three_surface.toml").as_posix()
    path.write_text(textwrap.dedent(JUMP.format(material=material)))
    return path


def test_non_convergence_fails_clearly_and_keeps_the_results(comm, shared_tmp):
    if comm.rank == 0:
        write_jump(shared_tmp)
    comm.barrier()
    job = load_job(shared_tmp / "jump.toml")
    with pytest.raises(RunFailed) as caught:
        run_job(job, comm, output=shared_tmp / "jump")
    message = str(caught.value)
    assert "Newton did not converge at load factor t = 0.50" in message
    assert "last residual norm" in message and "steps.minimum = 0.001" in message
    assert "results up to t = 0.49" in message and str(shared_tmp / "jump") in message
    if comm.rank == 0:
        with open(shared_tmp / "jump" / "steps.csv") as stream:
            rows = list(csv.DictReader(stream))
        assert len(rows) > 10
        last = float(rows[-1]["t"])
        assert 0.49 < last <= 0.5
        assert f"step {int(rows[-1]['step']) + 1}:" in message
        snapshot = np.load(shared_tmp / "jump" / "result.npz")
        assert float(snapshot["t"]) == last
        # the committed state, not the failed attempt's: the clamp where the last step left it
        right = np.isclose(snapshot["node_xy"][:, 0], 100.0)
        assert np.allclose(snapshot["u"][right, 0], float(rows[-1]["d"]), rtol=1e-14, atol=0)
        # the checkpoint of the last converged step is written too
        assert message.endswith("(with a checkpoint)")
        with np.load(shared_tmp / "jump" / "checkpoint.npz") as data:
            assert f'"step": {rows[-1]["step"]},' in str(data["meta"])


def test_a_failed_run_goes_on_from_its_checkpoint_with_other_controls(comm, shared_tmp):
    """The jump job (5 mm stretch, then the 10 mm jump at t = 0.5) fails at the jump with at
    most 6 Newton iterations a step. Resumed from its checkpoint with `solver.max_iterations =
    40` (a numerical control a resume may change, drape.io.checkpoint.CONTROL_KEYS) it passes
    the jump and ends at t = 1, saying what it changed; and it ends where the same job run
    with 40 iterations from the start does, although the two took different steps (the failed
    run cut back before the jump): the law's increments do not depend on their size (version
    2), so the converged end states agree to Newton's tolerance (measured 2e-12 relative). A
    resume that changes the problem (the mesh) is still refused, naming only that key."""
    from drape.errors import InputError
    if comm.rank == 0:
        write_jump(shared_tmp)
    comm.barrier()
    path, short = shared_tmp / "jump.toml", ["history.d.values=[0, 5]"]
    folder = shared_tmp / "failed"
    with pytest.raises(RunFailed) as caught:
        run_job(load_job(path, overrides=short), comm, output=folder)
    assert caught.value.resumable and "Newton did not converge at load factor t = 0.50" in str(
        caught.value)
    with pytest.raises(InputError) as refused:
        run_job(load_job(path, overrides=short + ["mesh.size=5"]), comm, output=folder,
                resume=True)
    assert "mesh.size (4.5 -> 5.0)" in str(refused.value)
    assert "only the steps.*, solver.* and process.holder_prediction" in str(refused.value)
    said = []
    more = short + ["solver.max_iterations=40"]
    resumed = run_job(load_job(path, overrides=more), comm, output=folder, resume=True,
                      log=said.append)
    assert any("resuming with other numerical controls: solver.max_iterations (6 -> 40)" in line
               for line in said)
    assert resumed.rows[-1].t == 1.0 and resumed.rows[0].t == 0.0
    assert any(r.cutbacks for r in resumed.rows)          # the failed run's, before the jump
    straight = run_job(load_job(path, overrides=more), comm, output=shared_tmp / "straight")
    assert [r.t for r in straight.rows] != [r.t for r in resumed.rows]
    if comm.rank == 0:
        a, b = (np.load(shared_tmp / name / "result.npz") for name in ("failed", "straight"))
        assert np.abs(a["u"] - b["u"]).max() <= 1e-8 * np.abs(b["u"]).max()
        assert np.abs(a["tau"] - b["tau"]).max() <= 1e-8 * np.abs(b["tau"]).max()
        assert np.abs(b["u"]).max() == pytest.approx(15.0, rel=1e-3)
