"""The progress display: plain lines off a terminal, a redrawn bar on one, silence when quiet."""

import io

import pytest

from drape.io.progress import Progress, _duration

# no MPI in these tests: under mpirun each rank would do the same (tests/conftest.py)
pytestmark = pytest.mark.serial


class FakeClock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


class Terminal(io.StringIO):
    def isatty(self):
        return True


def test_plain_lines_with_time_left_when_not_a_terminal():
    clock, stream = FakeClock(), io.StringIO()
    progress = Progress(total=1.0, stream=stream, clock=clock)
    clock.now += 30.0
    progress.step(1, 0.25, 4, 0.25)
    clock.now += 30.0
    progress.step(2, 0.5, 2, 0.25, note="cutback once")
    lines = stream.getvalue().splitlines()
    assert lines == [
        "step 1: load 0.25/1 (+0.25), 4 Newton iterations, 30s elapsed, ~1m30s left",
        "step 2: load 0.5/1 (+0.25), 2 Newton iterations, 1m00s elapsed, ~1m00s left, cutback once",
    ]


def steps_at(clock, progress, seconds_and_loads):
    """Converge steps after the given seconds at the given loads; the estimates shown."""
    left = []
    previous = progress.history[-1][1] if progress.history else 0.0
    for seconds, load in seconds_and_loads:
        clock.now += seconds
        progress.step(len(left) + 1, load, 5, load - previous)
        previous = load
        left.append(progress.time_left())
    return left


def test_time_left_follows_the_recent_steps_when_the_run_slows_down():
    # four steps of 0.2 in 10 s each, then two of 0.05 in 30 s each (the shear locking)
    clock, stream = FakeClock(), io.StringIO()
    progress = Progress(total=1.0, stream=stream, clock=clock, recent_steps=3)
    left = steps_at(clock, progress, [(10, 0.2), (10, 0.4), (10, 0.6), (10, 0.8), (30, 0.85),
                                      (30, 0.9)])
    # at 0.85: the average pace is 70 s / 0.85, the last three steps' 50 s / 0.45 (from 0.4)
    assert left[4] == pytest.approx(max(70 / 0.85, 50 / 0.45) * 0.15) == pytest.approx(50 / 3)
    # at 0.9: 100 s / 0.9 against 70 s / 0.3 (from 0.6): 23.3 s, where the average says 11.1 s
    assert left[5] == pytest.approx(70 / 0.3 * 0.1)
    assert "~17s left" in stream.getvalue().splitlines()[4]
    assert "~23s left" in stream.getvalue().splitlines()[5]
    # while the pace is steady both paces agree: 10 s per 0.2
    assert left[:4] == pytest.approx([40.0, 30.0, 20.0, 10.0])


def test_time_left_keeps_the_average_when_the_run_speeds_up():
    # a slow first step (the blank settling), then quick ones: the average governs
    clock, stream = FakeClock(), io.StringIO()
    progress = Progress(total=1.0, stream=stream, clock=clock, recent_steps=3)
    left = steps_at(clock, progress, [(50, 0.1), (5, 0.2), (5, 0.3), (4, 0.4)])
    assert left[3] == pytest.approx(64 / 0.4 * 0.6)           # the recent pace: 14 s / 0.3
    assert "~1m36s left" in stream.getvalue().splitlines()[3]


def test_time_left_of_a_resumed_run_counts_from_where_it_resumed():
    # resumed at 0.5: the first step of 0.01 took 2 s, so 0.49 still to go takes 98 s
    # (counting from 0, as if the first half had been done in those 2 s, it said "~2s left")
    clock, stream = FakeClock(), io.StringIO()
    progress = Progress(total=1.0, stream=stream, clock=clock)
    clock.now += 2.0
    progress.step(51, 0.51, 3, 0.01)
    assert progress.history[0] == (100.0, pytest.approx(0.5))
    assert progress.time_left() == pytest.approx(98.0)
    assert stream.getvalue().endswith("~1m38s left\n")
    clock.now += 2.0
    progress.step(52, 1.0, 3, 0.49)                            # done: nothing left
    assert progress.time_left() == 0.0 and stream.getvalue().endswith("~0s left\n")


