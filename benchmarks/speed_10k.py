"""The default hemisphere against the 10k-cell hemisphere of an earlier commit, side by side
(issue 27: the default hemisphere at >= 10 000 cells, full stroke, in about 60 s on 2 ranks).

    .venv/bin/python benchmarks/speed_10k.py                       # 2 ranks, one pair of runs
    .venv/bin/python benchmarks/speed_10k.py --rounds 2 --ranks 2
    .venv/bin/python benchmarks/speed_10k.py --baseline none --ranks 1 2 4   # this tree only

"new" is `drape run configs/hemisphere.toml` of this checkout, as shipped; "base" is the same
command in a checkout of ``--baseline`` (default d648e27, main before issue 27) with
``--set mesh.size=2`` (10 000 cells, its 10k benchmark's mesh), made once with `git worktree
add --detach` in ``--baseline-tree`` and run by this checkout's Python with PYTHONPATH at it
(the same PETSc, MUMPS and numba; the printed drape path shows which package ran). Both get
``--set output.xdmf=false`` and ``--quiet``; further ``--set`` go to both. The runs alternate
(base, new, base, new, ...) so that a drifting machine load falls on both. Each run goes
through benchmarks/_timed_run.py, which gives its breakdown: PETSc's log of the factorisations,
residual and Jacobian evaluations (the slowest rank's seconds), drape's timers of the law and
the tools' contact inside the residuals, and summary.json's wall_time_s (the load steps,
after meshing and the JIT) and results. The ratio is base's wall_time_s over new's, per round.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
TIMED = REPO / "benchmarks" / "_timed_run.py"
BASELINE = "d648e27"


def baseline_tree(commit: str, folder: Path) -> Path:
    """A detached worktree of ``commit`` at ``folder`` (made once, reused)."""
    if not (folder / "drape" / "__init__.py").exists():
        subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", str(folder),
                        commit], check=True, capture_output=True)
    return folder


def run(tree: Path, ranks: int, overrides: list[str], folder: Path) -> dict:
    """One timed `drape run` of ``tree``'s configs/hemisphere.toml; its summary and breakdown."""
    breakdown = folder.with_suffix(".json")
    command = [sys.executable, str(TIMED), str(breakdown), "run",
               str(tree / "configs" / "hemisphere.toml"), "--output", str(folder),
               "--overwrite", "--quiet", "--set", "output.xdmf=false"]
    for text in overrides:
        command += ["--set", text]
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1",
               PYTHONPATH=str(tree) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    if ranks > 1:
        command = ["mpirun", "-n", str(ranks), "-x", "PYTHONPATH", *command]
    started = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, env=env, cwd=tree)
    seconds = time.perf_counter() - started
    if done.returncode != 0:
        sys.exit(f"speed_10k: the run of {tree} on {ranks} rank(s) failed:\n{done.stderr}")
    summary = json.loads((folder / "summary.json").read_text())
    return {"summary": summary, "breakdown": json.loads(breakdown.read_text()),
            "process_s": seconds}


def report(label: str, result: dict) -> str:
    s, b = result["summary"], result["breakdown"]
    events, timings = b["events"], b["timings"]
    factor = events["MatLUFactorNum"]
    if events["MatCholeskyFactorNum"]["count"]:
        factor = events["MatCholeskyFactorNum"]
    draw = s["draw_in_mm"]
    mids = [v for k, v in draw.items() if k.startswith("mid")]
    corners = [v for k, v in draw.items() if k.startswith("corner")]
    lines = [
        f"{label}: {s['cells']} cells, {s['ranks']} rank(s), "
        f"drape from {Path(b['drape_file']).parent}",
        f"  wall_time_s {s['wall_time_s']:.1f} (whole process {result['process_s']:.1f} s, "
        f"processor {b['cpu_s']:.1f} s over the ranks); "
        f"{s['steps']} steps, {s['newton_iterations']} Newton iterations, "
        f"{s['cutbacks']} cutbacks, "
        f"{events['SNESSolve']['count']} Newton solves (holder re-solves and cut-back attempts "
        f"included)",
        f"  factorisations {factor['count']:5d} {factor['s']:7.1f} s"
        f"  ({factor['s'] / max(factor['count'], 1):.3f} s each)",
        f"  triangular solves {events['MatSolve']['count']:5d} {events['MatSolve']['s']:7.1f} s",
        f"  residuals      {events['SNESFunctionEval']['count']:5d} "
        f"{events['SNESFunctionEval']['s']:7.1f} s   of which the law "
        f"{timings.get('law', 0.0):.1f} s ({timings.get('count_law', 0)} calls), contact "
        f"{timings.get('contributions', 0.0):.1f} s",
        f"  Jacobians      {events['SNESJacobianEval']['count']:5d} "
        f"{events['SNESJacobianEval']['s']:7.1f} s",
        f"  results: max shear {s['max_shear_angle_deg']:.3f} deg, max punch force "
        f"{s['max_punch_force_N']:.2f} N, draw-in mid-sides {min(mids):.3f}-{max(mids):.3f} mm, "
        f"corners {min(corners):.3f}-{max(corners):.3f} mm",
    ]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", default=BASELINE,
                        help=f"commit to compare against (default {BASELINE}); none: no baseline")
    parser.add_argument("--baseline-tree", type=Path,
                        default=Path(tempfile.gettempdir()) / "drape-baseline",
                        help="where its worktree is (made if missing)")
    parser.add_argument("--baseline-set", action="append", default=["mesh.size=2"],
                        metavar="KEY=VALUE",
                        help="the baseline's overrides, after mesh.size=2")
    parser.add_argument("--ranks", type=int, nargs="+", default=[2])
    parser.add_argument("--rounds", type=int, default=1)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="further overrides for both")
    args = parser.parse_args(argv)
    base = None
    if args.baseline != "none":
        base = baseline_tree(args.baseline, args.baseline_tree.resolve())
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for round_ in range(args.rounds):
            for ranks in args.ranks:
                pair = {}
                if base is not None:
                    pair["base"] = run(base, ranks, args.baseline_set + args.set,
                                       Path(tmp) / f"base{round_}_{ranks}")
                pair["new"] = run(REPO, ranks, args.set, Path(tmp) / f"new{round_}_{ranks}")
                results.append((round_, ranks, pair))
                print(f"--- round {round_ + 1}, {ranks} rank(s); load average "
                      f"{os.getloadavg()[0]:.2f}")
                for label, result in pair.items():
                    shipped = " ".join(args.set) or "as shipped"
                    name = (f"base ({args.baseline}, {' '.join(args.baseline_set + args.set)})"
                            if label == "base" else f"new (this checkout, {shipped})")
                    print(report(name, result))
                if "base" in pair:
                    ratio = (pair["base"]["summary"]["wall_time_s"]
                             / pair["new"]["summary"]["wall_time_s"])
                    print(f"  ratio base / new wall_time_s: {ratio:.2f}")
                sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
