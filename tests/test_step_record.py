"""The step loop's typed records (drape/step_record.py): steps.csv's columns in the order drape
has always written them, rows read back to the same record (a checkpoint stores the rows; one
written before the records were typed resumes), the work ledger's trapezoidal rule, and a
step loop that knows nothing of forming."""

import ast
import csv
import io
from pathlib import Path

import numpy as np
import pytest

from drape.step_record import StepRecord, WorkLedger

# no MPI in these tests: under mpirun each rank would do the same (tests/conftest.py)
pytestmark = pytest.mark.serial

REPO = Path(__file__).resolve().parent.parent

#: steps.csv of `drape run configs/picture_frame.toml` before the records were typed (header and
#: step 1, as written by commit b6ed9d8): the loop's columns, a history, a boundary's reaction,
#: the frame-force report's columns, the wall time last
PICTURE_FRAME_CSV = (
    "step,t,dt,newton_iterations,cutbacks,residual_norm,angle,boundary_Fx,boundary_Fy,"
    "boundary_Fz,external_work,regularisation_work,regularisation_share,bending_energy,"
    "max_shear_angle_deg,max_yarn_strain,shear_oscillation_deg,tau_mean,frame_force,"
    "frame_force_from_tau,seconds\n"
    "1,0.001984126984126984,0.001984126984126984,1,0,1.3000013562299846e-16,"
    "0.5555555555555556,8.326672684688674e-17,1.0755285551056204e-16,0.0,0.1841346475245404,"
    "0.0,0.0,0.0,0.555555555555563,0.0,3.4416913763379853e-15,0.007596307782624614,"
    "0.5397378802992777,0.5397378803004994,0.0728607919991191\n")


def _typed(text: dict) -> dict:
    """A csv row as the loop held it: integers for the counters, floats for the rest."""
    counters = ("step", "newton_iterations", "cutbacks")
    return {k: int(v) if k in counters else float(v) for k, v in text.items()}


def test_the_row_has_steps_csv_columns_in_their_order():
    record = StepRecord(3, 0.25, 0.05, 4, 1, 1e-9, histories={"d": 3.75},
                        reactions={"left": (-2.0, 0.5, 0.0), "right": (2.0, -0.5, 0.0)},
                        external_work=8.0, regularisation_work=2.0, bending_energy=0.5,
                        max_shear_angle_deg=12.0, max_yarn_strain=1e-4,
                        shear_oscillation_deg=0.3, tau_mean=0.02,
                        columns={"force_N": 2.0, "central_shear_deg": 11.5}, seconds=1.5)
    assert list(record.row().items()) == [
        ("step", 3), ("t", 0.25), ("dt", 0.05), ("newton_iterations", 4), ("cutbacks", 1),
        ("residual_norm", 1e-9), ("d", 3.75),
        ("left_Fx", -2.0), ("left_Fy", 0.5), ("left_Fz", 0.0),
        ("right_Fx", 2.0), ("right_Fy", -0.5), ("right_Fz", 0.0),
        ("external_work", 8.0), ("regularisation_work", 2.0), ("regularisation_share", 0.25),
        ("bending_energy", 0.5), ("max_shear_angle_deg", 12.0), ("max_yarn_strain", 1e-4),
        ("shear_oscillation_deg", 0.3), ("tau_mean", 0.02),
        ("force_N", 2.0), ("central_shear_deg", 11.5), ("seconds", 1.5)]
    assert StepRecord.from_row(record.row(), ["d"], ["left", "right"]) == record


@pytest.mark.parametrize("external, share", [(8.0, 0.25), (-8.0, 0.25), (0.0, 0.0)])
def test_the_regularisation_share_follows_the_external_work(external, share):
    """|W_reg / W_ext|, 0 before any external work; a part adding its work (the punch's)
    changes it with the external work."""
    record = StepRecord(1, 0.1, external_work=external, regularisation_work=2.0)
    assert record.regularisation_share == share
    record.external_work += 12.0
    assert record.regularisation_share == 2.0 / abs(external + 12.0)


def test_a_row_written_before_the_records_were_typed_reads_back_unchanged():
    """A checkpoint keeps its rows as steps.csv's (version 4, before and after the records
    were typed): a row of the old loop gives a record whose row is the same, key for key, in
    the same order, the derived regularisation share included."""
    (text,) = list(csv.DictReader(io.StringIO(PICTURE_FRAME_CSV)))
    row = _typed(text)
    record = StepRecord.from_row(row, ["angle"], ["boundary"])
    assert record.histories == {"angle": 0.5555555555555556}
    assert record.reactions["boundary"][0] == pytest.approx(8.326672684688674e-17, rel=0)
    assert record.columns == {"frame_force": 0.5397378802992777,
                              "frame_force_from_tau": 0.5397378803004994}
    assert list(record.row().items()) == list(row.items())


def test_the_ledger_adds_the_boundary_work_by_the_trapezoidal_rule():
    """Two steps of a linear spring's end, f = k g with k = 3 N/mm, g 0 -> 1 -> 2 mm: the
    trapezoidal rule is exact for it, W = k g^2 / 2 = 1.5 then 6 N mm."""
    class One:      # a communicator of one rank
        @staticmethod
        def allreduce(value):
            return value
    ledger = WorkLedger()
    for g, work in ((0.0, 0.0), (1.0, 1.5), (2.0, 6.0)):
        ledger.add_boundary_work(np.array([3.0 * g]), np.array([g]), One)
        assert ledger.external == work


def _imports_and_attributes(path: Path):
    tree = ast.parse(path.read_text())
    modules = [node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)]
    modules += [alias.name for node in ast.walk(tree) if isinstance(node, ast.Import)
                for alias in node.names]
    attributes = {node.attr for node in ast.walk(tree) if isinstance(node, ast.Attribute)}
    return modules, attributes


def test_the_step_loop_knows_no_forming():
    """drape/step_loop.py imports nothing of drape.forming and reads no forming config key:
    the forming job's facts (a centred blank, its default bending, inertia) come from its
    part (drape.fe.job_part.JobPart)."""
    modules, attributes = _imports_and_attributes(REPO / "drape" / "step_loop.py")
    assert modules and not [m for m in modules if m.startswith("drape.forming")]
    assert not attributes & {"process", "tools", "contact", "forming"}


def test_the_bending_rigidity_is_the_configs_else_a_parts_default():
    """A forming job's unset bending rigidity is its part's default (10 N mm, drape.job_tables's
    DEFAULT_FORMING_BENDING, as before the loop stopped asking the config whether the job
    forms); a flat job's is 0; a set one is the config's."""
    from types import SimpleNamespace

    from drape.fe.job_part import JobPart
    from drape.forming.press import Forming
    from drape.job_tables import DEFAULT_FORMING_BENDING, BendingConfig
    from drape.step_loop import bending_rigidity
    assert Forming.default_bending_rigidity == DEFAULT_FORMING_BENDING == 10.0
    forming = SimpleNamespace(default_bending_rigidity=Forming.default_bending_rigidity)
    assert bending_rigidity(BendingConfig(), [JobPart(), forming]) == 10.0
    assert bending_rigidity(BendingConfig(), [JobPart()]) == 0.0
    assert bending_rigidity(BendingConfig(), []) == 0.0
    assert bending_rigidity(BendingConfig(rigidity=2.5), [forming]) == 2.5
