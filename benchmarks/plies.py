"""The two-ply hemisphere against the single-ply job in the same invocation (issue 29): wall
time, Newton iterations, their ratio, and where the stack's time goes.

    .venv/bin/python benchmarks/plies.py                  # 2 ranks, the punch 2 mm down
    .venv/bin/python benchmarks/plies.py --stroke 5 --ranks 1

Both runs are `drape run` through benchmarks/_timed_run.py (under mpirun for 2 ranks) at the
same stroke and steps: configs/hemisphere.toml (one 200 x 200 mm ply) and
configs/hemisphere_2ply.toml (two such plies, 0/90 over +-45). Printed per run: the load
steps' wall time (summary.json's wall_time_s: after meshing and the JIT), Newton iterations,
seconds per iteration; drape's timers (the slowest rank's: law, tools' contact, assemblies,
and the stack's ply_search, ply_forces, ply_assembly, drape.fe.stack_problem); PETSc's LU
factorisations (count, seconds). The ratio is the stack's wall time over the single ply's
(issue 29 aims at 2.5 or less).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
CONFIGS = {"one ply": REPO / "configs" / "hemisphere.toml",
           "two plies": REPO / "configs" / "hemisphere_2ply.toml"}
TIMERS = ("law", "contributions", "residual_assembly", "jacobian_assembly", "ply_search",
          "ply_forces", "ply_assembly")


def run(config: Path, ranks: int, stroke: float, step: float, folder: Path) -> dict:
    """One timed `drape run`: its breakdown (benchmarks/_timed_run.py) and summary.json."""
    breakdown = folder / "breakdown.json"
    command = [sys.executable, str(REPO / "benchmarks" / "_timed_run.py"), str(breakdown),
               "run", str(config), "--output", str(folder / "results"), "--quiet",
               "--set", f"process.stroke={stroke:g}", "--set", f"steps.initial={step:g}",
               "--set", f"steps.maximum={step:g}", "--set", "output.xdmf=false"]
    if ranks > 1:
        command = ["mpirun", "-n", str(ranks), *command]
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1")
    done = subprocess.run(command, capture_output=True, text=True, env=env, cwd=REPO)
    if done.returncode != 0:
        sys.exit(f"plies: the run of {config.name} failed:\n{done.stderr[-3000:]}")
    out = json.loads(breakdown.read_text())
    out["summary"] = json.loads((folder / "results" / "summary.json").read_text())
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ranks", type=int, default=2)
    parser.add_argument("--stroke", type=float, default=2.0, help="punch travel (mm)")
    parser.add_argument("--step", type=float, default=0.25,
                        help="load step, fraction of the stroke (steps.initial = maximum)")
    args = parser.parse_args()
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, config in CONFIGS.items():
            folder = Path(tmp) / name.replace(" ", "_")
            folder.mkdir()
            results[name] = run(config, args.ranks, args.stroke, args.step, folder)
    print(f"hemisphere, the punch {args.stroke:g} mm down in steps of {args.step:g} of it, "
          f"{args.ranks} rank(s)")
    print(f"{'':>20} " + " ".join(f"{name:>12}" for name in results))
    summaries = {name: r["summary"] for name, r in results.items()}
    rows = [("cells", lambda r, s: f"{s['cells']}"),
            ("wall time (s)", lambda r, s: f"{s['wall_time_s']:.1f}"),
            ("Newton iterations", lambda r, s: f"{s['newton_iterations']}"),
            ("s per iteration", lambda r, s: f"{s['wall_time_s'] / s['newton_iterations']:.3f}"),
            ("LU factorisations", lambda r, s: f"{r['events']['MatLUFactorNum']['count']}"),
            ("LU seconds", lambda r, s: f"{r['events']['MatLUFactorNum']['s']:.1f}")]
    rows += [(f"{timer} (s)", lambda r, s, timer=timer: f"{r['timings'].get(timer, 0.0):.2f}")
             for timer in TIMERS]
    for label, value in rows:
        print(f"{label:>20} " + " ".join(f"{value(results[n], summaries[n]):>12}"
                                         for n in results))
    one, two = summaries["one ply"], summaries["two plies"]
    per_iteration = [s["wall_time_s"] / s["newton_iterations"] for s in (one, two)]
    print(f"ratio two plies / one ply: wall time {two['wall_time_s'] / one['wall_time_s']:.2f}, "
          f"per Newton iteration {per_iteration[1] / per_iteration[0]:.2f} (aim: <= 2.5)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
