"""Open a results folder of `drape run` in ParaView: the blank warped by its displacement
(scale 1), coloured by the shear angle (deg), the locking angle marked (colour-map range
+-locking angle, cells beyond it dark red / dark blue, black contour lines at +-locking angle),
at the last written load step.

    drape view results/bias_extension                        # the ParaView GUI
    drape view results/bias_extension --screenshot shear.png # a PNG, off screen, then exit

ParaView is Debian's (`apt-get install paraview python3-paraview`, plus `xvfb` for screenshots
on a machine without a display); drape runs its shipped script drape/paraview_view.py with
ParaView's `pvpython` (or `paraview --script=`). Without a display and without a screenshot,
the command to run on a machine with one is printed. A stack's results (a job with
``[[plies]]``) carry a cell field ``ply``; ``--ply N`` shows ply N only. See docs/viewing.md.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import select
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from drape.errors import InputError, RunFailed

HELP = "open a results folder in ParaView (shear-angle map on the deformed blank) or render a PNG"

#: the locking angle marked when neither --locking-angle nor summary.json gives one (deg):
#: a typical shear-locking angle of woven glass and carbon fabrics (35-50 deg); drape's law has
#: no locking angle of its own, so pass your fabric's.
DEFAULT_LOCKING_ANGLE = 40.0
SCRIPT = Path(__file__).with_name("paraview_view.py")
INSTALL_HINT = "apt-get install -y paraview python3-paraview xvfb"


def add_arguments(parser) -> None:
    parser.add_argument("results", metavar="RESULTS",
                        help="a results folder of `drape run` (it must hold fields.xdmf + .h5)")
    parser.add_argument("--locking-angle", type=float, default=None, metavar="DEG",
                        help="shear locking angle marked on the map, degrees, in (0, 90) "
                             "(default: locking_angle_deg of RESULTS/summary.json if there, "
                             f"else {DEFAULT_LOCKING_ANGLE:g})")
    parser.add_argument("--screenshot", default=None, metavar="FILE.png",
                        help="render off screen to this PNG and exit (under an Xvfb of its "
                             "own when there is no display) instead of opening the ParaView GUI")
    parser.add_argument("--size", default="1200x900", metavar="WxH",
                        help="screenshot size in pixels (default 1200x900)")
    parser.add_argument("--time", type=float, default=None, metavar="T",
                        help="load factor t in [0, 1] to show; the nearest written step "
                             "(default: the last written step)")
    parser.add_argument("--ply", type=int, default=None, metavar="N",
                        help="a stack of plies: show ply N only (0 the bottom ply, on the die)")


def locking_angle(results: Path, given: float | None) -> float:
    """--locking-angle, else summary.json's locking_angle_deg, else the default (deg)."""
    if given is not None:
        value, source, key = given, None, "--locking-angle"
    else:
        summary = results / "summary.json"
        if not summary.is_file():
            return DEFAULT_LOCKING_ANGLE
        try:
            data = json.loads(summary.read_text())
        except (OSError, ValueError) as error:
            raise InputError(f"not readable JSON ({error})", source=str(summary),
                             expected="a JSON object, e.g. {\"locking_angle_deg\": 40}") from None
        if not isinstance(data, dict) or "locking_angle_deg" not in data:
            return DEFAULT_LOCKING_ANGLE
        value, source, key = data["locking_angle_deg"], str(summary), "locking_angle_deg"
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            not math.isfinite(value) or not 0 < value < 90:
        raise InputError("not a locking angle", source=source, key=key, value=value,
                         expected="degrees in (0, 90), e.g. 40")
    return float(value)


def check_results(folder: str) -> Path:
    path = Path(folder)
    if not path.is_dir():
        raise InputError("no such results folder", source=str(path),
                         expected="a folder written by `drape run` (holding fields.xdmf)")
    xdmf = path / "fields.xdmf"
    if not xdmf.is_file() or not (path / "fields.h5").is_file():
        raise InputError("no fields.xdmf + fields.h5 in this folder", source=str(path),
                         expected="a folder written by `drape run` with output.xdmf = true")
    head = xdmf.read_text(errors="replace")[:4096]
    if "<Xdmf" not in head:
        raise InputError("fields.xdmf is not an XDMF file", source=str(xdmf),
                         expected="the XDMF file written by `drape run`")
    return path


