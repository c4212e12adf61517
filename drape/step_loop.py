"""The step loop of ``drape run``: one job, meshed and set up, solved in adaptive load steps,
each converged step recorded, written and checkpointed.

The loop knows the membrane problem, the boundary motion and the writers; what a kind of job
adds (the forming process, a picture frame's or a bias extension's report) comes in as
:class:`~drape.fe.job_part.JobPart` objects, which the loop calls at fixed points: bind, set
the load, predict, re-solve, measure, finish. Hooks (``on_start``, ``on_attempt``,
``on_solve``, ``on_step``) let progress displays, benchmarks and tests look in.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np

from drape.step_record import StepRecord, WorkLedger

#: seconds the ranks wait for each other to raise the same unexpected error before a rank
#: that raised alone aborts the run (StepLoop._abort_if_alone)
ALONE_WAIT = 20.0

FREE_MESH_WARNING = (
    "drape run: warning: mesh.pattern = \"free\": element edges do not follow the yarns; "
    "with stiff yarns such meshes lock in tension (too stiff, yarns stretched: watch "
    "max_yarn_strain in steps.csv). mesh.pattern = \"aligned\" avoids it; see "
    "docs/fe-results.md")


@dataclasses.dataclass
class Hooks:
    """Callbacks into a run, each optional, called on every rank."""
    on_start: object = None     #: on_start(RunParts) once the run is set up
    on_attempt: object = None   #: on_attempt(t) before each Newton attempt at load factor t
    on_solve: object = None     #: on_solve(solver, result) after each Newton solve
    on_step: object = None      #: on_step(record, problem) after a converged step is written


@dataclasses.dataclass
class RunParts:
    """What a run is made of, handed to the ``on_start`` hook (benchmarks and tests read it;
    the run owns it)."""
    job: object
    problem: object      #: drape.fe.membrane.MembraneProblem
    solver: object       #: drape.fe.solver.NewtonSolver
    motion: object       #: drape.fe.constraints.PrescribedMotion
    parts: list          #: the job's parts (drape.fe.job_part.JobPart)

    def part(self, kind: type):
        """The job's part of class ``kind`` (e.g. drape.forming.press.Forming), or None."""
        return next((part for part in self.parts if isinstance(part, kind)), None)


@dataclasses.dataclass
class RunSummary:
    """What a finished run returns (drape.run.run_job)."""
    steps: int          #: the last converged step's number
    t: float            #: its load factor
    seconds: float      #: wall time of the run (s)
    folder: Path        #: the results folder
    rows: list          #: every converged step's drape.step_record.StepRecord, step 0 first
    timings: dict       #: the membrane problem's timings (s) and counts (count_*)


def part_problem(parts, job, comm, law, damping: float, centred: bool, options: dict):
    """The first problem a part builds for its job (JobPart.create_problem: e.g. a stack of
    plies' StackProblem), None when none does (the loop's MembraneProblem on the blank)."""
    for part in parts:
        problem = part.create_problem(job, comm, law, damping, centred, options)
        if problem is not None:
            return problem
    return None


def bending_rigidity(bending, parts) -> float:
    """The problem's bending rigidity B (N mm): the config's ``[bending]`` rigidity, else the
    first part's default (a forming job's), else 0."""
    if bending.rigidity is not None:
        return bending.rigidity
    defaults = [part.default_bending_rigidity for part in parts
                if part.default_bending_rigidity is not None]
    return defaults[0] if defaults else 0.0


