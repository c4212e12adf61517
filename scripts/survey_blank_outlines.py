"""How many outlines the yarn-aligned clipped lattice meshes (docs/blanks.md).

    .venv/bin/python scripts/survey_blank_outlines.py [--baseline REV]

Meshes 64 random convex polygons (4-8 vertices 50-100 mm from the origin, seed 1) at yarn
angles 0, 17, 30, 45 and -60 deg and element sizes 3.9 and 2.5 mm, the five-sided patch of
tests/test_blanks.py at the same angles and sizes, and triangles with one sharp corner, and
prints how many mesh and why the others are refused. With ``--baseline REV`` the same for the
clipped lattice of that commit (its ``geometry/clipped_lattice.py``, or before that its
``geometry/lattice.py``), and how many meshes both make are the same node for node.
"""

from __future__ import annotations

import argparse
import collections
import importlib.util
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.spatial import ConvexHull

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from drape.errors import InputError  # noqa: E402
from drape.geometry.outline import polygon_outline  # noqa: E402

PATCH = [[-70.0, -40.0], [50.0, -50.0], [60.0, 30.0], [-20.0, 60.0], [-65.0, 20.0]]
ANGLES = (0.0, 17.0, 30.0, 45.0, -60.0)
SIZES = (3.9, 2.5)


def outlines():
    """(name, polygon) of the survey."""
    rng = np.random.default_rng(1)
    for k in range(64):
        n = rng.integers(4, 9)
        phi = np.sort(rng.uniform(0, 2 * np.pi, n))
        points = rng.uniform(50, 100, n)[:, None] * np.column_stack([np.cos(phi), np.sin(phi)])
        yield "random", polygon_outline(points[ConvexHull(points).vertices])
    yield "patch", polygon_outline(PATCH)
    for apex in range(-60, 61, 10):
        yield "triangle", polygon_outline([[-80.0, -40.0], [90.0, -40.0], [float(apex), 60.0]])


def load_baseline(rev: str):
    """The clipped_lattice function of commit ``rev``, loaded from its source."""
    for path in ("geometry/clipped_lattice.py", "geometry/lattice.py"):
        shown = subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:{path}"],
                               capture_output=True, text=True)
        if shown.returncode == 0 and "def clipped_lattice" in shown.stdout:
            file = Path(tempfile.mkdtemp()) / "baseline_lattice.py"
            file.write_text(shown.stdout)
            spec = importlib.util.spec_from_file_location("baseline_lattice", file)
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
            return module.clipped_lattice
    raise SystemExit(f"no clipped_lattice in {rev}")


def survey(mesher):
    """Per outline kind: (meshed, tried, Counter of refusals), and every mesh (None: refused)."""
    counts = collections.defaultdict(lambda: [0, 0, collections.Counter()])
    meshes = []
    for kind, outline in outlines():
        for angle in ANGLES:
            for size in SIZES:
                row = counts[kind]
                row[1] += 1
                try:
                    meshes.append(mesher(outline, angle, size)[0])
                    row[0] += 1
                except InputError as error:
                    meshes.append(None)
                    why = error.problem.split(";")[0].split(" (near")[0]
                    row[2][why.lstrip("0123456789 ")] += 1
    return counts, meshes


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", help="a commit to compare with, e.g. HEAD~1")
    args = parser.parse_args()
    from drape.geometry.clipped_lattice import clipped_lattice
    runs = [("this checkout", clipped_lattice)]
    if args.baseline:
        runs.insert(0, (args.baseline, load_baseline(args.baseline)))
    results = []
    for name, mesher in runs:
        counts, meshes = survey(mesher)
        results.append(meshes)
        print(f"{name}:")
        for kind, (meshed, tried, refusals) in counts.items():
            print(f"  {kind:9s} {meshed:3d} of {tried:3d} meshed; refused: "
                  + (", ".join(f"{n} x {why}" for why, n in refusals.most_common()) or "none"))
    if len(results) == 2:
        both = [(a, b) for a, b in zip(*results) if a is not None and b is not None]
        same = sum(a.shape == b.shape and np.array_equal(a, b) for a, b in both)
        print(f"meshed by both: {len(both)}, of them the same node for node: {same}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
