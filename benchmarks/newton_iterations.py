"""What changes between a forming job's Newton iterations: per iteration of every solve, the
residual norm, the line search's extra residuals, and how many of the law's points and of the
tools' contact points switched branch since the iterate before.

    .venv/bin/python benchmarks/newton_iterations.py configs/hemisphere.toml OUT \
        --set output.xdmf=false [--json OUT.json] [--until MM]

Runs the job (``--set table.key=value`` as ``drape run`` takes it) into the folder OUT, 1 rank,
with a SNES monitor that records at each iterate: |F| (N); the residual evaluations the line
search spent on it (1 for a full Newton step); the law's points that switched between elastic
and plastic, and those whose active surface changed (the Mroz hand-overs), since the previous
iterate; the contact points of each tool that switched between separated, stick and slip; in
a stack, the ply-ply pairs (keyed by direction and slave node) that switched likewise. A
solve is one SNES call: a step's attempt, or a re-solve after the holder moved (``resolve``),
marked as such (a solve starts at the monitor's iterate 0: hooks only). It prints, for all
solves together, iteration by iteration (0 the predictor): the solves still running, the
median contraction |F_k| / |F_k-1|, the line search's extra residuals and the mean switches.
``--json`` keeps every record (docs/speed.md, "Fewer Newton
iterations", was taken from it). ``--tolerance-cap N`` is a code experiment: each solve stops
at min(rtol |F_0|, N).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("config")
    parser.add_argument("folder")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--json", help="write every solve's per-iteration record here")
    parser.add_argument("--until", type=float, metavar="MM",
                        help="stop after the first converged step at or beyond this stroke (mm)")
    parser.add_argument("--petsc-option", action="append", default=[], metavar="NAME[=VALUE]")
    parser.add_argument("--tolerance-cap", type=float, metavar="N",
                        help="a code experiment: each solve stops at min(rtol |F_0|, N) instead "
                        "of rtol |F_0| (rtol lowered at iteration 0, before SNES's test)")
    args = parser.parse_args(argv)

    from drape.fe.solver import parse_option
    from drape.forming.press import Forming
    from drape.job import load_job
    from drape.run import run_job

    parts, solves, current = {}, [], {}

    def branches():
        problem = parts["run"].problem
        response = problem.response
        tools = parts["run"].part(Forming).tool_contact
        contact = {name: r.state.copy() for name, (_, r) in tools.last.items()}
        plies = getattr(problem, "ply_contact", None)
        if plies is not None and plies.counts.get("pairs"):
            # a stack: its pairs' states keyed by (direction, slave node)
            keys, states = [], []
            for i in range(len(plies.directions)):
                slaves = plies.last("slaves", i).astype(np.int64)
                keys.append(slaves * len(plies.directions) + i)
                states.append(plies.last("state", i).astype(int))
            contact["plies"] = (np.concatenate(keys), np.concatenate(states))
        return response.active_surface.copy(), response.trial.active.copy(), contact

    def switched(state, before) -> int:
        """How many points changed state (tools: arrays; plies: pairs found in both)."""
        if not isinstance(state, tuple):
            return int(np.sum(state != before))
        _, here, there = np.intersect1d(state[0], before[0], return_indices=True)
        return int(np.sum(state[1][here] != before[1][there]))

    def monitor(snes, its, norm):
        problem = parts["run"].problem
        if its == 0:        # a new solve: a step's attempt or a holder's re-solve
            start_solve()
        flow, active, contact = branches()
        evaluations = problem.counts["residual"]
        row = dict(norm=float(norm), evaluations=evaluations - current.get("evaluations", 0))
        if "flow" in current:
            plastic, plastic0 = flow >= 0, current["flow"] >= 0
            row["law_to_plastic"] = int(np.sum(plastic & ~plastic0))
            row["law_to_elastic"] = int(np.sum(~plastic & plastic0))
            row["law_surface"] = int(np.sum(active != current["active"]))
            row["contact"] = {name: switched(state, current["contact"][name])
                              for name, state in contact.items()
                              if name in current["contact"]}
            row["in_contact"] = {name: int(np.sum((state[1] if isinstance(state, tuple)
                                                   else state) > 0))
                                 for name, state in contact.items()}
        current.update(flow=flow, active=active, contact=contact, evaluations=evaluations)
        if its == 0 and args.tolerance_cap and norm > 0.0:
            snes.setTolerances(rtol=min(current["rtol"], args.tolerance_cap / norm))
        current["rows"].append(row)

    def attempt(t):
        current["t"] = t
        current["solve_in_step"] = 0

    def start_solve():
        """Called by the monitor at a solve's iterate 0 (before SNES's convergence test)."""
        newton = parts["run"].solver
        kept = {key: current[key] for key in ("t", "solve_in_step") if key in current}
        current.clear()
        current.update(kept, rows=[], rtol=parts["rtol"],
                       evaluations=newton.problem.counts["residual"] - 1)
        newton.snes.setTolerances(rtol=parts["rtol"])

    def on_solve(newton, result):
        forming = parts["run"].part(Forming)
        solves.append(dict(stroke_from=forming.stroke * float(newton.problem.t_committed),
                           stroke_to=forming.stroke * current.get("t", 0.0),
                           resolve=current.get("solve_in_step", 0) > 0,
                           converged=result.converged, iterations=result.iterations,
                           reason=result.reason, rows=current["rows"]))
        t = current.get("t", 0.0)
        current.clear()
        current.update(t=t, solve_in_step=1, rows=[])

    def started(run):
        parts["run"] = run
        parts["rtol"] = run.solver.rtol
        run.solver.snes.setMonitor(monitor)

    class Reached(Exception):
        """The stroke given by --until is reached."""

    def stop_at_until(record, problem):
        if args.until is not None and record.columns["stroke"] >= args.until:
            raise Reached

    options = dict(parse_option(text) for text in args.petsc_option)
    start = time.perf_counter()
    try:
        run_job(load_job(args.config, overrides=args.set), output=args.folder, overwrite=True,
                petsc_options=options, on_start=started, on_attempt=attempt, on_solve=on_solve,
                on_step=stop_at_until)
    except Reached:
        pass
    wall = time.perf_counter() - start
    report(solves, wall)
    if args.json:
        with open(args.json, "w") as stream:
            json.dump(dict(wall=wall, solves=solves), stream)
    return 0


def report(solves: list[dict], wall: float) -> None:
    iterations = sum(s["iterations"] for s in solves)
    print(f"{len(solves)} solves ({sum(s['resolve'] for s in solves)} re-solves, "
          f"{sum(not s['converged'] for s in solves)} failed), {iterations} iterations, "
          f"{wall:.1f} s")
    print(" k  solves  median |F_k|/|F_k-1|  line-search extra  law e->p  p->e  surface  "
          "contact switches  ply pairs")
    deepest = max((len(s["rows"]) for s in solves), default=0)
    for k in range(deepest):
        rows = [s["rows"][k] for s in solves if len(s["rows"]) > k]
        if k == 0:
            first = np.median([r["norm"] for r in rows])
            print(f"{k:2d}  {len(rows):6d}  predictor |F| median {first:.3g} N")
            continue
        ratio = [s["rows"][k]["norm"] / s["rows"][k - 1]["norm"] for s in solves
                 if len(s["rows"]) > k and s["rows"][k - 1]["norm"] > 0]
        mean = {key: np.mean([r.get(key, 0) for r in rows])
                for key in ("evaluations", "law_to_plastic", "law_to_elastic", "law_surface")}
        contact = np.mean([sum(v for name, v in r.get("contact", {}).items() if name != "plies")
                           for r in rows])
        plies = np.mean([r.get("contact", {}).get("plies", 0) for r in rows])
        print(f"{k:2d}  {len(rows):6d}  {np.median(ratio):20.3g}  {mean['evaluations'] - 1:17.2f}"
              f"  {mean['law_to_plastic']:8.1f}  {mean['law_to_elastic']:4.1f}  "
              f"{mean['law_surface']:7.1f}  {contact:8.2f}  {plies:8.2f}")


if __name__ == "__main__":
    raise SystemExit(main())
