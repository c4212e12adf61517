"""Check a tool configuration and write the tool surfaces to a file you can open (ParaView, gmsh).

    drape tools configs/tools/hemisphere.toml               -> results/tools/hemisphere.vtu
    drape tools configs/tools/double_dome.toml --output dd.msh
    drape tools my_tools.toml --check                        (validate only, nothing written)

The file's ``[tools]`` table is read (a job file with a ``[tools]`` table works too; its other
tables are left to ``drape run``). See docs/tools.md for every key.
"""

from __future__ import annotations

import difflib
from pathlib import Path

HELP = "check a tool configuration ([tools] table) and write its surfaces (.vtu or .msh)"


def add_arguments(parser) -> None:
    parser.add_argument("config", metavar="CONFIG.toml", help="a file with a [tools] table")
    parser.add_argument("--output", default=None, metavar="FILE",
                        help="surfaces file, .vtu or .msh "
                             "(default results/tools/<config name>.vtu)")
    parser.add_argument("--check", action="store_true",
                        help="only validate the configuration; build and write nothing")


def main(args) -> int:
    from drape.config import from_mapping, read_toml
    from drape.errors import InputError
    from drape.geometry.tools import ToolsConfig

    path = Path(args.config)
    data = read_toml(path)
    if "tools" not in data:
        close = difflib.get_close_matches("tools", list(data), n=1, cutoff=0.6)
        hint = f"; did you mean '{close[0]}'?" if close else ""
        raise InputError(f"no [tools] table{hint}", source=str(path), key="tools",
                         expected="a [tools] table with kind = \"hemisphere\", \"double_dome\" "
                                  "or \"step\" (docs/tools.md)")
    if not isinstance(data["tools"], dict):
        raise InputError("wrong type", source=str(path), key="tools", value=data["tools"],
                         expected="a table")
    config = from_mapping(ToolsConfig, data["tools"], source=str(path), prefix="tools")
    output = Path(args.output) if args.output else Path("results") / "tools" / f"{path.stem}.vtu"
    if output.suffix not in (".vtu", ".msh"):
        raise InputError("unknown tool file format", key="--output", value=str(output),
                         expected="a path ending in .vtu or .msh")
    if args.check:
        print(f"drape tools: {path}: {config.kind} tools, valid")
        return 0
    from mpi4py import MPI

    from drape.geometry.tools import build_tools, write_tool_surfaces
    comm = MPI.COMM_WORLD
    surfaces = build_tools(config, comm=comm)
    if comm.rank == 0:
        write_tool_surfaces(output, surfaces)
        counts = ", ".join(f"{name} {len(s.triangles)}" for name, s in surfaces.items())
        print(f"drape tools: {path}: {config.kind} tools ({counts} triangles) in {output}")
    return 0
