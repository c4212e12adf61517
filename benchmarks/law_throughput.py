"""Throughput of the law's compiled kernel, against the same code interpreted and against the
vectorised numpy law of version 1 (the last commit before the kernel).

    .venv/bin/python benchmarks/law_throughput.py [--sizes 1e3,1e4,1e5,1e6] [--baseline REV]

For each number of points N and three kinds of increment, from committed states prepared by a
random cyclic history (not timed):

* elastic   -- a tiny reversal from each committed state: every point stays elastic (what a
               residual evaluation sees where nothing yields);
* forming   -- a 0.2 deg increment continuing each point's last direction: plastic, mostly on
               the surface already active (a typical load step of a forming run);
* cyclic    -- a random +-2 deg increment: reversals, hand-overs between surfaces.

Times are the process's CPU time (time.process_time), not the wall clock: the project's
machines are shared, and the CPU time of a single-threaded call does not count the time other
jobs hold the core. Columns (points per second of CPU time, one core): *compiled*, the best of
--repeats calls from the same
committed state (as in a Newton loop); *interpreted*, the same kernel with NUMBA_DISABLE_JIT=1
in a subprocess, on a sample of --sample points (its time is linear in N); *v1 numpy*, the
vectorised law of ``git show REV:drape/law/nested_surface.py`` (version 1 of the reading, so
its plastic work differs: a baseline of speed, not of results), best of --repeats calls. The
first compiled call of the process (numba's cache loaded, or the compilation) is printed too.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
#: the last commit with the vectorised law of version 1
BASELINE = "7cc2b0a"


def prepared(law_module, params, n_points, seed, steps=12):
    """Committed states after a random cyclic history, each point's last angle and direction."""
    law = law_module.NestedSurfaceLaw(params)
    rng = np.random.default_rng(seed)
    state = law_module.LawState.virgin(n_points, law.n)
    angle, step = np.zeros(n_points), np.zeros(n_points)
    for _ in range(steps):
        step = rng.normal(0.0, 4.0, n_points)
        angle = np.clip(angle + step, -45.0, 45.0)
        ones = np.ones(n_points)
        state = law.update(state, ones, ones, np.sin(np.radians(angle))).trial
    return law, state, angle, np.sign(step), rng


def increment(kind, angle, direction, rng):
    if kind == "elastic":
        return np.sin(np.radians(angle)) - 2e-6 * direction
    if kind == "forming":
        return np.sin(np.radians(angle + 0.2 * direction))
    return np.sin(np.radians(angle + rng.uniform(-2.0, 2.0, angle.size)))


def rates(law_module, params, size, repeats, seed=2026):
    """{kind: (points/s, plastic share)} for one law module, best of ``repeats`` calls."""
    law, state, angle, direction, rng = prepared(law_module, params, size, seed)
    out = {}
    for kind in ("elastic", "forming", "cyclic"):
        C12 = increment(kind, angle, direction, rng)
        ones = np.ones(size)
        best = np.inf
        for _ in range(repeats):
            start = time.process_time()
            response = law.update(state, ones, ones, C12)
            best = min(best, time.process_time() - start)
        out[kind] = (size / best, float(np.mean(response.active_surface >= 0)))
    return out


def baseline_module(revision):
    """The vectorised law of ``revision``, imported from git under another name."""
    source = subprocess.run(["git", "show", f"{revision}:drape/law/nested_surface.py"],
                            cwd=REPO, check=True, capture_output=True, text=True).stdout
    path = Path(tempfile.mkdtemp()) / "law_v1.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("law_v1", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules["law_v1"] = module          # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def interpreted_rates(surfaces, sample):
    """The kernel with numba's JIT disabled, in a subprocess (the switch is read at import)."""
    code = ("import json, sys; sys.path.insert(0, %r); import law_throughput as b; "
            "from drape.law import nested_surface as m; "
            "from drape.law.parameters import MaterialParameters as P; "
            "print(json.dumps(b.rates(m, P().with_surfaces(%d), %d, 1)))"
            % (str(Path(__file__).parent), surfaces, sample))
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    output = subprocess.run([sys.executable, "-c", code], env=env, check=True,
                            capture_output=True, text=True).stdout
    return {k: tuple(v) for k, v in json.loads(output.splitlines()[-1]).items()}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="1e3,1e4,1e5,1e6")
    parser.add_argument("--sample", type=int, default=2000, help="points for the interpreted run")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--surfaces", type=int, default=2, help="inner surfaces (paper: 2)")
    parser.add_argument("--baseline", default=BASELINE, help="git revision of the v1 numpy law")
    args = parser.parse_args(argv)

    from drape.law import nested_surface
    from drape.law.parameters import MaterialParameters
    params = MaterialParameters().with_surfaces(args.surfaces)
    start = time.perf_counter()
    law = nested_surface.NestedSurfaceLaw(params)
    law.update(nested_surface.LawState.virgin(1, law.n), np.ones(1), np.ones(1), np.ones(1) * 0.3)
    print(f"law: {params.name}; first compiled call {time.perf_counter() - start:.2f} s")
    interpreted = interpreted_rates(args.surfaces, args.sample)
    v1 = baseline_module(args.baseline)
    print(f"{'points':>9} {'increment':>9} {'plastic':>8} {'compiled':>10} {'interpreted':>12}"
          f" {'v1 numpy':>10} {'compiled/v1':>12}")
    print(f"{'':>9} {'':>9} {'share':>8} {'Mpoints/s':>10} {'Mpoints/s':>12} {'Mpoints/s':>10}")
    for size in (int(float(s)) for s in args.sizes.split(",")):
        compiled = rates(nested_surface, params, size, args.repeats)
        old = rates(v1, params, size, args.repeats)
        for kind, (rate, plastic) in compiled.items():
            print(f"{size:>9} {kind:>9} {plastic:>8.2f} {rate / 1e6:>10.2f} "
                  f"{interpreted[kind][0] / 1e6:>12.4f} {old[kind][0] / 1e6:>10.3f} "
                  f"{rate / old[kind][0]:>11.1f}x", flush=True)


if __name__ == "__main__":
    main()
