"""The ``drape`` command: one subcommand per job, each in its own module.

Exit codes: 0 success, 2 bad input (nothing computed), 1 a run that failed after it started
(results up to the last converged step kept). Errors are one clear message, no traceback
(set DRAPE_DEBUG=1 to see one).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from drape import __version__
from drape.errors import EXIT_BAD_INPUT, EXIT_RUN_FAILED, InputError, RunFailed, one_line

#: subcommand -> module providing ``add_arguments(parser)``, ``main(args)`` and ``HELP``.
#: Modules are imported only for the subcommand that runs (dolfinx takes seconds to import).
SUBCOMMANDS = {
    "picture-frame": "drape.picture_frame",
    "run": "drape.run",
    "calibrate": "drape.calibrate",
    "tools": "drape.tools_command",
    "view": "drape.view",
}

DESCRIPTION = """\
drape simulates the forming (draping) of woven composite fabrics with the nested-surface
elasto-plastic shear law, on FEniCSx. Units: mm, N, MPa; angles in degrees.
`drape COMMAND --help` explains each command's options.
"""

EPILOG = """\
exit codes:
  0  success
  2  bad input (a config key, value, file or option is wrong; nothing computed)
  1  a run that failed after it started (results up to the last converged step kept)

Errors are one line on stderr without a traceback (DRAPE_DEBUG=1 shows one).
Documentation: README.md and docs/ (docs/fe-solver.md, docs/viewing.md, ...).
"""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="drape", description=DESCRIPTION, epilog=EPILOG,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"drape {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, module_name in SUBCOMMANDS.items():
        module = importlib.import_module(module_name)
        command = sub.add_parser(name, help=module.HELP, description=module.__doc__,
                                 epilog="exit codes: 0 success, 2 bad input, 1 a run that "
                                        "failed after it started (see drape --help)",
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
        module.add_arguments(command)
        command.set_defaults(_module=module)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return EXIT_BAD_INPUT
    try:
        return args._module.main(args) or 0
    except InputError as error:
        if os.environ.get("DRAPE_DEBUG"):
            raise
        _report(one_line(args.command, error))
        return EXIT_BAD_INPUT
    except RunFailed as error:
        if os.environ.get("DRAPE_DEBUG"):
            raise
        _report(one_line(args.command, error))
        return EXIT_RUN_FAILED


def _report(message: str) -> None:
    """One line on stderr; under MPI (every rank raises the same error) from rank 0 only --
    also for commands that never import mpi4py (the launcher's rank variable says which)."""
    mpi = sys.modules.get("mpi4py.MPI")
    if mpi is not None and mpi.COMM_WORLD.rank != 0:
        return
    if mpi is None and os.environ.get("OMPI_COMM_WORLD_RANK",
                                      os.environ.get("PMI_RANK", "0")) != "0":
        return
    print(message, file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
