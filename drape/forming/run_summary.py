"""What a forming run writes at its end (drape.forming.press.Forming.finish): summary.json
(the shear and draw-in reports, the tools, the stroke, the punch force, the holder, the
inertia, the steps; a stack's blocks per ply and interface), force_stroke.csv/.png and the
shear maps. Rank 0 writes; the gathering is collective."""

from __future__ import annotations

import json
from pathlib import Path

from drape.forming.checks import full_stroke
from drape.forming.holder import HOLDER_WARNING
from drape.job import describe_blank
from drape.reports.oscillation import OSCILLATION_WARNING

SUMMARY_FILE = "summary.json"


def holder_entries(forming, measured: list) -> dict:
    """summary.json's holder entries: how it was driven, the force it was driven to (force
    control only) and the ``measured`` force over the converged steps (never the config's
    force where it was not applied)."""
    mode = forming.holder_mode if "holder" in forming.tool_contact.surfaces else None
    entries = {"holder_control": mode or "none"}
    if mode == "force":
        entries["holder_force_N"] = forming.process.holder_force
        entries["holder_force_steps_off_5pct"] = len(forming.holder_warnings)
    elif mode == "position":
        entries["holder_force_N"] = float(measured[-1]) if measured else 0.0
    else:
        entries["holder_force_N"] = 0.0
    if measured:
        entries["holder_force_measured_N"] = [float(min(measured)), float(max(measured))]
    return entries


def run_entries(forming, records: list, seconds: float, measured: list) -> dict:
    """summary.json's entries on the job and the run (rank 0): the tools, the stroke, the
    punch force (N), the shear oscillation, the holder, the inertia, the steps."""
    problem, process, last = forming.problem, forming.process, records[-1]
    forces = [r.columns.get("punch_force", 0.0) for r in records]
    return {
        "title": forming.title, "blank": describe_blank(forming.blank),
        "tools": forming.kind,
        "yarn_angle_deg": forming.blank.yarn_angle,
        "stroke_mm": last.columns.get("stroke", 0.0), "configured_stroke_mm": forming.stroke,
        "tools_full_stroke_mm": full_stroke(forming.config),
        "max_punch_force_N": float(max(forces)),
        # cell-to-cell shear oscillation (drape/reports/oscillation.py, docs/blanks.md)
        "shear_oscillation_deg": float(last.shear_oscillation_deg),
        "max_shear_oscillation_deg": float(max(r.shear_oscillation_deg for r in records)),
        "shear_oscillation_warning_deg": OSCILLATION_WARNING,
        "punch_force_at_end_N": float(forces[-1]),
        **holder_entries(forming, measured),
        # the blank's inertia: a dynamic run's forces depend on these (docs/forming.md)
        "areal_density_kg_per_m2": process.areal_density,
        "punch_speed_m_per_s": process.punch_speed,
        "punch_ramp_mm": process.punch_ramp,
        "max_penetration_mm": float(max(r.columns.get("max_penetration", 0.0)
                                        for r in records)),
        "penalty_N_per_mm3": forming.penalty,
        "friction": dict(forming.tool_contact.friction),     # μ per tool
        "regularisation_share": last.regularisation_share,
        "steps": last.step,
        "newton_iterations": int(sum(r.newton_iterations for r in records)),
        "cutbacks": int(sum(r.cutbacks for r in records)),
        "wall_time_s": seconds, "ranks": forming.comm.size,
        "cells": problem.mesh.topology.index_map(problem.mesh.topology.dim).size_global,
    }


def stack_entries(forming, summary: dict, locking: float):
    """A stack's blocks of summary.json, ``plies`` and ``interfaces``
    (drape.forming.stack_reports), and its cells by ply for the per-ply shear maps (rank
    0; None for one blank). Collective."""
    if forming.stack is None:
        return None
    from drape.forming import stack_reports
    summary["plies"] = stack_reports.ply_summaries(forming.problem, forming.stack, locking,
                                                   forming.comm)
    summary["interfaces"] = stack_reports.interface_summaries(forming.problem, forming.comm)
    return stack_reports.gather_ply_cells(forming.problem)


def write_reports(forming, folder: Path, records: list, seconds: float) -> dict:
    """force_stroke.csv/.png, shear maps, summary.json (collective; rank 0 writes)."""
    from drape.forming import reports
    problem = forming.problem
    locking = forming.process.locking_angle
    cells = reports.gather_cells(problem)
    summary = reports.shear_summary(problem, locking, forming.comm)
    summary.update(reports.draw_in(problem, forming.blank, forming.comm))
    measured = [r.columns["holder_force"] for r in records[1:]
                if "holder_force" in r.columns]
    if measured:
        target = (f"its target {forming.process.holder_force:g} N; "
                  f"{len(forming.holder_warnings)} step(s) off it by more than "
                  f"{100 * HOLDER_WARNING:g} %" if forming.holder is not None
                  else "position-controlled")
        forming.say(f"drape run: holder force measured {min(measured):.5g} to "
                    f"{max(measured):.5g} N over the converged steps ({target})")
    plies = stack_entries(forming, summary, locking)
    if forming.comm.rank == 0:
        summary.update(run_entries(forming, records, seconds, measured))
        summary.update(reports.strip_summary(cells, forming.blank.yarn_angle))
        folder = Path(folder)
        rows = [record.row() for record in records]     # as in steps.csv
        reports.write_force_stroke(folder, rows)
        reports.plot_force_stroke(folder, rows, forming.title)
        reports.plot_shear_maps(folder, cells, locking, forming.title)
        if plies is not None:
            from drape.forming.stack_reports import plot_ply_shear_maps
            plot_ply_shear_maps(folder, plies, locking, forming.title)
        with (folder / SUMMARY_FILE).open("w") as stream:
            json.dump(summary, stream, indent=2)
            stream.write("\n")
    return summary
