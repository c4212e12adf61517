"""The table of bad inputs: every case in one list (:data:`CASES`), each run through the real
``drape`` command line; ``docs/bad-inputs.md`` is generated from it.

A case writes its files into an empty folder, runs ``drape ARGS...`` there (relative paths, so
the messages are the same on every machine) and expects exit code 2 with one message naming
the file (or command-line option), the key, the value and what was expected. Adding a row is
adding one :class:`Case` to :data:`CASES`, then::

    .venv/bin/python tests/bad_inputs.py --write-docs      # regenerate docs/bad-inputs.md

This file is also the runner the tests start (one process runs many cases: each ``drape run``
start imports DOLFINx, seconds)::

    python tests/bad_inputs.py ROOT RESULTS.json [CASE_ID ...]       (under mpirun too)

runs the cases (all by default) in ROOT/<case id>/ through :func:`drape.cli.main`, exactly what
the ``drape`` script calls, and writes per case the exit code, stderr and the files left
behind to RESULTS.json (RESULTS.rank<r>.json on rank r > 0 under mpirun). The case being run is
written to RESULTS.progress first, so that a hang names its case.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import os
import sys
import traceback
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
CONFIGS = REPO / "configs"
DOC = REPO / "docs" / "bad-inputs.md"
#: seconds the tests give one bundled run of every case (a few seconds normally): longer is a hang
RUNNER_TIMEOUT = 600


@dataclasses.dataclass(frozen=True)
class Case:
    """One bad input. ``source`` (a file, or the command-line option), ``key``, ``value`` and
    ``expected`` are fragments the message must contain (None: not part of this message, e.g.
    a missing file has no key); ``also`` more fragments (a "did you mean" hint)."""

    id: str
    input: str                      # the bad input in words (docs table)
    args: tuple[str, ...]           # drape's command line
    files: dict[str, str]           # file name -> text, written before the run
    source: str | None
    key: str | None
    value: str | None
    expected: str
    also: tuple[str, ...] = ()

    def fragments(self) -> list[str]:
        parts = [self.source, None if self.key is None else f"key '{self.key}'", self.value,
                 f"expected {self.expected}", *self.also]
        return [p for p in parts if p is not None]


# --- the inputs the cases start from ---------------------------------------------------------

MATERIAL = (CONFIGS / "materials" / "paper_three_surface.toml").read_text()
HEMISPHERE = (CONFIGS / "tools" / "hemisphere.toml").read_text()

#: a small valid job (the bias-extension test); cases edit it
JOB = """\
title = "bias extension"
material = "material.toml"

[blank]
shape = "rectangle"
length = 100.0
width = 50.0
yarn_angle = 45.0

[mesh]
size = 10.0

[steps]
initial = 0.05
maximum = 0.1

[history.d]
values = [0.0, 15.0]

[[boundary]]
on = "left"
ux = "0"
uy = "0"
uz = "0"

[[boundary]]
on = "right"
ux = "d"
uy = "0"
uz = "0"
"""

#: a measured picture-frame curve for calibrate (a cycle to 10 deg and back)
CURVE = "gamma_t_deg,tau\n" + "".join(f"{a:g},{0.001 * a:g}\n" for a in
                                        list(range(0, 11)) + list(range(9, -1, -1)))
#: published picture-frame curves (a series column, monotonic), as in data/cao2008
SERIES = "series,shear_angle_deg,shear_force_N\n" + "".join(
    f"{lab},{a},{0.1 * a:g}\n" for lab in ("HKUST", "UN") for a in range(0, 40))


def edit(text: str, old: str, new: str) -> str:
    """``text`` with ``old`` (which must be there) replaced by ``new``."""
    assert old in text, f"{old!r} not in the base text"
    return text.replace(old, new, 1)


def job(text: str = JOB, **files: str) -> dict[str, str]:
    """The files of a ``drape run`` case: job.toml, its material, and any others."""
    out = {"job.toml": text, "material.toml": MATERIAL}
    out.update({name.replace("__", "/").replace("_toml", ".toml"): t for name, t in files.items()})
    return out


def material(old: str, new: str) -> dict[str, str]:
    """The files of a case whose material file (material.toml) is edited."""
    return {"job.toml": JOB, "material.toml": edit(MATERIAL, old, new)}


def tools(old: str | None = None, new: str = "", text: str | None = None,
          **extra) -> dict[str, str]:
    out = {"tools.toml": text if text is not None else edit(HEMISPHERE, old, new)}
    out.update(extra)
    return out


RUN = ("run", "job.toml", "--quiet")

#: a small valid forming job (the hemisphere); forming cases edit it
FORMING = """\
title = "hemisphere"
material = "material.toml"

