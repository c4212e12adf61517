"""The progress display: plain lines off a terminal, a redrawn bar on one, silence when quiet."""

import io

from drape.progress import Progress, _duration


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
    progress.step(3, 0.25, 4, 0.05)
    clock.now += 30.0
    progress.step(4, 0.5, 2, 0.1, note="cutback once")
    lines = stream.getvalue().splitlines()
    assert lines == [
        "step 3: load 0.25/1 (+0.05), 4 Newton iterations, 30s elapsed, ~1m30s left",
        "step 4: load 0.5/1 (+0.1), 2 Newton iterations, 1m00s elapsed, ~1m00s left, cutback once",
    ]


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