def check_ply(results: Path, ply: int | None) -> None:
    """--ply N: N >= 0, the results a stack's (fields.xdmf has the cell field "ply") and N
    below summary.json's number of plies when it lists them (ParaView checks it otherwise)."""
    if ply is None:
        return
    if ply < 0:
        raise InputError("not a ply", key="--ply", value=ply,
                         expected="a ply's index, 0 for the bottom ply")
    if 'Name="ply"' not in (results / "fields.xdmf").read_text(errors="replace"):
        raise InputError("no cell field 'ply' in fields.xdmf: not the results of a stack",
                         source=str(results), key="--ply",
                         expected="the results of a job with [[plies]], or no --ply")
    summary = results / "summary.json"
    try:
        plies = json.loads(summary.read_text()).get("plies") if summary.is_file() else None
    except (OSError, ValueError, AttributeError):
        plies = None
    if isinstance(plies, list) and ply >= len(plies):
        raise InputError(f"no ply {ply}: the stack has {len(plies)} plies", key="--ply",
                         value=ply, expected=f"0 to {len(plies) - 1}")


def parse_size(text: str) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        width = height = 0
    if not (16 <= width <= 8192 and 16 <= height <= 8192):
        raise InputError("not an image size", key="--size", value=text,
                         expected="WIDTHxHEIGHT in pixels, each 16 to 8192, e.g. 1200x900")
    return width, height


def script_arguments(args, results: Path, angle: float) -> list[str]:
    extra = [str(results.resolve()), "--locking-angle", repr(angle)]
    if args.time is not None:
        extra += ["--time", repr(args.time)]
    if getattr(args, "ply", None) is not None:
        extra += ["--ply", str(args.ply)]
    return extra


def main(args) -> int:
    results = check_results(args.results)
    angle = locking_angle(results, args.locking_angle)
    check_ply(results, args.ply)
    width, height = parse_size(args.size)
    if args.time is not None and not (math.isfinite(args.time) and 0 <= args.time <= 1):
        raise InputError("not a load factor", key="--time", value=args.time,
                         expected="t in [0, 1]")
    pvpython = shutil.which("pvpython")
    if pvpython is None:
        raise InputError("ParaView is not installed (no pvpython on PATH)",
                         expected=f"Debian's ParaView: `{INSTALL_HINT}` (as root)")
    extra = script_arguments(args, results, angle)
    if args.screenshot:
        return screenshot(args.screenshot, pvpython, extra, width, height)
    return open_gui(args.results, results, angle, extra)


def screenshot(target: str, pvpython: str, extra: list[str], width: int, height: int) -> int:
    """Render the picture off screen with pvpython (under Xvfb without a display) to the
    PNG ``target``; one more attempt if ParaView exits without it."""
    png = Path(target).resolve()
    if png.suffix.lower() != ".png" or not png.parent.is_dir():
        raise InputError("not a PNG path in an existing folder", key="--screenshot",
                         value=target, expected="e.g. results/shear.png")
    command = [pvpython, "--force-offscreen-rendering", str(SCRIPT), *extra,
               "--screenshot", str(png), "--size", f"{width}x{height}"]
    xvfb = None
    if not os.environ.get("DISPLAY"):
        # Debian's ParaView renders through GLX: off screen it still needs an X server
        xvfb = shutil.which("Xvfb")
        if xvfb is None:
            raise InputError("no display and no Xvfb for off-screen rendering",
                             expected=f"`{INSTALL_HINT}` (as root), or a DISPLAY")
    for attempt in (1, 2):
        if png.exists():
            png.unlink()
        with x_server(xvfb, width + 64, height + 64) as display:
            env = dict(os.environ, DISPLAY=display) if display else None
            done = subprocess.run(command, capture_output=True, text=True, env=env,
                                  stdin=subprocess.DEVNULL)
        if done.returncode == 0 and png.is_file():
            break
        if done.returncode == 2:        # the script refused its input (e.g. no such ply)
            lines = (done.stderr or "").strip().splitlines() or ["the script refused its input"]
            raise InputError(lines[-1].replace("paraview_view.py: ", "ParaView: "))
        # should pvpython abort creating its GL context: one more attempt, on a new server
        print(f"drape view: ParaView exited with code {done.returncode} without a picture"
              f"{'; trying once more' if attempt == 1 else ''}", file=sys.stderr)
    else:
        lines = (done.stderr or done.stdout).strip().splitlines()
        why = [line for line in lines if any(word in line for word in
                                             ("ERR", "rror", "annot", "ailed", "Signal"))]
        detail = "; ".join((why or lines)[-4:])
        raise RunFailed(f"ParaView did not write {png} (exit code {done.returncode}): {detail}")
    print(done.stdout.strip().replace("paraview_view.py:", "drape view:"))
    return 0


