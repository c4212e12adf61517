"""Run a forming job from a TOML config: the blank is meshed, held and moved as the config says,
and solved in adaptive load steps with the nested-surface law at every quadrature point.

    drape run configs/picture_frame.toml
    mpirun -n 2 drape run configs/bias_extension.toml --petsc-option snes_monitor

Writes results/<config name>/ (or --output): fields.xdmf (+ .h5), steps.csv, result.npz and,
for a picture-frame job, frame_force.csv and frame_force.png. Every converged step is written
as it converges; a run that fails keeps what converged (exit code 1). A checkpoint
(checkpoint.npz) every output.checkpoint_every steps and when a run stops (SIGTERM, Ctrl-C, a
failure) lets `drape run CONFIG --resume` continue it. A folder that holds results is not
overwritten without --overwrite. See docs/fe-solver.md.

Progress (rank 0 only, on stdout): on a terminal one redrawn line, a bar over the load factor t
from 0 to 1 with the step, Newton iterations, step size, elapsed time and an estimate of the
time left (the load still to go at the slower of the average pace and the last 3 steps';
drape.io.progress); otherwise (a log file, a batch job, and always under mpirun) one plain line per
converged step; nothing with --quiet. Cutbacks and warnings get lines of their own. View the
results with `drape view`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np

HELP = "run a forming job from a TOML config (serial or under mpirun)"
# added to a quasi-static forming run's failure: where the steps shrink as the blank wrinkles
# or snaps into a clearance, inertia carried the runs of docs/forming.md through
INERTIA_HINT = ("; if the steps shrank where the blank wrinkles or is drawn into a narrow "
                "clearance, the blank's inertia may carry it through: set process.areal_density "
                "(kg/m^2, e.g. 1) and process.punch_speed (m/s, e.g. 3); docs/forming.md, "
                "'Inertia'")


def add_arguments(parser) -> None:
    parser.add_argument("config", metavar="CONFIG.toml",
                        help="the job file (TOML: material, blank, mesh, steps, histories, "
                             "boundaries; every key in docs/fe-solver.md), e.g. "
                             "configs/bias_extension.toml")
    parser.add_argument("--output", default=None, metavar="DIR",
                        help="results folder (default: output.folder of the config, else "
                             "results/<config name>)")
    parser.add_argument("--petsc-option", action="append", default=[], metavar="NAME[=VALUE]",
                        help="a PETSc option for the solver (prefix drape_ added), e.g. "
                             "snes_monitor or ksp_type=gmres; repeatable; overrides the config")
    parser.add_argument("--set", action="append", default=[], metavar="TABLE.KEY=VALUE",
                        help="override a config value (TOML syntax), e.g. mesh.size=2.5 or "
                             "output.xdmf=false; repeatable")
    parser.add_argument("--quiet", action="store_true",
                        help="print nothing but errors (no progress, no summary line)")
    again = parser.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true",
                       help="continue from the checkpoint in the results folder (same config, "
                            "--set values and number of ranks)")
    again.add_argument("--overwrite", action="store_true",
                       help="start over in a results folder that already holds results")


def main(args) -> int:
    from mpi4py import MPI

    from drape.errors import Interrupted, WriteFailed
    from drape.job import load_job
    from drape.fe.solver import parse_option

    options = dict(parse_option(text) for text in args.petsc_option)
    job = load_job(args.config, overrides=args.set)
    comm = MPI.COMM_WORLD
    progress = step_progress(job, enabled=comm.rank == 0 and not args.quiet)
    try:
        summary = run_job(job, comm, output=args.output, petsc_options=options,
                          log=progress.message if progress.enabled else None,
                          on_step=progress.on_step, resume=args.resume, overwrite=args.overwrite)
    except Interrupted as stopped:
        raise Interrupted(f"{stopped}; resume with: {resume_command(args, comm.size)}") from None
    except WriteFailed as failed:
        if not failed.resumable:
            raise
        raise WriteFailed(f"{failed}; resume (once there is space) with: "
                          f"{resume_command(args, comm.size)}") from None
    finally:
        progress.close()
    if comm.rank == 0 and not args.quiet:
        print(f"drape run: {summary.steps} steps to t = {summary.t:g} in {summary.seconds:.1f} s; "
              f"results in {summary.folder}")
    return 0


def resume_command(args, ranks: int) -> str:
    """The command line that resumes the run of ``args``."""
    import shlex
    words = ["drape", "run", args.config, "--resume"]
    if args.output:
        words += ["--output", args.output]
    for item in args.set:
        words += ["--set", item]
    for item in args.petsc_option:
        words += ["--petsc-option", item]
    text = shlex.join(words)
    return f"mpirun -n {ranks} {text}" if ranks > 1 else text


def step_progress(job, *, enabled: bool, stream=None):
    """The progress display of `drape run` (drape.io.progress.Progress on stdout): a redrawn bar
    over the load factor on a terminal, one line per converged step otherwise (and always under
    mpirun), nothing when disabled; ``progress.on_step`` is run_job's on_step."""
    import os
    import sys

    from drape.io.progress import Progress

    progress = Progress(1.0, enabled=enabled, stream=stream if stream is not None else sys.stdout)
    if any(name in os.environ for name in ("OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMI_RANK")):
        # Open MPI hands its ranks a pseudo-terminal whether or not mpirun's own output is one:
        # under mpirun a terminal cannot be told from a log file, so plain lines
        progress.interactive = False
    histories = list(job.config.history)

    def on_step(row, problem=None):
        notes = [f"{name}={row[name]:.4g}" for name in histories if name in row]
        notes.append(f"max|gamma|={row['max_shear_angle_deg']:.3f} deg")
        if row.get("cutbacks"):
            notes.append(f"{row['cutbacks']} cutback(s)")
        progress.step(row["step"], row["t"], row["newton_iterations"], row["dt"],
                      note="  ".join(notes))

    progress.on_step = on_step
    return progress


