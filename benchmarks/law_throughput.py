"""Throughput of the vectorised law against a per-point Python loop of the same law.

    .venv/bin/python benchmarks/law_throughput.py [--sizes 1e3,1e4,1e5,1e6] [--loop-sample 2000]

For each number of points N and three kinds of increment, from committed states prepared by a
random cyclic history (not timed):

* elastic   -- a tiny reversal from each committed state: every point stays elastic (what a
               residual evaluation sees where nothing yields);
* forming   -- a 0.2 deg increment continuing each point's last direction: plastic, mostly on
               the surface already active (a typical load step of a forming run);
* cyclic    -- a random +-2 deg increment: reversals, hand-overs between surfaces, detachments.

The vectorised law is timed on all N points: the best of the repeated calls from the same
committed state (what a Newton loop does; the law remembers q, alpha and sin at the committed
angles between calls) and, in brackets, the first call; the loop
(drape.law.pointwise, one point at a time) on a sample of --loop-sample points, whose per-point
time is exact for any N since the loop is linear in N. Prints points per second side by side.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from drape.law.nested_surface import LawState, NestedSurfaceLaw
from drape.law.parameters import MaterialParameters
from drape.law.pointwise import PointwiseLaw


def prepared_states(law, n_points, rng, steps=12):
    """Committed states after a random cyclic history, with each point's last angle and direction."""
    state = LawState.virgin(n_points, law.n)
    angle = np.zeros(n_points)
    step = np.zeros(n_points)
    for _ in range(steps):
        step = rng.normal(0.0, 4.0, n_points)
        angle = np.clip(angle + step, -45.0, 45.0)
        ones = np.ones(n_points)
        state = law.update(state, ones, ones, np.sin(np.radians(angle))).trial
    return state, angle, np.sign(step)


def increments(kind, angle, direction, rng):
    if kind == "elastic":
        return np.sin(np.radians(angle)) - 2e-6 * direction
    if kind == "forming":
        return np.sin(np.radians(angle + 0.2 * direction))
    return np.sin(np.radians(angle + rng.uniform(-2.0, 2.0, angle.size)))


def time_vectorised(law, state, C12, repeats):
    """Best of ``repeats`` calls, the first from a cold start and the others (warm) after the law
    has seen the committed state, as in a Newton loop. Returns (cold, warm, response)."""
    ones = np.ones(C12.size)
    law._committed_cache = None
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        response = law.update(state, ones, ones, C12)
        times.append(time.perf_counter() - start)
    return times[0], min(times[1:] or times), response


def time_loop(reference, state, C12, sample):
    start = time.perf_counter()
    for i in range(sample):
        reference.update(state.gamma_p[i], list(state.centres[:, i]), state.gamma_max_deg[i],
                         1.0, 1.0, C12[i])
    return (time.perf_counter() - start) / sample


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="1e3,1e4,1e5,1e6")
    parser.add_argument("--loop-sample", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--surfaces", type=int, default=2, help="inner surfaces (paper: 2)")
    args = parser.parse_args(argv)
    params = MaterialParameters().with_surfaces(args.surfaces)
    law, reference = NestedSurfaceLaw(params), PointwiseLaw(params)
    rng = np.random.default_rng(2026)
    print(f"law: {params.name}; numpy {np.__version__}")
    print(f"{'points':>9} {'increment':>9} {'plastic':>8} {'vectorised':>12} {'(1st call)':>12}"
          f" {'loop':>12} {'speed-up':>9}")
    print(f"{'':>9} {'':>9} {'share':>8} {'Mpoints/s':>12} {'Mpoints/s':>12} {'Mpoints/s':>12} {'':>9}")
    for size in (int(float(s)) for s in args.sizes.split(",")):
        state, angle, direction = prepared_states(law, size, rng)
        for kind in ("elastic", "forming", "cyclic"):
            C12 = increments(kind, angle, direction, rng)
            cold, seconds, response = time_vectorised(law, state, C12, args.repeats)
            sample = min(size, args.loop_sample)
            per_point = time_loop(reference, state, C12, sample)
            plastic = np.mean(response.active_surface >= 0)
            rate, loop_rate = size / seconds / 1e6, 1.0 / per_point / 1e6
            print(f"{size:>9} {kind:>9} {plastic:>8.2f} {rate:>12.3f} {size / cold / 1e6:>12.3f}"
                  f" {loop_rate:>12.4f} {rate / loop_rate:>8.0f}x", flush=True)


if __name__ == "__main__":
    main()
