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