@dataclasses.dataclass
class RunSummary:
    steps: int
    t: float
    seconds: float
    folder: Path
    rows: list
    timings: dict


@dataclasses.dataclass
class RunParts:
    """What a run is made of, handed to the ``on_start`` hook (benchmarks and tests read it;
    the run owns it)."""
    job: object
    problem: object      #: drape.fe.membrane.MembraneProblem
    solver: object       #: drape.fe.solver.NewtonSolver
    motion: object       #: drape.fe.constraints.PrescribedMotion
    forming: object      #: drape.forming.press.Forming, or None for a flat job


def run_job(job, comm=None, *, output=None, petsc_options=None, on_step=None, log=None,
            jit_params=None, resume=False, overwrite=False, on_start=None, on_attempt=None,
            on_solve=None) -> RunSummary:
    """Run a loaded :class:`~drape.job.Job` on ``comm`` (default COMM_WORLD).

    Hooks, each optional and called on every rank: on_start(RunParts) once the run is set up;
    on_attempt(t) before each Newton attempt at load factor t; on_solve(solver, result) after
    each Newton solve (a holder's re-solves too); on_step(step_row, problem) after each
    converged step is written (`drape run` shows its progress from there). log(text) gets the
    other messages (start, warnings, cutbacks).
    Raises RunFailed (results so far written) when a step does not converge, Interrupted on
    SIGTERM/SIGINT (after the checkpoint), InputError if the results folder holds results and
    neither ``overwrite`` (start over) nor ``resume`` (continue from its checkpoint) is given.
    """
    from mpi4py import MPI

    from drape.reports import bias_extension, frame_force
    from drape.io.checkpoint import Checkpoints, rewind_outputs
    from drape.fe.constraints import PrescribedMotion
    from drape.io.disk import Disk, estimate
    from drape.errors import InputError, Interrupted, RunFailed, WriteFailed
    from drape.io.folder import claim
    from drape.io.interrupt import StopRequest
    from drape.law.nested_surface import NestedSurfaceLaw
    from drape.fe.loading import Loading
    from drape.fe.membrane import MembraneProblem
    from drape.fe.mesh import create_blank_mesh
    from drape.io.writer import FIELDS_FILE, STEPS_FILE, ResultsWriter
    from drape.fe.solver import NewtonSolver, run_load_steps
    from drape.reports.oscillation import OSCILLATION_WARNING, ShearOscillation

    _quiet_jit_logging()
    comm = comm or MPI.COMM_WORLD
    config = job.config
    started = time.perf_counter()
    say = log or (lambda *_: None)
    folder = job.results_folder(output)
    claim(folder, RESULT_FILES, comm=comm, overwrite=overwrite, resume=resume,
          also_remove=ALSO_REMOVED, can_resume=True)

    forming = None
    if config.process is not None:
        from drape.forming.press import Forming
        forming = Forming(job, comm, log=say)
    try:
        blank_mesh = create_blank_mesh(comm, config.blank, config.mesh,
                                       centred=forming is not None)
    except InputError as error:     # the mesher names the key; the job file is ours to add
        raise error.located(str(job.path)) from None
    say(f"drape run: {job.path}: {blank_mesh.description}, {comm.size} rank(s)")
    law = NestedSurfaceLaw(job.params)
    inertial = forming is not None and config.process.areal_density > 0
    loading = Loading.from_config(config, source=str(job.path))
    problem = MembraneProblem(blank_mesh, law, config.blank.yarn_angle,
                              config.regularisation.out_of_plane_damping,
                              contributions=forming.contributions if forming else None,
                              jit_params=jit_params,
                              bending_rigidity=config.bending.value(forming is not None),
                              inertia=inertial,
                              neutral_loading_band=config.solver.neutral_loading_band)
    if forming is not None:
        forming.bind(problem)
    motion = PrescribedMotion(problem.V, blank_mesh, loading)
    problem.bcs = motion.bcs
    area = comm.allreduce(problem.cell_areas.sum())
    force_scale = job.params.mu * max(job.params.K1, job.params.K2) * math.sqrt(area)
    stop = StopRequest()
    solver = NewtonSolver(problem, config.solver, force_scale, petsc_options,
                          interrupted=lambda: bool(stop.signal), on_solve=on_solve)
    rows, frame_rows = [], []
    ledger = {"external": 0.0, "regularisation": 0.0, "f": None, "g": None}
    checkpoints = Checkpoints(folder, problem, job, config.output.checkpoint_every, rows,
                              frame_rows, ledger, motion.prescribed_dofs)
    start = checkpoints.load() if resume else None   # (step, t, dt) to continue from
    if start is not None:
        rewind_outputs(folder, rows, start[1], comm)
        say(f"drape run: resuming from the checkpoint of step {start[0]} (t = {start[1]:.6g})")
    disk = Disk(folder, comm, estimate(problem, config, forming is not None))
    disk.warn_at_start(say)
    checkpoints.disk = disk
    writer = disk.write(FIELDS_FILE, lambda: ResultsWriter(
        folder, problem, xdmf=config.output.xdmf, xdmf_every=config.output.xdmf_every,
        snapshot=config.output.snapshot, append=start is not None,
        extra_cell_fields={"contact_pressure": forming.contact_pressure} if forming else None),
        root_only=False, fields=True)
    frame = config.picture_frame
    side = config.blank.length
    if config.mesh.pattern == "free":
        say("drape run: warning: mesh.pattern = \"free\": element edges do not follow the yarns; "
            "with stiff yarns such meshes lock in tension (too stiff, yarns stretched: watch "
            "max_yarn_strain in steps.csv). mesh.pattern = \"aligned\" avoids it; see "
            "docs/fe-solver.md")

    oscillation = ShearOscillation(problem)
    oscillation_warned = []

    def record(step, t, iterations=0, cutbacks=0, dt=0.0, residual=0.0, seconds=0.0):
        force = problem.internal_force()
        f_prescribed = force.array_r[motion.prescribed_dofs].copy()
        u_prescribed = problem.u.x.array[motion.prescribed_dofs].copy()
        if ledger["f"] is not None:
            local = 0.5 * (ledger["f"] + f_prescribed) @ (u_prescribed - ledger["g"])
            ledger["external"] += comm.allreduce(float(local))
        ledger["f"], ledger["g"] = f_prescribed, u_prescribed
        response = problem.response
        local_max = float(np.abs(response.gamma_t_deg).max()) if response.tau.size else 0.0
        row = {"step": step, "t": t, "dt": dt, "newton_iterations": iterations,
               "cutbacks": cutbacks, "residual_norm": residual}
        row.update(loading.history_values(t))
        for name, value in motion.reactions(force).items():
            row.update({f"{name}_Fx": value[0], f"{name}_Fy": value[1], f"{name}_Fz": value[2]})
        row["external_work"] = ledger["external"]
        row["regularisation_work"] = ledger["regularisation"]
        row["regularisation_share"] = (ledger["regularisation"] / abs(ledger["external"])
                                       if ledger["external"] != 0.0 else 0.0)
        row["bending_energy"] = problem.bending_energy()
        row["max_shear_angle_deg"] = comm.allreduce(local_max, op=MPI.MAX)
        strain = float(problem.yarn_strains().max()) if response.tau.size else 0.0
        row["max_yarn_strain"] = comm.allreduce(strain, op=MPI.MAX)
        row["shear_oscillation_deg"] = oscillation.measure()
        if row["shear_oscillation_deg"] > OSCILLATION_WARNING and not oscillation_warned:
            oscillation_warned.append(step)
            say(f"drape run: warning: step {step}: the shear angle oscillates from cell to cell "
                f"by +-{row['shear_oscillation_deg']:.3g} deg (shear_oscillation_deg in "
                f"steps.csv): above {OSCILLATION_WARNING:g} deg the shear map has a cell-scale "
                f"pattern, a spurious checkerboard (a mesh that locks) or wrinkles only a few "
                f"cells wide; docs/blanks.md")
        tau_sum = comm.allreduce(float(response.tau.sum()))
        tau_count = comm.allreduce(response.tau.size)
        row["tau_mean"] = tau_sum / tau_count
        if forming is not None:
            row.update(forming.measure(t, converged=step > 0))
            forming.control_holder(row)
            # the punch's work (trapezoidal in the stroke) is the forming job's external work
            before = rows[-1] if rows else {"punch_work": 0.0, "punch_force": 0.0, "stroke": 0.0}
            row["punch_work"] = before["punch_work"] + 0.5 * (
                before["punch_force"] + row["punch_force"]) * (row["stroke"] - before["stroke"])
            row["external_work"] += row["punch_work"]
            row["regularisation_share"] = (ledger["regularisation"] / abs(row["external_work"])
                                           if row["external_work"] != 0.0 else 0.0)
            row["bending_share"] = (row["bending_energy"] / abs(row["external_work"])
                                    if row["external_work"] != 0.0 else 0.0)
        if frame is not None:
            angle = row[frame.angle]
            q = motion.conjugate_force(force, t, frame.angle)
            row["frame_force"] = (frame_force.from_conjugate_force(side, angle, q)
                                  if step > 0 else 0.0)
            row["frame_force_from_tau"] = float(frame_force.closed_form(side, angle,
                                                                        row["tau_mean"]))
            frame_rows.append({"step": step, "t": t, "angle_deg": angle, **{
                k: row[k] for k in ("frame_force", "frame_force_from_tau", "tau_mean")}})
        if config.bias_extension is not None:
            row.update(bias_extension.measure(config, comm, problem, row))
        force.destroy()
        row["seconds"] = seconds
        rows.append(row)
        return row

    def stop_if_requested():
        signal_name = stop.requested(comm)   # collective: every rank stops at the same point
        if signal_name:
            raise Interrupted(signal_name)

    def attempt(t):
        stop_if_requested()
        if on_attempt is not None:
            on_attempt(t)
        # a step whose files would not fit on the disk: the run stops before solving it
        number = rows[-1]["step"] + 1
        disk.check(number, checkpoints.due(number))
        motion.set_load(t)
        if forming is not None:
            forming.set_load(t)
            forming.predict(t)
        result = solver.solve()
        if forming is not None:   # the holder's force within 1 %: the same step again
            floor = solver.rtol * result.first_residual
            result = forming.hold_force(t, lambda: solver.solve(floor), result)
        stop_if_requested()   # a signal during the attempt cut it short: not a failed step
        return result

    def accept(step):
        ledger["regularisation"] += problem.regularisation_work()
        problem.commit(step.t)
        row = record(step.number, step.t, step.iterations, step.cutbacks, step.dt,
                     step.residual, step.seconds)
        try:
            disk.write(f"step {step.number}'s results ({STEPS_FILE}, {FIELDS_FILE})",
                       lambda: writer.write_step(row, step.t, last=step.t >= 1.0 - 1e-12),
                       root_only=False, fields=True)
        except WriteFailed as failure:      # the files end with the step before
            failure.committed = True
            rows.pop()
            if frame is not None:
                frame_rows.pop()
            raise
        disk.measure((STEPS_FILE, FIELDS_FILE, "fields.h5"))
        try:
            checkpoints.step_done(step)
        except WriteFailed as failure:
            failure.committed = True
            raise
        if on_step is not None:
            on_step(row, problem)

    if on_start is not None:
        on_start(RunParts(job, problem, solver, motion, forming))
    write_failure = None
    stop.install()
    try:
        if start is None:
            motion.set_load(0.0)
            if forming is not None:
                forming.set_load(0.0)
            problem.evaluate()
            writer.write_step(record(0, 0.0), 0.0)
            start = (0, 0.0, None)
        elif forming is not None:
            forming.set_load(start[1])
        run_load_steps(config.steps, loading.breakpoints(), attempt, accept, problem.restore,
                       step0=start[0], t0=start[1], dt0=start[2], log=say)
    except WriteFailed as failure:
        write_failure = failure
        raise write_failed(failure, writer, checkpoints, rows, folder) from None
    except RunFailed as failure:
        problem.restore()
        problem.evaluate()
        if config.output.snapshot != "none":
            writer.write_snapshot(rows[-1]["t"])
        saved = checkpoints.save_last()
        last = f"t = {rows[-1]['t']:.6g} (step {rows[-1]['step']})"
        if isinstance(failure, Interrupted):
            raise Interrupted(f"{failure} received; stopped after step {rows[-1]['step']} at "
                              f"t = {rows[-1]['t']:.6g}: "
                              f"results{' and checkpoint' if saved else ''}"
                              f" up to it are in {folder}") from None
        raise RunFailed(f"{failure}; results up to {last} are in {folder}"
                        f"{' (with a checkpoint)' if saved else ''}"
                        f"{INERTIA_HINT if forming is not None and not inertial else ''}"
                        ) from None
    finally:
        stop.uninstall()
        writer.close()
        solver.close()
        if write_failure is None:   # after a write failure the resumed run writes them
            if frame is not None and len(frame_rows) > 1:
                disk.write("frame_force.csv/.png",
                           lambda: frame_force.write(folder, side, frame_rows))
            if config.bias_extension is not None and len(rows) > 1:
                disk.write("bias_extension.csv/.png",
                           lambda: bias_extension.write(folder, rows, config.title))
            if forming is not None and len(rows) > 1:
                disk.write("force_stroke.csv/.png, the shear maps and summary.json",
                           lambda: forming.finish(folder, rows, time.perf_counter() - started),
                           root_only=False)
    checkpoints.finished()
    timings = dict(problem.timings)
    timings.update({f"count_{k}": v for k, v in problem.counts.items()})
    return RunSummary(rows[-1]["step"], rows[-1]["t"], time.perf_counter() - started, folder,
                      rows, timings)


