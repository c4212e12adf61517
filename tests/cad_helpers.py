"""Tools written as STEP files the way a user's CAD would hold them, for the tests that compare
STEP tools with the built-in ones: the default hemisphere's punch, die and holder built with
gmsh's OpenCASCADE kernel from the dimensions of ``configs/tools/hemisphere.toml`` (not through
drape's own builder), in their working positions, one solid per file."""

from __future__ import annotations

from pathlib import Path


def write_hemisphere_step(folder, dims=None, plate: float = 300.0) -> dict[str, Path]:
    """punch.step, die.step, holder.step in ``folder`` for the hemisphere dimensions ``dims``
    (a drape.geometry.tools.HemisphereTools; default: the built-in one, gap 0):

    * punch: a whole sphere of radius R centred at z = R fused with a cylinder of radius R from
      z = R up by the shank height (its lowest point at z = 0);
    * die: a square plate ``plate`` x ``plate`` x die_thickness under z = 0 minus a cylinder of
      the opening radius, the top edge of the hole filleted with the die fillet radius;
    * holder: a square plate ``plate`` x ``plate`` x holder_thickness above z = 0 minus a
      cylinder of the holder's inner radius, the lower edge of the hole filleted with the
      holder's fillet radius.

    The plates are squares (a user's plates would be) where drape's are discs of radius 150 mm:
    the 200 mm blank (corners at r = 141 mm) never reaches the difference."""
    from drape.geometry._gmsh import scratch_model
    from drape.geometry.tools import HemisphereTools

    dims = dims or HemisphereTools()
    if dims.gap != 0.0:
        raise ValueError("written for gap = 0")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = {}
    for name in ("punch", "die", "holder"):
        with scratch_model(f"cad-{name}") as gmsh:
            occ = gmsh.model.occ
            R, half = dims.punch_radius, plate / 2.0
            if name == "punch":
                ball = occ.addSphere(0, 0, R, R)
                shank = occ.addCylinder(0, 0, R, 0, 0, dims.shank_height, R)
                occ.fuse([(3, ball)], [(3, shank)])
            else:
                die = name == "die"
                thickness = dims.die_thickness if die else dims.holder_thickness
                radius = dims.die_opening_radius if die else dims.holder_inner_radius
                fillet = dims.die_fillet_radius if die else dims.holder_fillet_radius
                z0 = -thickness if die else 0.0
                box = occ.addBox(-half, -half, z0, plate, plate, thickness)
                hole = occ.addCylinder(0, 0, z0 - 1.0, 0, 0, thickness + 2.0, radius)
                (solid,), _ = occ.cut([(3, box)], [(3, hole)])
                occ.synchronize()
                # the hole's edge on the face at z = 0: a circle of the hole's radius
                edges = []
                for dim, curve in gmsh.model.getEntities(1):
                    x0, y0, z_lo, x1, y1, z_hi = gmsh.model.getBoundingBox(dim, curve)
                    if abs(z_lo) < 1e-6 and abs(z_hi) < 1e-6 and \
                            abs(x1 - radius) < 1e-4 * radius and abs(x0 + radius) < 1e-4 * radius:
                        edges.append(curve)
                if fillet > 0.0:
                    occ.fillet([solid[1]], edges, [fillet])
            occ.synchronize()
            paths[name] = folder / f"{name}.step"
            gmsh.write(str(paths[name]))
    return paths


def step_tools_table(paths: dict[str, Path], **holder) -> dict:
    """The ``[tools]`` table of a job using these files (holder: extra keys such as control)."""
    return {"kind": "step", "step": {
        "punch": {"file": str(paths["punch"])},
        "die": {"file": str(paths["die"])},
        "holder": {"file": str(paths["holder"]), **holder}}}


def step_job(config: Path, folder, paths: dict[str, Path], **holder) -> Path:
    """A copy of the job file ``config`` in ``folder`` whose [tools] table (and its sub-tables)
    is replaced by STEP tools from ``paths`` (holder: extra keys such as control = "position");
    the material path is made absolute. Returns the new file's path."""
    config, folder = Path(config), Path(folder)
    lines, skipping = [], False
    for line in config.read_text().splitlines():
        header = line.strip().startswith("[")
        if header:
            skipping = line.strip().startswith("[tools")
        if skipping:
            continue
        if line.startswith("material"):
            material = line.split("=", 1)[1].split("#")[0].strip().strip('"')
            line = f'material = "{(config.parent / material).resolve()}"'
        lines.append(line)
    lines.append('\n[tools]\nkind = "step"')
    for name in ("punch", "die", "holder"):
        lines.append(f'[tools.step.{name}]\nfile = "{Path(paths[name]).resolve()}"')
        if name == "holder":
            lines.extend(f'{key} = "{value}"' for key, value in holder.items())
    path = folder / f"{config.stem}_step.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def write_double_dome_step(folder, margin: float = 50.0) -> dict[str, Path]:
    """punch.step, die.step, holder.step in ``folder``: the default double dome's tools built
    by drape's gmsh/OpenCASCADE builder and written as STEP, one solid per file, with the die
    block and the holder plate ``margin`` mm wider all round than drape's 470 x 270 mm. drape's
    exact double-dome tools are unbounded outward (docs/tools.md): the blank's ends lie on the
    die's outer edge, where the finite block's sharp edge (its mean normal) would push them
    sideways; the wider plates leave the fabric on the flat faces, as the exact tools do."""
    import dataclasses

    from drape.geometry._gmsh import scratch_model
    from drape.geometry.double_dome_tools import DoubleDomeTools, build_double_dome_solids

    base = DoubleDomeTools()
    dims = dataclasses.replace(base, die_length=base.die_length + 2 * margin,
                               die_width=base.die_width + 2 * margin)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = {}
    for name in ("punch", "die", "holder"):
        with scratch_model(f"cad-{name}") as gmsh:
            volumes = build_double_dome_solids(gmsh, dims)
            gmsh.model.occ.remove([(3, tag) for other, tag in volumes.items() if other != name],
                                  recursive=True)
            gmsh.model.occ.synchronize()
            paths[name] = folder / f"{name}.step"
            gmsh.write(str(paths[name]))
    return paths