def test_terminal_bar_is_redrawn_and_messages_get_their_own_line():
    clock, stream = FakeClock(), Terminal()
    progress = Progress(total=2.0, stream=stream, clock=clock, width=10)
    clock.now += 10.0
    progress.step(1, 1.0, 3, 0.5)
    progress.message("step 2 cut back to 0.25")
    progress.step(2, 1.5, 3, 0.25)
    progress.close()
    text = stream.getvalue()
    assert text.startswith("\r[#####.....]  50.0% step 1: load 1/2 (+0.5)")
    assert "\nstep 2 cut back to 0.25\n\r[########..]  75.0% step 2" in text
    assert text.endswith("\n") and text.count("\n") == 3   # before, after the message; at close


def test_quiet_writes_nothing():
    stream = Terminal()
    progress = Progress(stream=stream, enabled=False)
    progress.step(1, 0.5, 2, 0.5)
    progress.message("x")
    progress.close()
    assert stream.getvalue() == ""


def test_durations():
    assert [_duration(s) for s in (0.4, 59, 61, 3599, 3600 * 2 + 65, float("inf"))] == \
        ["0s", "59s", "1m01s", "59m59s", "2h01m", "?"]


def test_run_log_keeps_lines_until_open_then_writes_each_at_once(tmp_path):
    """drape.io.run_log.RunLog: lines before open() are kept and follow the dated header; after
    it each write is in the file at once (a kill loses nothing written); close() adds the last
    line; append=True (a resume) adds to the file; a disabled log (ranks > 0) writes nothing;
    a log that cannot be opened is given up without an error."""
    import re

    from drape.io.progress import Progress
    from drape.io.run_log import LOG_FILE, RunLog
    log = RunLog(tmp_path, append=False)
    progress = Progress(1.0, stream=log)
    assert not progress.interactive                 # plain lines, never a redrawn bar
    progress.message("drape run: before the folder is claimed")
    assert not (tmp_path / LOG_FILE).exists()
    log.open("drape run job.toml")
    progress.step(1, 0.5, 3, 0.5)
    lines = (tmp_path / LOG_FILE).read_text().splitlines()   # before close: already there
    assert re.fullmatch(r"# \d{4}-\d\d-\d\d \d\d:\d\d:\d\d UTC: drape run job\.toml", lines[0])
    assert lines[1] == "drape run: before the folder is claimed"
    assert lines[2].startswith("step 1: load 0.5/1 (+0.5), 3 Newton iterations")
    log.close("drape run: stopped: SIGTERM received")
    again = RunLog(tmp_path, append=True)
    again.open("drape run job.toml --resume")
    again.close("drape run: 2 steps to t = 1")
    lines = (tmp_path / LOG_FILE).read_text().splitlines()
    assert len(lines) == 6 and lines[3] == "drape run: stopped: SIGTERM received"
    assert lines[4].endswith("drape run job.toml --resume")
    assert lines[5] == "drape run: 2 steps to t = 1"
    fresh = RunLog(tmp_path, append=False)
    fresh.open("new")
    fresh.close()
    assert len((tmp_path / LOG_FILE).read_text().splitlines()) == 1
    quiet = RunLog(tmp_path / "other", append=False, enabled=False)
    quiet.open("x")
    quiet.close("y")
    assert not (tmp_path / "other").exists()
    broken = RunLog(tmp_path / "missing" / "folder", append=False)
    broken.write("kept\n")
    broken.open("cannot be written")                # no such folder: given up, no error
    broken.write("more\n")
    broken.close("last")
    assert not broken.enabled and not (tmp_path / "missing").exists()


def test_failures_are_reported_in_one_line_with_their_kind():
    """drape.errors.one_line: the line on stderr and at the end of run.log."""
    from drape.errors import InputError, Interrupted, RunFailed, WriteFailed, one_line
    assert one_line("run", InputError("bad", key="mesh.size", value=-1, expected="> 0")) \
        .startswith("drape run: error: ")
    assert one_line("run", Interrupted("SIGTERM received")) == \
        "drape run: stopped: SIGTERM received"
    assert one_line("run", RunFailed("step 3: Newton")) == "drape run: run failed: step 3: Newton"
    assert one_line("calibrate", WriteFailed("no space")) == \
        "drape calibrate: run failed: no space"