def write_failed(failure, writer, checkpoints, rows, folder):
    """After a write failure (drape.io.disk): fields.xdmf back to its last complete step; a
    checkpoint of that step when the failure came before the step changed anything (a step
    that would not fit) and there is room for one (else the last good one is kept). Returns
    the WriteFailed to raise: the failure, what is kept, and whether a resume can follow."""
    from drape.errors import WriteFailed
    if not failure.fields_intact:
        writer.rewind_fields()
    room = None
    if not getattr(failure, "committed", False):
        try:
            checkpoints.save_last(check_space=True)
        except WriteFailed:
            from drape.io.disk import size
            room = size(checkpoints.disk.checkpoint_bytes())
    kept = (f"; results up to step {rows[-1]['step']} (t = {rows[-1]['t']:.6g}) are kept in "
            f"{folder}")
    saved = checkpoints.saved_step
    if saved is not None:
        kept += f", with the checkpoint of step {saved}"
        if room is not None:
            kept += f" (no room for a newer one: about {room})"
    elif room is not None:
        kept += (f", without a checkpoint (no room for one either: about {room}): --overwrite "
                 "starts over once there is space")
    else:
        kept += (", without a checkpoint (output.checkpoint_every = 0 or none written yet): "
                 "--overwrite starts over")
    error = WriteFailed(f"{failure}{kept}", fields_intact=failure.fields_intact)
    error.resumable = saved is not None
    return error


#: what a run writes in its folder (drape.io.folder.claim refuses to overwrite them silently)
RESULT_FILES = ("steps.csv", "fields.xdmf", "result.npz", "checkpoint.npz")
#: removed with them by --overwrite
ALSO_REMOVED = ("fields.h5", "fields-*.h5", "checkpoint.xdmf", "checkpoint.h5",
                "frame_force.csv", "frame_force.png", "bias_extension.csv", "bias_extension.png")


def _quiet_jit_logging() -> None:
    """The JIT compiler (cffi through distutils) logs every compilation at INFO level on the
    root logger; keep warnings only."""
    import logging
    root = logging.getLogger()
    if not any(getattr(f, "_drape", False) for f in root.filters):
        keep = logging.Filter()
        keep.filter = lambda record: record.levelno >= logging.WARNING
        keep._drape = True
        root.addFilter(keep)