[blank]
shape = "rectangle"
length = 200.0
width = 200.0

[mesh]
size = 3.9

[process]
stroke = 10.0
holder_force = 200.0

[tools]
kind = "hemisphere"
"""


# --- the cases --------------------------------------------------------------------------------

CASES: list[Case] = [
    # drape run: the job file
    Case("run-missing-config", "a job file that does not exist", ("run", "nope.toml"), {},
         "nope.toml", None, None, "the path of an existing TOML file", ("file not found",)),
    Case("run-not-toml", "job.toml is not TOML (`mesh.size: 10`)", RUN,
         job(edit(JOB, "size = 10.0", "size: 10")), "job.toml", None, None, "TOML syntax",
         ("not valid TOML",)),
    Case("run-not-text", "job.toml is a binary file", RUN, {"job.toml": "\x00\x81\x82\xff"},
         "job.toml", None, None, "a UTF-8 TOML file"),
    Case("run-unknown-key", "`[blank] colour = \"red\"`: no such key", RUN,
         job(edit(JOB, "[blank]\n", "[blank]\ncolour = \"red\"\n")), "job.toml", "blank.colour",
         None, "one of the known keys", ("known keys here: shape, length",)),
    Case("run-misspelt-key", "`[mesh] sise = 5` (misspelt size): the closest key is suggested",
         RUN, job(edit(JOB, "size = 10.0", "sise = 5.0")), "job.toml", "mesh.sise", None,
         "one of the known keys", ("did you mean 'size'?",)),
    Case("run-misspelt-table", "`[mesch]` (misspelt table mesh)", RUN,
         job(edit(JOB, "[mesh]", "[mesch]")), "job.toml", "mesch", None,
         "one of the known keys", ("did you mean 'mesh'?",)),
    Case("run-wrong-type", "`[blank] length = \"100\"` (a string)", RUN,
         job(edit(JOB, "length = 100.0", "length = \"100\"")), "job.toml", "blank.length",
         "'100'", "a number", ("wrong type",)),
    Case("run-table-wrong-type", "`steps = 3` (a number where a table goes)", RUN,
         job(edit(JOB, "[steps]\ninitial = 0.05\nmaximum = 0.1\n", "").replace(
             'title = "bias extension"', 'title = "bias extension"\nsteps = 3')),
         "job.toml", "steps", "3", "a table"),
    Case("run-negative-size", "`[blank] width = -50` (a negative size)", RUN,
         job(edit(JOB, "width = 50.0", "width = -50.0")), "job.toml", "blank.width", "-50.0",
         "a number > 0"),
    Case("run-zero-mesh-size", "`[mesh] size = 0`", RUN, job(edit(JOB, "size = 10.0", "size = 0")),
         "job.toml", "mesh.size", "0", "a number > 0"),
    Case("run-negative-mesh-size", "`[mesh] size = -10`", RUN,
         job(edit(JOB, "size = 10.0", "size = -10.0")), "job.toml", "mesh.size", "-10.0",
         "a number > 0"),
    Case("run-mesh-too-coarse", "`[mesh] size = 20` on a 100 x 50 mm blank: 2.5 elements across",
         RUN, job(edit(JOB, "size = 10.0", "size = 20.0")), "job.toml", "mesh.size", "20.0",
         "at least 3 elements across the blank", ("too coarse",)),
    Case("run-mesh-too-fine", "`[mesh] size = 0.01`: some 50 million elements", RUN,
         job(edit(JOB, "size = 10.0", "size = 0.01")), "job.toml", "mesh.size", "0.01",
         "a size giving at most 4e+06 elements"),
    Case("forming-stroke-too-large", "`[process] stroke = 80` with hemisphere tools that "
         "allow 50 mm", RUN, job(edit(FORMING, "stroke = 10.0", "stroke = 80.0")), "job.toml",
         "process.stroke", "80.0", "<= 50 mm, the full stroke of these hemisphere tools",
         ("larger than the tools allow",)),
    Case("forming-mesh-too-coarse-for-tools", "`[mesh] size = 8` against the die's 5 mm entry "
         "fillet", RUN, job(edit(FORMING, "size = 3.9", "size = 8.0")), "job.toml", "mesh.size",
         "8.0", "<= 3.93 mm", ("too coarse for the tools",)),
    Case("forming-blank-beyond-die", "`[blank] length = width = 250`: corners beyond the "
         "150 mm die", RUN, job(edit(edit(FORMING, "length = 200.0", "length = 250.0"),
                                    "width = 200.0", "width = 250.0")),
         "job.toml", "blank.length", None, "a blank within r = 150 mm",
         ("reaches beyond the die",)),
    Case("forming-negative-holder-force", "`[process] holder_force = -5`", RUN,
         job(edit(FORMING, "holder_force = 200.0", "holder_force = -5.0")), "job.toml",
         "process.holder_force", "-5.0", "a number >= 0"),
    Case("forming-unknown-tool-kind", "`[tools] kind = \"cone\"`", RUN,
         job(edit(FORMING, 'kind = "hemisphere"', 'kind = "cone"')), "job.toml", "tools.kind",
         "'cone'", "one of 'hemisphere', 'double_dome', 'step'"),
    Case("run-yarn-angle-range", "`[blank] yarn_angle = 135` (accepted: -90 to 90)", RUN,
         job(edit(JOB, "yarn_angle = 45.0", "yarn_angle = 135.0")), "job.toml",
         "blank.yarn_angle", "135.0", "a number in [-90.0, 90.0]"),
    Case("run-yarn-angle-not-aligned", "`yarn_angle = 30` with the default aligned mesh", RUN,
         job(edit(JOB, "yarn_angle = 45.0", "yarn_angle = 30.0")), "job.toml",
         "blank.yarn_angle", "30.0", "0, 90, 45 or -45, or mesh.pattern = \"free\""),
    Case("run-lattice-misfit", "a +-45 deg blank of 141 x 50 mm: gmsh is given no mesh to build",
         RUN, job(edit(JOB, "length = 100.0", "length = 141.0")), "job.toml", "blank.length",
         "141.0", "length/width = i/j with small integers"),
    Case("run-nan", "`[steps] initial = nan`", RUN,
         job(edit(JOB, "initial = 0.05", "initial = nan")),
         "job.toml", "steps.initial", "nan", "a finite number"),
    Case("run-huge", "`[blank] length = 1e300` (and width)", RUN,
         job(edit(edit(JOB, "length = 100.0", "length = 1e300"), "width = 50.0", "width = 5e299")),
         "job.toml", "mesh.size", "10.0", "a size giving at most 4e+06 elements"),
    Case("run-steps-order", "`[steps] minimum = 0.5` > maximum = 0.1", RUN,
         job(edit(JOB, "maximum = 0.1", "maximum = 0.1\nminimum = 0.5")), "job.toml",
         "steps.minimum", "0.5", "minimum <= maximum = 0.1"),
    Case("run-steps-initial", "`[steps] initial = 0.5` > maximum = 0.1", RUN,
         job(edit(JOB, "initial = 0.05", "initial = 0.5")), "job.toml", "steps.initial", "0.5",
         "minimum = 1e-06 <= initial <= maximum = 0.1"),
    Case("run-cutback", "`[steps] cutback = 1.5`", RUN,
         job(edit(JOB, "maximum = 0.1", "maximum = 0.1\ncutback = 1.5")), "job.toml",
         "steps.cutback", "1.5", "a number in (0.0, 1.0)"),
    Case("run-bad-choice", "`[mesh] cell = \"hexahedron\"`", RUN,
         job(edit(JOB, "size = 10.0", "size = 10.0\ncell = \"hexahedron\"")), "job.toml",
         "mesh.cell", "'hexahedron'", "one of 'quadrilateral', 'triangle'"),
    Case("run-history-t", "`[history.d] t = [0, 0.6, 0.4, 1]`: not increasing", RUN,
         job(edit(JOB, "values = [0.0, 15.0]",
                  "values = [0.0, 5.0, 10.0, 15.0]\nt = [0, 0.6, 0.4, 1]")),
         "job.toml", "history.d.t", "[0.0, 0.6, 0.4, 1.0]", "[0, ..., 1], strictly increasing"),
    Case("run-history-length", "`[history.d] t` with 3 entries for 2 values", RUN,
         job(edit(JOB, "values = [0.0, 15.0]", "values = [0.0, 15.0]\nt = [0, 0.5, 1]")),
         "job.toml", "history.d.t", "[0.0, 0.5, 1.0]", "one load factor per value"),
    Case("run-formula-syntax", "`ux = \"d *\"`: does not parse", RUN,
         job(edit(JOB, 'ux = "d"', 'ux = "d *"')),
         "job.toml", "boundary[1].ux", "'d *'", "a numpy expression in d, t, theta, x, y",
         ("not an expression",)),
    Case("run-formula-forbidden", "`ux = \"__import__('os')\"`: a forbidden name", RUN,
         job(edit(JOB, 'ux = "d"', "ux = \"__import__('os')\"")), "job.toml", "boundary[1].ux",
         "\"__import__('os')\"", "a numpy expression in d, t, theta, x, y",
         ("unknown function '__import__'",)),
    Case("run-formula-attribute", "`ux = \"d.real\"`: attribute access", RUN,
         job(edit(JOB, 'ux = "d"', 'ux = "d.real"')), "job.toml", "boundary[1].ux", "'d.real'",
         "a numpy expression", ("'d.real' is not allowed",)),
    Case("run-formula-unknown-name", "`ux = \"2 * dd\"`: no such name", RUN,
         job(edit(JOB, 'ux = "d"', 'ux = "2 * dd"')), "job.toml", "boundary[1].ux", "'2 * dd'",
         "a numpy expression in d, t, theta, x, y", ("unknown name 'dd'",)),
    Case("run-formula-not-finite", "`ux = \"d / 0\"`: infinite", RUN,
         job(edit(JOB, 'ux = "d"', 'ux = "d / 0"')), "job.toml", "boundary[1].ux", "'d / 0'",
         "a formula giving a finite displacement in mm"),
    Case("run-unknown-boundary", "`on = \"middle\"`: not a boundary of a rectangle", RUN,
         job(edit(JOB, 'on = "right"', 'on = "middle"')), "job.toml", "boundary[1].on",
         "'middle'", "one of left, right, bottom, top, boundary"),
    Case("run-no-boundary", "no `[[boundary]]` table", RUN, job(JOB[:JOB.index("[[boundary]]")]),
         "job.toml", "boundary", None, "at least one [[boundary]] table"),
    Case("run-history-name", "`[history.t]`: a history named like the load factor", RUN,
         job(edit(JOB, "[history.d]", "[history.t]")), "job.toml", "history.t", "'t'",
         "an identifier other than"),
    Case("run-picture-frame-angle", "`[picture_frame] angle = \"phi\"`: no such history", RUN,
         job(JOB + "\n[picture_frame]\nangle = \"phi\"\n"), "job.toml", "picture_frame.angle",
         "'phi'", "one of the names under [history]: d"),
    Case("run-bias-extension-history", "`[bias_extension] displacement = \"u\"`: no such history",
         RUN, job(JOB + "\n[bias_extension]\ndisplacement = \"u\"\n"), "job.toml",
         "bias_extension.displacement", "'u'", "one of the names under [history]: d"),
    Case("run-picture-frame-square", "`[picture_frame]` on a 100 x 50 mm blank", RUN,
         job(JOB + "\n[picture_frame]\nangle = \"d\"\n"), "job.toml", "picture_frame", None,
         "blank.shape = \"rectangle\" with length = width"),
    Case("run-petsc-name", "`[solver.petsc] \"-snes_monitor\" = \"\"`", RUN,
         job(JOB + "\n[solver.petsc]\n\"-snes_monitor\" = \"\"\n"), "job.toml",
         "solver.petsc.-snes_monitor", "'-snes_monitor'", "a name without the leading '-'"),
    Case("run-surfaces", "`surfaces = 5` for a material with 2 inner surfaces", RUN,
         job(edit(JOB, 'material = "material.toml"', 'material = "material.toml"\nsurfaces = 5')),
         "job.toml", "surfaces", "5", "an integer from 0 to 2"),
    # drape run: the material file
    Case("run-missing-material", "`material = \"materials/nope.toml\"`: no such file", RUN,
         job(edit(JOB, 'material = "material.toml"', 'material = "materials/nope.toml"')),
         "job.toml", "material", "'materials/nope.toml'", "a TOML file relative to"),
    Case("material-not-nested", "material: `Sy = [0.0081, 0.009, 0.0025]`: surfaces not nested",
         RUN, material("Sy = [0.0081, 0.006, 0.0025]", "Sy = [0.0081, 0.009, 0.0025]"),
         "material.toml", "Sy", "[0.0081, 0.009, 0.0025]", "Sy_0 > Sy_1 > ... > Sy_n > 0"),
    Case("material-rows", "material: `[surfaces] a` with 4 rows for 5 ranges", RUN,
         material("a = [[0.9, 0.85], [0.9, 0.75], [0.9, 0.6], [0.9, 0.5], [0.99, 0.45]]",
                  "a = [[0.9, 0.85], [0.9, 0.75], [0.9, 0.6], [0.9, 0.5]]"),
         "material.toml", "surfaces.a", "[[0.9, 0.85], [0.9, 0.75], [0.9, 0.6], [0.9, 0.5]]",
         "one row per range (5 rows)"),
    Case("material-row-length", "material: a row of `[surfaces] h` with 3 numbers", RUN,
         material("[4.0, 10.0]]", "[4.0, 10.0, 12.0]]"), "material.toml", "surfaces.h", None,
         "the same number n of inner surfaces in every row"),
    Case("material-columns", "material: `Sy` with 4 surfaces, Table 2 with 2 inner ones", RUN,
         material("Sy = [0.0081, 0.006, 0.0025]", "Sy = [0.0081, 0.006, 0.0025, 0.001]"),
         "material.toml", "surfaces.a", None, "3 columns in a and h"),
    Case("material-wrong-type", "material: `K1 = \"stiff\"`", RUN,
         material("K1 = 10000.0", "K1 = \"stiff\""), "material.toml", "K1", "'stiff'", "a number"),
    Case("material-negative", "material: `Ksh = -142`", RUN,
         material("Ksh = 142.0", "Ksh = -142.0"),
         "material.toml", "Ksh", "-142.0", "a number > 0"),
    Case("material-misspelt", "material: `K_sh = 142` (misspelt Ksh)", RUN,
         material("Ksh = 142.0", "K_sh = 142.0"), "material.toml", "K_sh", None,
         "one of the known keys", ("did you mean 'Ksh'?",)),
    Case("material-not-toml", "material.toml is not TOML", RUN,
         {"job.toml": JOB, "material.toml": "K1 = = 3\n"}, "material.toml", None, None,
         "TOML syntax", ("not valid TOML",)),
    # drape run: the command line
    Case("run-set-syntax", "`--set mesh.size` (no value)", RUN + ("--set", "mesh.size"),
         job(), "--set", None, "'mesh.size'", "TABLE.KEY=VALUE"),
    Case("run-set-unknown", "`--set mesh.sise=5` (misspelt key)", RUN + ("--set", "mesh.sise=5"),
         job(), "job.toml", "mesh.sise", None, "one of the known keys", ("did you mean 'size'?",)),
    Case("run-set-type", "`--set mesh.size=fine` (a word where a number goes)",
         RUN + ("--set", "mesh.size=fine"), job(), "job.toml", "mesh.size", "'fine'", "a number"),
    Case("run-set-not-table", "`--set title.size=3` (title is not a table)",
         RUN + ("--set", "title.size=3"), job(), "--set", None, "'title.size=3'",
         "'title' to be a table of the job"),
    Case("run-petsc-option", "`--petsc-option \"snes type=newtonls\"` (a space in the name)",
         RUN + ("--petsc-option", "snes type=newtonls"), job(), "--petsc-option", None,
         "'snes type=newtonls'", "NAME or NAME=VALUE"),
    # drape tools: tool configs
    Case("tools-missing", "a tool config that does not exist", ("tools", "nope.toml", "--check"),
         {}, "nope.toml", None, None, "the path of an existing TOML file"),
    Case("tools-no-table", "a file without a `[tools]` table (`[tool]`)",
         ("tools", "tools.toml", "--check"),
         tools(text=HEMISPHERE.replace("[tools", "[tool")),
         "tools.toml", "tools", None, "a [tools] table", ("did you mean 'tool'?",)),
    Case("tools-misspelt", "`punch_radus = 50` (misspelt punch_radius)",
         ("tools", "tools.toml", "--check"),
         tools("punch_radius =", "punch_radus ="), "tools.toml", "tools.hemisphere.punch_radus",
         None, "one of the known keys", ("did you mean 'punch_radius'?",)),
    Case("tools-kind", "`kind = \"cone\"`", ("tools", "tools.toml", "--check"),
         tools('kind = "hemisphere"', 'kind = "cone"'), "tools.toml", "tools.kind", "'cone'",
         "one of 'hemisphere', 'double_dome', 'step'"),
    Case("tools-not-nested", "die opening 50 mm < punch radius 50 + clearance 1",
         ("tools", "tools.toml", "--check"),
         tools("die_opening_radius = 55.0", "die_opening_radius = 50.0"), "tools.toml",
         "tools.hemisphere.die_opening_radius", "50.0", ">= punch_radius + clearance = 51 mm"),
    Case("tools-negative", "`clearance = -1`", ("tools", "tools.toml", "--check"),
         tools("clearance = 1.0", "clearance = -1.0"), "tools.toml", "tools.hemisphere.clearance",
         "-1.0", "a number >= 0"),
    Case("tools-mesh-sizes", "`[tools.mesh] min_size = 20` > max_size = 10",
         ("tools", "tools.toml", "--check"), tools("min_size = 0.2", "min_size = 20.0"),
         "tools.toml", "tools.mesh.min_size", "20.0", "a size <= max_size = 10.0"),
    Case("tools-missing-step", "`[tools.step.punch] file = \"punch.step\"`: no such file",
         ("tools", "tools.toml", "--check"),
         tools(text='[tools]\nkind = "step"\n[tools.step.punch]\nfile = "punch.step"\n'),
         "tools.toml", "tools.step.punch.file", "'punch.step'", "the path of an existing STEP file",
         ("file not found",)),
    Case("tools-not-step", "`punch.step` is a text file, not STEP",
         ("tools", "tools.toml", "--check"),
         tools(text='[tools]\nkind = "step"\n[tools.step.punch]\nfile = "punch.step"\n',
               **{"punch.step": "solid punch\nendsolid punch\n"}),
         "tools.toml", "tools.step.punch.file", "'punch.step'",
         "a STEP file with at least one surface"),
    Case("tools-step-none", "`kind = \"step\"` with no STEP file",
         ("tools", "tools.toml", "--check"),
         tools(text='[tools]\nkind = "step"\n'), "tools.toml", "tools.step", None,
         "a [tools.step.punch] (or .die, .holder) table with file"),
    Case("tools-holder-control", "`[tools.step.holder] control = \"pressure\"`",
         ("tools", "tools.toml", "--check"),
         tools(text='[tools]\nkind = "step"\n[tools.step.holder]\nfile = "holder.step"\n'
                    'control = "pressure"\n'),
         "tools.toml", "tools.step.holder.control", "'pressure'", "one of 'force', 'position'"),
    Case("tools-output", "`--output tools.stl` (an unknown format)",
         ("tools", "tools.toml", "--output", "tools.stl"), tools(text=HEMISPHERE), "--output", None,
         "'tools.stl'", "a path ending in .vtu or .msh"),
    # drape picture-frame
    Case("pf-cycles", "`--cycles 10,abc`", ("picture-frame", "--cycles", "10,abc"), {},
         "--cycles", None, "'10,abc'", "comma-separated amplitudes in degrees"),
    Case("pf-cycles-range", "`--cycles 10,95`: beyond 90 deg",
         ("picture-frame", "--cycles", "10,95"),
         {}, "--cycles", None, "'10,95'", "e.g. 10,20,30,40,-40", ("within (-90, 90) deg",)),
    Case("pf-increment", "`--increment=-0.1`", ("picture-frame", "--increment=-0.1"), {},
         "--increment", None, "-0.1", "a shear-angle increment > 0 in degrees"),
    Case("pf-missing-material", "`--material nope.toml`",
         ("picture-frame", "--material", "nope.toml"),
         {}, "nope.toml", None, None, "the path of an existing TOML file", ("file not found",)),
    Case("pf-material-not-nested", "`--material` a file with non-nested surfaces",
         ("picture-frame", "--material", "material.toml"),
         {"material.toml": edit(MATERIAL, "Sy = [0.0081, 0.006, 0.0025]",
                                "Sy = [0.0081, 0.0081, 0.0025]")},
         "material.toml", "Sy", "[0.0081, 0.0081, 0.0025]", "Sy_0 > Sy_1 > ... > Sy_n > 0"),
    Case("pf-surfaces", "`--surfaces 3` for a material with 2 inner surfaces",
         ("picture-frame", "--surfaces", "3"), {}, "--surfaces", None, "3",
         "an integer from 0 to 2"),
    Case("pf-history", "`--history angles.csv` without a gamma_t_deg column",
         ("picture-frame", "--history", "angles.csv"), {"angles.csv": "angle\n1\n2\n"},
         "angles.csv", None, "['angle']", "a header line naming the column gamma_t_deg"),
    # drape calibrate
    Case("cal-missing", "a measured curve that does not exist", ("calibrate", "nope.csv"), {},
         "nope.csv", None, None, "a CSV file", ("file not found",)),
    Case("cal-no-column", "a CSV without a tau column", ("calibrate", "curve.csv"),
         {"curve.csv": CURVE.replace("tau", "stress")}, "curve.csv", None,
         "['gamma_t_deg', 'stress']",
         "a CSV file with a header line naming gamma_t_deg and tau", ("no 'tau' column",)),
    Case("cal-not-number", "a CSV with `abc` in the tau column", ("calibrate", "curve.csv"),
         {"curve.csv": CURVE.replace("\n5,0.005\n", "\n5,abc\n")}, "curve.csv", None, "'abc'",
         "a finite number (N/mm)", ("line 7, column 'tau'",)),
    Case("cal-surfaces", "`--surfaces 9`", ("calibrate", "curve.csv", "--surfaces", "9"),
         {"curve.csv": CURVE}, "--surfaces", None, "9", "an integer from 0 to 6"),
    Case("cal-rows", "`--rows 0,30,20`: not increasing",
         ("calibrate", "curve.csv", "--rows", "0,30,20"),
         {"curve.csv": CURVE}, "--rows", None, "'0,30,20'", "0 < b1 < b2 < ..."),
    Case("cal-frame-side", "`--frame-side=-100`", ("calibrate", "curve.csv", "--frame-side=-100"),
         {"curve.csv": CURVE}, "--frame-side", None, "-100.0",
         "the side of the picture frame in mm"),
    Case("cal-series", "`--series UT`: not a series of the file", ("calibrate", "pf.csv",
         "--series", "UT"), {"pf.csv": SERIES}, None, "--series", "'UT'",
         "series of pf.csv: HKUST, UN", ("unknown series",)),
    Case("cal-sides", "forces per series without the fabric's side",
         ("calibrate", "pf.csv", "--frame-side", "HKUST=180,UN=145"), {"pf.csv": SERIES},
         "pf.csv", "--fabric-side", None, "--fabric-side MM (every series) or NAME=MM",
         ("series 'HKUST'",)),
    Case("cal-angle-range", "`--angle-range 35,10`", ("calibrate", "pf.csv", "--angle-range",
         "35,10"), {"pf.csv": SERIES}, None, "--angle-range", "'35,10'", "LO,HI in degrees"),
    Case("cal-material", "`--material notes.txt`: not TOML",
         ("calibrate", "curve.csv", "--material", "notes.txt"),
         {"curve.csv": CURVE, "notes.txt": "K1: 10000\n"}, "notes.txt", None, None, "TOML syntax",
         ("not valid TOML",)),
]


# --- running ----------------------------------------------------------------------------------

def listing(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def run_case(case: Case, root: Path) -> dict:
    """Run one case through drape.cli.main in root/<id>/: exit code, stderr, files left behind."""
    from drape import cli

    folder = root / case.id
    folder.mkdir(parents=True, exist_ok=True)
    for name, text in case.files.items():
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if text.startswith("\x00"):
            path.write_bytes(text.encode("latin-1"))
        else:
            path.write_text(text)
    before = listing(folder)
    err, out = io.StringIO(), io.StringIO()
    here = os.getcwd()
    os.chdir(folder)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            try:
                code = cli.main(list(case.args))
            except SystemExit as stop:             # argparse
                code = stop.code
            except BaseException:                  # noqa: BLE001 - reported, not raised
                code = "exception"
                traceback.print_exc()
    finally:
        os.chdir(here)
    return {"code": code, "stderr": err.getvalue(), "stdout": out.getvalue(),
            "left": sorted(listing(folder) - before)}


def run_cases(root: Path, ids: list[str] | None = None, progress: Path | None = None) -> dict:
    results = {}
    for case in CASES:
        if ids and case.id not in ids:
            continue
        if progress is not None:
            with progress.open("a") as stream:
                stream.write(case.id + "\n")
        results[case.id] = run_case(case, root)
    return results


def rank() -> int:
    return int(os.environ.get("OMPI_COMM_WORLD_RANK", os.environ.get("PMI_RANK", "0")))


# --- the docs table ---------------------------------------------------------------------------

HEADER = """\
# Bad inputs: what drape says

