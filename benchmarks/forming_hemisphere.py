"""Wall time of the hemisphere forming job on 1 and 2 ranks, side by side, with the breakdown
per load step (stroke, Newton iterations, cutbacks, seconds).

    .venv/bin/python benchmarks/forming_hemisphere.py                 # 10 mm, both rank counts
    .venv/bin/python benchmarks/forming_hemisphere.py --stroke 20     # the default job's stroke
    .venv/bin/python benchmarks/forming_hemisphere.py --set mesh.size=2 --ranks 2
    .venv/bin/python benchmarks/forming_hemisphere.py --reference-blas   # + 1 rank, netlib BLAS

Each run is `drape run configs/hemisphere.toml` (through mpirun for 2 ranks) into a temporary
folder; the figures come from its summary.json (wall_time_s: the load steps, after meshing and
the JIT) and steps.csv (seconds per step). The 1-rank run is the baseline of the same call;
``--reference-blas`` adds, first, a 1-rank run with Debian's reference BLAS and LAPACK
(``LD_LIBRARY_PATH`` to their directories, which take precedence over the OpenBLAS that
scripts/install.sh makes the system's choice), to show what the optimised BLAS gives.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import sysconfig
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
CONFIG = REPO / "configs" / "hemisphere.toml"


#: Debian's netlib BLAS and LAPACK (packages libblas3, liblapack3), beside the alternatives,
#: in the multiarch directory of this machine (x86_64-linux-gnu, aarch64-linux-gnu, ...)
_LIB = Path("/usr/lib") / (sysconfig.get_config_var("MULTIARCH") or "x86_64-linux-gnu")
REFERENCE_BLAS = f"{_LIB / 'blas'}:{_LIB / 'lapack'}"


def run(ranks: int, stroke: float, overrides: list[str], folder: Path,
        reference_blas: bool = False) -> dict:
    """One drape run; returns its summary, its steps and the whole process's wall time (s)."""
    command = [sys.executable, "-m", "drape.cli", "run", str(CONFIG), "--output", str(folder),
               "--quiet", "--set", f"process.stroke={stroke:g}", "--set", "output.xdmf=false"]
    for text in overrides:
        command += ["--set", text]
    if ranks > 1:
        command = ["mpirun", "-n", str(ranks), *command]
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1")
    if reference_blas:
        env["LD_LIBRARY_PATH"] = REFERENCE_BLAS + ":" + env.get("LD_LIBRARY_PATH", "")
    started = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, env=env, cwd=REPO)
    seconds = time.perf_counter() - started
    if done.returncode != 0:
        sys.exit(f"forming_hemisphere: the {ranks}-rank run failed:\n{done.stderr}")
    summary = json.loads((folder / "summary.json").read_text())
    with (folder / "steps.csv").open() as stream:
        steps = list(csv.DictReader(stream))
    return {"summary": summary, "steps": steps, "process_s": seconds}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stroke", type=float, default=10.0, help="punch travel (mm)")
    parser.add_argument("--ranks", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="further config overrides (e.g. mesh.size=2)")
    parser.add_argument("--reference-blas", action="store_true",
                        help="add a 1-rank run with Debian's reference BLAS/LAPACK, first")
    args = parser.parse_args(argv)
    columns = ([("1, netlib BLAS", 1, True)] if args.reference_blas else []) + [
        (f"{r} rank(s)", r, False) for r in args.ranks]
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for label, ranks, reference in columns:
            results[label] = run(ranks, args.stroke, args.set, Path(tmp) / f"run{len(results)}",
                                 reference_blas=reference)
    print(f"hemisphere, stroke {args.stroke:g} mm, overrides {args.set or 'none'}")
    print(f"{'':32s}" + "".join(f"{label:>16s}" for label in results))
    rows = [("cells", lambda r: r["summary"].get("cells", "")),
            ("steps", lambda r: r["summary"]["steps"]),
            ("Newton iterations", lambda r: r["summary"]["newton_iterations"]),
            ("cutbacks", lambda r: r["summary"]["cutbacks"]),
            ("load steps wall time (s)", lambda r: f"{r['summary']['wall_time_s']:.1f}"),
            ("whole process (s)", lambda r: f"{r['process_s']:.1f}"),
            ("s per Newton iteration",
             lambda r: "%.3f" % (r['summary']['wall_time_s']
                                 / max(1, r['summary']['newton_iterations']))),
            ("max shear (deg)", lambda r: f"{r['summary']['max_shear_angle_deg']:.3f}"),
            ("max punch force (N)", lambda r: f"{r['summary']['max_punch_force_N']:.3f}")]
    for label, value in rows:
        print(f"{label:32s}" + "".join(f"{str(value(r)):>16s}" for r in results.values()))
    for label, result in results.items():
        print(f"\nper step, {label}: step, stroke (mm), Newton iterations, cutbacks, s")
        for row in result["steps"][1:]:
            print(f"  {row['step']:>4s} {float(row['stroke']):8.3f} {row['newton_iterations']:>4s} "
                  f"{row['cutbacks']:>3s} {float(row['seconds']):8.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
