"""The command line as a user meets it: `drape --help` and every subcommand's --help exit 0,
explain every option (with its default), and state the exit codes (0, 2, 1); `drape run` shows
its progress on rank 0 only, plain lines off a terminal (one per converged step, with the load
factor and Newton iterations of steps.csv), nothing under --quiet (checked on every shipped
job's short run, on 1 and 2 ranks, by tests/test_fe_cli.py)."""

import csv
import io
import os
import re
import subprocess
import sys

import pytest

from conftest import REPO

pytestmark = pytest.mark.serial

ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
           OMPI_MCA_rmaps_base_oversubscribe="1")


def drape(*args, ranks=1):
    command = [sys.executable, "-m", "drape.cli", *map(str, args)]
    if ranks > 1:
        command = ["mpirun", "-n", str(ranks), *command]
    return subprocess.run(command, capture_output=True, text=True, cwd=REPO, env=ENV,
                          timeout=900, stdin=subprocess.DEVNULL)


def test_every_help_exits_0_and_documents_options_and_exit_codes():
    from drape.cli import SUBCOMMANDS, build_parser
    top = drape("--help")
    assert top.returncode == 0, top.stderr
    for code, meaning in (("0", "success"), ("2", "bad input"),
                          ("1", "a run that failed after it started")):
        assert re.search(rf"^\s*{code}\s+{meaning}", top.stdout, re.M), (code, top.stdout)
    parser = build_parser()
    subparsers = next(a for a in parser._actions if a.dest == "command").choices
    assert set(subparsers) == set(SUBCOMMANDS) == {"picture-frame", "run", "calibrate",
                                                   "tools", "view"}
    for name in SUBCOMMANDS:
        assert name in top.stdout
        done = drape(name, "--help")
        assert done.returncode == 0, (name, done.stderr)
        text = " ".join(done.stdout.split())
        assert "exit codes: 0 success, 2 bad input, 1 a run that failed" in text, name
        for action in subparsers[name]._actions:
            if action.dest == "help":
                continue
            # every option is explained, and one with a default value says it
            assert action.help and len(action.help) > 15, (name, action.dest)
            shown = action.option_strings[0] if action.option_strings else action.metavar
            assert shown in done.stdout, (name, shown)
            if action.option_strings and action.default not in (None, False, []):
                assert "default" in action.help, (name, action.dest)
    assert drape().returncode == 2                                  # no command: bad input


def steps(folder):
    with (folder / "steps.csv").open() as stream:
        return list(csv.DictReader(stream))


def test_run_progress_plain_lines_off_a_terminal_rank_0_only(bias_extension_short):
    for ranks in (1, 2):
        done, folder = bias_extension_short(ranks)      # the run, shared with test_paraview.py
        assert done.returncode == 0, done.stderr
        lines = [line for line in done.stdout.splitlines() if line.startswith("step ")]
        rows = steps(folder)[1:]                                     # step 0 is the start
        assert len(lines) == len(rows) >= 4 and "\r" not in done.stdout
        for line, row in zip(lines, rows):
            load = float(row["t"])
            assert line.startswith(f"step {row['step']}: load {load:.4g}/1 "), line
            assert f"{row['newton_iterations']} Newton iterations" in line
            assert f"d={float(row['d']):.4g}" in line and "left" in line
        assert done.stdout.rstrip().splitlines()[-1].startswith(f"drape run: {len(rows)} steps")


class Terminal(io.StringIO):
    def isatty(self):
        return True


def test_run_progress_bar_on_a_terminal():
    from types import SimpleNamespace

    from drape.run import step_progress
    from drape.step_record import StepRecord
    job = SimpleNamespace(config=SimpleNamespace(history={"d": None}))
    stream = Terminal()
    progress = step_progress(job, enabled=True, stream=stream)
    progress.on_step(StepRecord(step=1, t=0.25, dt=0.25, newton_iterations=4, cutbacks=0,
                                histories={"d": 3.75}, max_shear_angle_deg=9.5))
    progress.message("step 2: no convergence at t = 0.75, cut back")
    progress.on_step(StepRecord(step=2, t=0.5, dt=0.25, newton_iterations=5, cutbacks=1,
                                histories={"d": 7.5}, max_shear_angle_deg=19.0))
    progress.close()
    text = stream.getvalue()
    assert text.startswith("\r[######..................]  25.0% step 1: load 0.25/1 (+0.25), "
                           "4 Newton iterations")
    assert ("\nstep 2: no convergence at t = 0.75, cut back\n"
            "\r[############............]  50.0%") in text
    assert text.endswith("\n")
    silent = Terminal()
    off = step_progress(job, enabled=False, stream=silent)
    off.on_step(StepRecord(step=1, t=1.0, dt=1.0, newton_iterations=1, cutbacks=0,
                           histories={"d": 1.0}, max_shear_angle_deg=1.0))
    off.close()
    assert silent.getvalue() == ""