Every row is a case of `tests/bad_inputs.py`, run through the `drape` command line by
`tests/test_bad_inputs.py` (serially and under `mpirun -n 2`) and written here by

    .venv/bin/python tests/bad_inputs.py --write-docs

so this table is what drape prints today. Each case runs in an empty folder holding the files
it writes (`job.toml` is a small bias-extension job: a 100 x 50 mm blank at +-45 deg, mesh size
10 mm, the paper's three-surface material in `material.toml`; `tools.toml` is
`configs/tools/hemisphere.toml`; `curve.csv` a measured cycle to 10 deg); the input column
says what was changed.

Every bad input is exit code **2**, one line on stderr, `drape COMMAND: error: ` then the file
(or the command-line option), the key, the value, the problem and `expected ...`; nothing
has been computed and nothing is written. (A run that fails after it started is exit code 1:
`docs/fe-solver.md`.) Under `mpirun` every rank stops with exit code 2 and rank 0 alone prints.

Decisions the messages follow:

* unknown keys list the keys known there and, when one is close (difflib), suggest it
  ("did you mean");
* `blank.yarn_angle` is accepted from -90 to 90 deg (every direction: theta + 180 is the same
  yarn); an aligned mesh of a rectangle further needs a multiple of 45;
* `mesh.size` must give at least 3 elements across the blank's smallest extent and at most
  4 million elements;