class StepLoop:
    """One run of a job in its results folder (collective over ``comm``)."""

    def __init__(self, job, parts: list, comm, folder: Path, *, petsc_options=None, log=None,
                 jit_params=None, resume=False, hooks: Hooks | None = None):
        """``parts``: the job's drape.fe.job_part.JobPart objects (drape.run.job_parts), in
        the order they add their columns."""
        from drape.errors import InputError
        from drape.fe.constraints import PrescribedMotion
        from drape.fe.loading import Loading
        from drape.fe.membrane import MembraneProblem
        from drape.fe.mesh import create_blank_mesh
        from drape.fe.solver import NewtonSolver
        from drape.io.interrupt import StopRequest
        from drape.law.nested_surface import NestedSurfaceLaw

        self.started = time.perf_counter()
        self.job, self.comm, self.folder = job, comm, folder
        self.hooks = hooks or Hooks()
        self.say = say = log or (lambda *_: None)
        config = self.config = job.config
        self.parts = parts
        centred = any(part.centres_blank for part in parts)
        contributions = [c for part in self.parts for c in part.contributions]
        options = dict(contributions=contributions or None, jit_params=jit_params,
                       bending_rigidity=bending_rigidity(config.bending, parts),
                       inertia=any(part.inertial for part in parts),
                       neutral_loading_band=config.solver.neutral_loading_band)
        law = NestedSurfaceLaw(job.params)
        damping = config.regularisation.out_of_plane_damping
        try:
            self.problem = problem = part_problem(parts, job, comm, law, damping, centred,
                                                  options)
            if problem is not None:
                blank_mesh = problem.blank_mesh
            else:
                blank_mesh = create_blank_mesh(comm, config.blank, config.mesh, centred=centred)
        except InputError as error:  # the mesher names the key; the job file is ours to add
            raise error.located(str(job.path)) from None
        say(f"drape run: {job.path}: {blank_mesh.description}, {comm.size} rank(s)")
        self.loading = Loading.from_config(config, source=str(job.path))
        if problem is None:
            self.problem = problem = MembraneProblem(blank_mesh, law, config.blank.yarn_angle,
                                                     damping, **options)
        self.motion = PrescribedMotion(problem.V, blank_mesh, self.loading)
        for part in self.parts:
            part.bind(problem, self.motion)
        problem.bcs = self.motion.bcs
        area = comm.allreduce(problem.cell_areas.sum())
        force_scale = job.params.mu * max(job.params.K1, job.params.K2) * math.sqrt(area)
        self.stop = StopRequest()
        self.solver = NewtonSolver(problem, config.solver, force_scale, petsc_options,
                                   interrupted=lambda: bool(self.stop.signal),
                                   on_solve=self.hooks.on_solve)
        from drape.reports.oscillation import ShearOscillation
        self.oscillation = ShearOscillation(problem)
        self.oscillation_warned = False
        self.records = []
        self.ledger = WorkLedger()
        self._open_outputs(resume)
        if config.mesh.pattern == "free":
            say(FREE_MESH_WARNING)

    def _open_outputs(self, resume: bool) -> None:
        """The checkpoints (and the state to resume from), the disk's watch and the writer."""
        from drape.io.checkpoint import Checkpoints
        from drape.io.disk import Disk, estimate
        from drape.io.rewind import rewind_outputs
        from drape.io.writer import FIELDS_FILE, ResultsWriter
        config, folder, comm = self.config, self.folder, self.comm
        histories, boundaries = list(self.loading.histories), list(self.motion.boundary_dofs)
        self.checkpoints = Checkpoints(
            folder, self.problem, self.job, config.output.checkpoint_every, self.records,
            self.ledger, self.motion.prescribed_dofs,
            read_row=lambda row: StepRecord.from_row(row, histories, boundaries))
        self.start = self.checkpoints.load() if resume else None   # (step, t, dt)
        if self.start is not None:
            rewind_outputs(folder, self.records, self.start[1], comm)
            ranks = self.checkpoints.saved_ranks
            self.say(f"drape run: resuming from the checkpoint of step {self.start[0]} "
                     f"(t = {self.start[1]:.6g})"
                     + (f", written by {ranks} rank(s), on {comm.size}" if ranks != comm.size
                        else ""))
            if self.checkpoints.changed_controls:
                self.say("drape run: resuming with other numerical controls: "
                         + "; ".join(self.checkpoints.changed_controls))
        cell_fields = {name: field for part in self.parts
                       for name, field in part.cell_fields.items()}
        extra_fields = self.output_fields()
        self.disk = Disk(folder, comm, estimate(
            self.problem, config, len(cell_fields),
            extra_fields.functions.values() if extra_fields is not None else ()))
        self.disk.warn_at_start(self.say)
        self.checkpoints.disk = self.disk
        output = config.output
        self.writer = self.disk.write(FIELDS_FILE, lambda: ResultsWriter(
            folder, self.problem, xdmf=output.xdmf, xdmf_every=output.xdmf_every,
            snapshot=output.snapshot, append=self.start is not None,
            resumed_from_ranks=(self.checkpoints.saved_ranks if self.start is not None
                                else None),
            extra_cell_fields=cell_fields or None, extra_fields=extra_fields),
            root_only=False, fields=True)

    def output_fields(self):
        """The parts' own XDMF fields (JobPart.output_fields: e.g. a stack's plies and
        interfaces), None when no part has any."""
        return next((fields for fields in (part.output_fields(self.problem)
                                           for part in self.parts) if fields is not None), None)

    # --- one step ---------------------------------------------------------------------------
    def record(self, step, t, iterations=0, cutbacks=0, dt=0.0, residual=0.0, seconds=0.0):
        """The converged step's record (collective), appended to the records."""
        from mpi4py import MPI
        problem, comm, ledger, records = self.problem, self.comm, self.ledger, self.records
        force = problem.internal_force()
        f_prescribed = force.array_r[self.motion.prescribed_dofs].copy()
        u_prescribed = problem.u.x.array[self.motion.prescribed_dofs].copy()
        ledger.add_boundary_work(f_prescribed, u_prescribed, comm)
        response = problem.response
        points = response.tau.size
        local_max = float(np.abs(response.gamma_t_deg).max()) if points else 0.0
        strain = float(problem.yarn_strains().max()) if points else 0.0
        record = StepRecord(
            step, t, dt, iterations, cutbacks, residual,
            histories=self.loading.history_values(t),
            reactions={name: tuple(value) for name, value in self.motion.reactions(force).items()},
            external_work=ledger.external, regularisation_work=ledger.regularisation,
            bending_energy=problem.bending_energy(),
            max_shear_angle_deg=comm.allreduce(local_max, op=MPI.MAX),
            max_yarn_strain=comm.allreduce(strain, op=MPI.MAX),
            shear_oscillation_deg=self.oscillation.measure(),
            tau_mean=comm.allreduce(float(response.tau.sum())) / comm.allreduce(points),
            seconds=seconds)
        self._warn_of_oscillation(record)
        for part in self.parts:
            part.measure(record, records, force)
        force.destroy()
        records.append(record)
        return record

    def _warn_of_oscillation(self, record: StepRecord) -> None:
        """Once per run: the shear map oscillates from cell to cell above the threshold."""
        from drape.reports.oscillation import OSCILLATION_WARNING
        value = record.shear_oscillation_deg
        if value > OSCILLATION_WARNING and not self.oscillation_warned:
            self.oscillation_warned = True
            self.say(f"drape run: warning: step {record.step}: the shear angle oscillates from "
                     f"cell to cell by +-{value:.3g} deg (shear_oscillation_deg in steps.csv): "
                     f"above {OSCILLATION_WARNING:g} deg the shear map has a cell-scale pattern, "
                     "a spurious checkerboard (a mesh that locks) or wrinkles only a few cells "
                     "wide; docs/blanks.md")

    def _stop_if_requested(self) -> None:
        from drape.errors import Interrupted
        signal_name = self.stop.requested(self.comm)   # collective: all ranks stop together
        if signal_name:
            raise Interrupted(signal_name)

    def attempt(self, t):
        """Newton's attempt at load factor t from the committed state (a SolveResult)."""
        self._stop_if_requested()
        if self.hooks.on_attempt is not None:
            self.hooks.on_attempt(t)
        # a step whose files would not fit on the disk: the run stops before solving it
        number = self.records[-1].step + 1
        self.disk.check(number, self.checkpoints.due(number))
        self.motion.set_load(t)
        for part in self.parts:
            part.set_load(t)
            part.predict(t)
        result = self.solver.solve()
        # a re-solve stops where the first solve would have: at rtol of its first residual
        floor = self.solver.rtol * result.first_residual
        for part in self.parts:
            result = part.resolve(t, lambda: self.solver.solve(floor), result)
        self._stop_if_requested()   # a signal during the attempt cut it short: not a failure
        return result

    def accept(self, step) -> None:
        """Commit a converged step (a drape.fe.solver.Step), record, write and checkpoint it."""
        from drape.errors import WriteFailed
        from drape.io.writer import FIELDS_FILE, STEPS_FILE
        self.ledger.regularisation += self.problem.regularisation_work()
        self.problem.commit(step.t)
        record = self.record(step.number, step.t, step.iterations, step.cutbacks, step.dt,
                             step.residual, step.seconds)
        try:
            self.disk.write(f"step {step.number}'s results ({STEPS_FILE}, {FIELDS_FILE})",
                            lambda: self.writer.write_step(record, step.t,
                                                           last=step.t >= 1.0 - 1e-12),
                            root_only=False, fields=True)
        except WriteFailed as failure:      # the files end with the step before
            failure.committed = True
            self.records.pop()
            raise
        self.disk.measure((STEPS_FILE, FIELDS_FILE, "fields.h5"))
        try:
            self.checkpoints.step_done(step)
        except WriteFailed as failure:
            failure.committed = True
            raise
        if self.hooks.on_step is not None:
            self.hooks.on_step(record, self.problem)

    # --- the whole run ----------------------------------------------------------------------
    def run(self) -> RunSummary:
        """Solve the load steps from the start (or the checkpoint) to t = 1; see run_job."""
        from drape.errors import InputError, RunFailed, WriteFailed
        from drape.fe.solver import run_load_steps
        from drape.io.disk import write_failed
        if self.hooks.on_start is not None:
            self.hooks.on_start(RunParts(self.job, self.problem, self.solver, self.motion,
                                         self.parts))
        write_failure = None
        # a communicator of its own for the ranks' agreement on an unexpected error (a pending
        # collective on self.comm must not meet it)
        self._agreement = self.comm.Dup() if self.comm.size > 1 else None
        self.stop.install()
        try:
            start = self.start
            if start is None:
                self.motion.set_load(0.0)
                for part in self.parts:
                    part.set_load(0.0)
                self.problem.evaluate()
                self.writer.write_step(self.record(0, 0.0), 0.0)
                start = (0, 0.0, None)
            else:
                for part in self.parts:
                    part.set_load(start[1])
            run_load_steps(self.config.steps, self.loading.breakpoints(), self.attempt,
                           self.accept, self.problem.restore, step0=start[0], t0=start[1],
                           dt0=start[2], log=self.say)
        except WriteFailed as failure:
            write_failure = failure
            raise write_failed(failure, self.writer, self.checkpoints, self.records,
                               self.folder) from None
        except RunFailed as failure:
            raise self._failed(failure) from None
        except InputError:
            raise
        except Exception:
            self._abort_if_alone()
            raise
        finally:
            self.stop.uninstall()
            self.writer.close()
            self.solver.close()
            if write_failure is None:   # after a write failure the resumed run writes them
                self._finish_parts()
            if self._agreement is not None:
                self._agreement.Free()
        self.checkpoints.finished()
        timings = dict(self.problem.timings)
        timings.update({f"count_{k}": v for k, v in self.problem.counts.items()})
        records = self.records
        return RunSummary(records[-1].step, records[-1].t, time.perf_counter() - self.started,
                          self.folder, records, timings)

    def _abort_if_alone(self) -> None:
        """An unexpected error (a bug, a hook's exception) may be raised on one rank only: the
        others then wait in a collective call, and the clean-up below (collective too) would
        hang the run until the job's time limit. Raised on every rank within ALONE_WAIT
        seconds (a hook that stops a run on purpose), the run ends in order; else this rank
        prints its traceback and aborts every rank (exit 1), the converged steps and the last
        checkpoint on disk."""
        if self._agreement is None:
            return
        import sys
        import traceback
        everyone = self._agreement.Ibarrier()
        deadline = time.monotonic() + ALONE_WAIT
        while time.monotonic() < deadline:
            if everyone.Test():
                return
            time.sleep(0.01)
        traceback.print_exc()
        print(f"drape: rank {self.comm.rank}: unexpected error (above), not raised on the "
              f"other ranks within {ALONE_WAIT:g} s; aborting all {self.comm.size} ranks; the "
              f"steps written so far and the last checkpoint are in {self.folder}",
              file=sys.stderr, flush=True)
        self.comm.Abort(1)

    def _failed(self, failure):
        """A step that did not converge, or a signal: the last converged step's snapshot and
        checkpoint; returns the RunFailed (or Interrupted) to raise, saying what is kept."""
        from drape.errors import Interrupted, RunFailed
        self.problem.restore()
        self.problem.evaluate()
        records, folder = self.records, self.folder
        if self.config.output.snapshot != "none":
            self.writer.write_snapshot(records[-1].t)
        saved = self.checkpoints.save_last()
        if isinstance(failure, Interrupted):
            # said before the results files are finished: mpirun, signalled too, may kill
            # the ranks before the last line (drape.io.run_log)
            if saved:
                self.say(f"drape run: {failure} received: the checkpoint of step "
                         f"{records[-1].step} is written; finishing the results files (the "
                         f"same command with --resume goes on)")
            return Interrupted(f"{failure} received; stopped after step {records[-1].step} at "
                               f"t = {records[-1].t:.6g}: results"
                               f"{' and checkpoint' if saved else ''} up to it are in {folder}")
        hint = "".join(part.failure_hint for part in self.parts)
        failed = RunFailed(f"{failure}; results up to t = {records[-1].t:.6g} (step "
                           f"{records[-1].step}) are in {folder}"
                           f"{' (with a checkpoint)' if saved else ''}{hint}")
        failed.resumable = saved
        return failed

    def _finish_parts(self) -> None:
        """Each part's files from the records so far (at least one converged step)."""
        if len(self.records) < 2:
            return
        for part in self.parts:
            self.disk.write(part.files, lambda part=part: part.finish(
                self.folder, self.records, time.perf_counter() - self.started),
                root_only=part.finish_on_root)
