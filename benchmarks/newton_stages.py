"""Where a forming job's Newton work goes, stage by stage of the stroke: every Newton attempt
(the converged ones and those cut back) with its iterations, seconds and residual history.

    .venv/bin/python benchmarks/newton_stages.py configs/hemisphere.toml OUT \
        --stages 0,20,40,47.5,50 --set output.xdmf=false [--histories OUT.json] [--until MM]

Runs the job (``--set table.key=value`` as ``drape run`` takes it) into the folder OUT, on the
ranks it is started on (rank 0 prints), and records each call of Newton's solve: the stroke it
starts from (mm), converged or not, iterations, seconds, and the residual norms (N) SNES
recorded. It prints, per stage of the stroke (the attempts that start in [a, b) mm): attempts,
Newton iterations (the failed attempts' included), failed attempts and seconds; then each
failed attempt. ``--histories`` writes every attempt's record as JSON, for a closer look (for
instance, how fast the residual falls in the attempts that fail). ``--until MM`` stops the job
after its first converged step at or beyond MM (the stroke's first stretch alone; the results
folder keeps what was written, as after an interruption).

The by-stage figures in docs/benchmarks.md ("Where the full stroke's time goes, by stage")
were taken with it.
"""

from __future__ import annotations

import argparse
import json
import time


def stage_table(records: list[dict], stages: list[float]) -> list[dict]:
    """Sum the attempts per stage [a, b) of the stroke (mm; the last stage includes b)."""
    rows = []
    for i, (a, b) in enumerate(zip(stages[:-1], stages[1:])):
        last = i == len(stages) - 2
        inside = [r for r in records if a <= r["stroke"] < b or (last and r["stroke"] == b)]
        rows.append(dict(stage=(a, b), attempts=len(inside),
                         iterations=sum(r["iterations"] for r in inside),
                         failed=sum(not r["converged"] for r in inside),
                         seconds=sum(r["seconds"] for r in inside)))
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("config")
    parser.add_argument("folder")
    parser.add_argument("--stages", default="0,20,40,47.5,50",
                        help="stage bounds along the stroke, mm (comma-separated)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--histories", help="write every attempt's record to this JSON file")
    parser.add_argument("--until", type=float, metavar="MM",
                        help="stop after the first converged step at or beyond this stroke (mm)")
    args = parser.parse_args(argv)
    stages = [float(s) for s in args.stages.split(",")]

    from mpi4py import MPI

    from drape.forming.press import Forming
    from drape.job import load_job
    from drape.run import run_job

    records, parts = [], {}

    def recording(newton, result):
        records.append(dict(
            stroke=parts["run"].part(Forming).stroke * float(newton.problem.t_committed),
            converged=result.converged, iterations=result.iterations, reason=result.reason,
            seconds=result.seconds,
            history=[float(v) for v in newton.snes.getConvergenceHistory()[0]]))

    class Reached(Exception):
        """The stroke given by --until is reached."""

    def stop_at_until(record, problem):
        if record.columns["stroke"] >= args.until:
            raise Reached

    start = time.perf_counter()
    try:
        run_job(load_job(args.config, overrides=args.set), output=args.folder, overwrite=True,
                on_start=lambda run: parts.update(run=run), on_solve=recording,
                on_step=None if args.until is None else stop_at_until)
    except Reached:
        pass
    finally:
        wall = time.perf_counter() - start
        if MPI.COMM_WORLD.rank == 0:
            report(records, stages, wall)
            if args.histories:
                with open(args.histories, "w") as stream:
                    json.dump(dict(wall=wall, records=records), stream)
    return 0


def report(records: list[dict], stages: list[float], wall: float) -> None:
    print(f"{len(records)} Newton attempts, {sum(r['iterations'] for r in records)} "
          f"iterations, {sum(r['seconds'] for r in records):.1f} s in Newton, "
          f"{wall:.1f} s in all (meshing and JIT included)")
    print("stage (mm)      attempts  iterations  failed        s")
    for row in stage_table(records, stages):
        a, b = row["stage"]
        print(f"{a:6g}-{b:<6g}  {row['attempts']:9d}  {row['iterations']:10d}  "
              f"{row['failed']:6d}  {row['seconds']:7.1f}")
    failed = [r for r in records if not r["converged"]]
    for r in failed:
        h = r["history"]
        print(f"failed at {r['stroke']:.3f} mm: {r['iterations']} iterations, "
              f"{r['seconds']:.1f} s, {r['reason']}, residual {h[0]:.3g} -> {h[-1]:.3g} N"
              if h else f"failed at {r['stroke']:.3f} mm: {r['reason']}")


if __name__ == "__main__":
    raise SystemExit(main())