* `--set` values are TOML (a bare word is a string) and are checked like the file's own, so
  the message names the file and the key they override.

"""


def table(results: dict) -> str:
    lines = [HEADER.rstrip("\n"), "",
             "| case | input | command | exit | message (stderr) |", "|---|---|---|---|---|"]
    for case in CASES:
        result = results[case.id]
        message = result["stderr"].strip().replace("|", "\\|")
        command = " ".join(["drape", *(f'"{a}"' if " " in a else a for a in case.args)])
        text = case.input.replace("|", "\\|")
        lines.append(f"| `{case.id}` | {text} | `{command}` | {result['code']} | `{message}` |")
    return "\n".join(lines) + "\n"


def main(argv: list[str]) -> int:
    import tempfile
    if argv[:1] == ["--write-docs"]:
        with tempfile.TemporaryDirectory() as root:
            results = run_cases(Path(root))
        DOC.write_text(table(results))
        bad = [i for i, r in results.items() if r["code"] != 2]
        print(f"wrote {DOC} ({len(results)} cases)"
              f"{'; not exit code 2: ' + ', '.join(bad) if bad else ''}")
        return 0
    root, out, ids = Path(argv[0]), Path(argv[1]), argv[2:]
    r = rank()
    if r:
        out = out.with_suffix(f".rank{r}.json")
    progress = out.with_suffix(".progress") if r == 0 else None
    results = run_cases(root / f"rank{r}", ids, progress)
    out.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
