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

from drape.io.folder import ALSO_REMOVED, RESULT_FILES
from drape.step_loop import Hooks, RunParts, RunSummary, StepLoop

__all__ = ["run_job", "job_parts", "RunParts", "RunSummary"]

HELP = "run a forming job from a TOML config (serial or under mpirun)"


def add_arguments(parser) -> None:
    from drape.io.checkpoint import CONTROLS_TEXT
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
                       help="continue from the checkpoint in the results folder (same config "
                            f"and --set values, but for {CONTROLS_TEXT}; any number of ranks)")
    again.add_argument("--overwrite", action="store_true",
                       help="start over in a results folder that already holds results")


def main(args) -> int:
    from mpi4py import MPI

    from drape import __version__
    from drape.errors import InputError, RunFailed, one_line
    from drape.fe.solver import parse_option
    from drape.io.run_log import RunLog
    from drape.job import load_job

    options = dict(parse_option(text) for text in args.petsc_option)
    job = load_job(args.config, overrides=args.set)
    comm = MPI.COMM_WORLD
    progress = step_progress(job, enabled=comm.rank == 0 and not args.quiet)
    # the same lines, --quiet or not, into the results folder's run.log (drape.io.run_log)
    run_log = RunLog(job.results_folder(args.output), append=args.resume,
                     enabled=comm.rank == 0)
    logged = step_progress(job, enabled=comm.rank == 0, stream=run_log)
    header = f"{command_line(args, comm.size)} (drape {__version__})"

    def log(text):
        progress.message(text)
        logged.message(text)

    def on_step(record, problem=None):
        progress.on_step(record, problem)
        logged.on_step(record, problem)

    try:
        summary = run_job(job, comm, output=args.output, petsc_options=options, log=log,
                          on_step=on_step, on_start=lambda _parts: run_log.open(header),
                          resume=args.resume, overwrite=args.overwrite)
    except RunFailed as failed:
        error = what_next(failed, args, job, comm.size)
        run_log.close(one_line("run", error))
        raise error from None
    except InputError as error:
        run_log.close(one_line("run", error))
        raise
    finally:
        progress.close()
    done = (f"drape run: {summary.steps} steps to t = {summary.t:g} in {summary.seconds:.1f} s; "
            f"results in {summary.folder}")
    run_log.close(done)
    if comm.rank == 0 and not args.quiet:
        print(done)
    return 0


def what_next(failed, args, job, ranks: int):
    """The failure with the command that goes on from its checkpoint, where there is one: the
    same run resumed after a stop or a write failure, smaller steps after Newton failed."""
    from drape.errors import Interrupted, RunFailed, WriteFailed
    if isinstance(failed, Interrupted):
        return Interrupted(f"{failed}; resume with: {resume_command(args, ranks)}")
    if not failed.resumable:
        return failed
    if isinstance(failed, WriteFailed):
        return WriteFailed(f"{failed}; resume (once there is space) with: "
                           f"{resume_command(args, ranks)}")
    smaller = f"steps.minimum={job.config.steps.minimum / 10:g}"
    return RunFailed(f"{failed}; to go on from the checkpoint with other step or solver "
                     f"settings: {resume_command(args, ranks, [smaller])} (or other steps.* and "
                     "solver.* values)")


def resume_command(args, ranks: int, changed: list[str] = ()) -> str:
    """The command line that resumes the run of ``args``, with the overrides ``changed``
    ("key=value") in place of the run's own for the same keys."""
    return command_line(args, ranks, changed, again="--resume")


def command_line(args, ranks: int, changed: list[str] = (), again: str | None = None) -> str:
    """The command line of the run of ``args`` on ``ranks`` ranks (``mpirun -n N`` before it
    when N > 1), with the overrides ``changed`` ("key=value") in place of the run's own for the
    same keys; ``again``: "--resume" or "--overwrite" in place of the run's own, if any."""
    import shlex

    from drape.job import override_key
    if again is None:
        again = "--resume" if args.resume else "--overwrite" if args.overwrite else None
    words = ["drape", "run", args.config] + ([again] if again else [])
    if args.output:
        words += ["--output", args.output]
    replaced = {override_key(item) for item in changed}
    for item in [i for i in args.set if override_key(i) not in replaced] + list(changed):
        words += ["--set", item]
    for item in args.petsc_option:
        words += ["--petsc-option", item]
    text = shlex.join(map(str, words))
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

    def on_step(record, problem=None):
        """A converged step's line: its drape.step_record.StepRecord."""
        notes = [f"{name}={record.histories[name]:.4g}" for name in histories
                 if name in record.histories]
        notes.append(f"max|gamma|={record.max_shear_angle_deg:.3f} deg")
        if record.cutbacks:
            notes.append(f"{record.cutbacks} cutback(s)")
        progress.step(record.step, record.t, record.newton_iterations, record.dt,
                      note="  ".join(notes))

    progress.on_step = on_step
    return progress


def job_parts(job, comm, log=None) -> list:
    """The parts (drape.fe.job_part.JobPart) the job's config asks for, in the order they add
    their columns: the forming process ``[process]``, the picture frame's report
    ``[picture_frame]``, the bias extension's ``[bias_extension]``; none for a patch test."""
    from drape.reports.bias_extension import BiasExtensionReport
    from drape.reports.frame_force import FrameForceReport
    config = job.config
    parts = []
    if config.process is not None:
        from drape.forming.press import Forming
        parts.append(Forming(job, comm, log=log))
    if config.picture_frame is not None:
        parts.append(FrameForceReport(config))
    if config.bias_extension is not None:
        parts.append(BiasExtensionReport(config, comm))
    return parts


def run_job(job, comm=None, *, output=None, petsc_options=None, on_step=None, log=None,
            jit_params=None, resume=False, overwrite=False, on_start=None, on_attempt=None,
            on_solve=None) -> RunSummary:
    """Run a loaded :class:`~drape.job.Job` on ``comm`` (default COMM_WORLD) in its results
    folder (``output``, else the config's): the step loop of :mod:`drape.step_loop`.

    Hooks, each optional and called on every rank: on_start(RunParts) once the run is set up;
    on_attempt(t) before each Newton attempt at load factor t; on_solve(solver, result) after
    each Newton solve (a holder's re-solves too); on_step(record, problem) after each
    converged step is written, with its drape.step_record.StepRecord (`drape run` shows its
    progress from there). log(text) gets the other messages (start, warnings, cutbacks).
    Raises RunFailed (results so far written) when a step does not converge, Interrupted on
    SIGTERM/SIGINT (after the checkpoint), InputError if the results folder holds results and
    neither ``overwrite`` (start over) nor ``resume`` (continue from its checkpoint) is given.
    """
    from mpi4py import MPI

    from drape.io.folder import claim

    _quiet_jit_logging()
    comm = comm or MPI.COMM_WORLD
    folder = job.results_folder(output)
    claim(folder, RESULT_FILES, comm=comm, overwrite=overwrite, resume=resume,
          also_remove=ALSO_REMOVED, can_resume=True)
    hooks = Hooks(on_start=on_start, on_attempt=on_attempt, on_solve=on_solve, on_step=on_step)
    loop = StepLoop(job, job_parts(job, comm, log), comm, folder, petsc_options=petsc_options,
                    log=log, jit_params=jit_params, resume=resume, hooks=hooks)
    return loop.run()


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