@contextlib.contextmanager
def x_server(xvfb: str | None, width: int, height: int, timeout: float = 60.0):
    """An Xvfb of its own for one rendering (``xvfb``: its path; None: the DISPLAY there is),
    on a display number it picks itself (``-displayfd``: it binds a free one and writes it
    when ready; xvfb-run -a takes the first number without a lock file, which a server still
    shutting down may hold), with ``-noreset``: an X server resets when its last client
    leaves, and pvpython, which connects more than once, then found no server ("bad X server
    connection", 1 attempt in 3 on a loaded machine). Yields ":N" (or None)."""
    if xvfb is None:
        yield None
        return
    read, write = os.pipe()
    server = subprocess.Popen([xvfb, "-displayfd", str(write), "-screen", "0",
                               f"{width}x{height}x24", "-nolisten", "tcp", "-noreset"],
                              pass_fds=(write,),
                              stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    os.close(write)
    try:
        number = b""
        ready, _, _ = select.select([read], [], [], timeout)
        while ready and not number.endswith(b"\n"):
            chunk = os.read(read, 16)
            if not chunk:
                break
            number += chunk
        if not number.strip().isdigit():
            raise RunFailed(f"Xvfb did not start within {timeout:g} s (exit code "
                            f"{server.poll()}); try `{xvfb} -displayfd 1` to see why")
        yield f":{int(number)}"
    finally:
        os.close(read)
        server.terminate()
        try:
            server.wait(timeout=10)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()


def open_gui(given: str, results: Path, angle: float, extra: list[str]) -> int:
    """Open the ParaView GUI on the results (``given``: the folder as the user typed it); with
    no display or no GUI, print the command to run on a machine that has them."""
    paraview = shutil.which("paraview")
    wrapper = ("import sys\n"
               f"sys.argv = {[str(SCRIPT), *extra]!r}\n"
               f"exec(compile(open({str(SCRIPT)!r}).read(), {str(SCRIPT)!r}, 'exec'))\n")
    if paraview is None or not os.environ.get("DISPLAY"):
        reason = "no display (DISPLAY is not set)" if paraview else "no paraview GUI on PATH"
        print(f"drape view: {reason}. On a machine with a display, run\n"
              f"  paraview --script=WRAPPER.py\n"
              f"with WRAPPER.py holding these three lines:\n{wrapper}"
              f"or render a picture here with\n"
              f"  drape view {given} --screenshot shear.png")
        return 0
    with tempfile.NamedTemporaryFile("w", suffix="_drape_view.py", delete=False) as stream:
        stream.write(wrapper)
    print(f"drape view: opening {results} in ParaView (locking angle {angle:g} deg)")
    try:
        code = subprocess.call([paraview, f"--script={stream.name}"])
    finally:
        os.unlink(stream.name)
    if code != 0:
        raise RunFailed(f"paraview exited with code {code}")
    return 0


if __name__ == "__main__":   # pragma: no cover
    sys.exit("run as: drape view RESULTS")
