"""Throughput of the contact kernels: closest-point queries against the tools, and the law.

    .venv/bin/python benchmarks/contact_search.py [--points 4e5] [--far-points 2e4] [--repeats 2]
                                                  [--workers 1]

Builds the tools with their default meshes (docs/tools.md), then times, on N points each:

* double dome, meshed (drape.forming.surfaces.MeshedSurface) -- the punch and the die:
  - ``contact``: points within +-0.3 mm of the tool's surface (a draped ply in contact);
  - ``near``: points within about +-3 mm (the ply around the contact zone);
  - ``blank``: a flat blank (1 mm under z = 0, over the die's footprint) against the punch in
    its working position: most points are 10-250 mm away (the first load step), with a 5 mm
    cutoff on N points and exact on --far-points points (exact far queries cost about d / h
    candidates per point: d the distance, h the element size);
* hemisphere: the punch and the die, analytic (drape.forming.surfaces.AxisymmetricSurface) and
  meshed,
  on points within +-3 mm of their surfaces;
* the contact law (drape.forming.contact.traction) on N points in contact, half of them slipping.

Times are the best of --repeats (wall clock, after one warm-up on 1000 points); "pairs/pt" is
the number of exact point-triangle projections per point. The machine's load matters: the
figures in docs/contact.md say on what they were taken.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from drape.forming.contact import traction
from drape.geometry.tools import (DoubleDomeTools, HemisphereTools, analytic_tools,
                                  build_tools)
from drape.forming.surfaces import MeshedSurface


def near_points(surface, n, spread, rng):
    """Points spread along the normal (uniform in +-spread) of random points of the surface."""
    tri = surface.triangles[rng.integers(0, len(surface.triangles), n)]
    w = rng.dirichlet([1.0, 1.0, 1.0], n)
    base = np.einsum("ij,ijk->ik", w, surface.nodes[tri])
    normal = np.einsum("ij,ijk->ik", w, surface.normals[tri])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    return base + normal * rng.uniform(-spread, spread, (n, 1))


def timed(label, call, n, repeats, pairs=None):
    best = np.inf
    for _ in range(repeats):
        if pairs is not None:
            pairs.pairs_evaluated = 0
        start = time.perf_counter()
        call()
        best = min(best, time.perf_counter() - start)
    extra = f"  {pairs.pairs_evaluated / n:5.1f} pairs/pt" if pairs is not None else ""
    print(f"  {label:<44s} {best:7.2f} s  {n / best / 1e3:8.1f} k points/s{extra}", flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--points", type=float, default=4e5)
    parser.add_argument("--far-points", type=float, default=2e4)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--workers", type=int, default=1, help="k-d tree threads (-1: all)")
    args = parser.parse_args(argv)
    n = int(args.points)
    rng = np.random.default_rng(1)
    print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"load average {os.getloadavg()[0]:.1f}; N = {n}")
    dd_cfg, dd = built("double dome", DoubleDomeTools())
    hemi_cfg, hemi = built("hemisphere", HemisphereTools())
    time_double_dome(dd, dd_cfg, n, rng, args)
    time_hemisphere(hemi, hemi_cfg, n, rng, args)
    time_contact_law(n, rng, args)


def built(name, config):
    """The tools of ``config`` meshed (their default meshes), with the time it took."""
    start = time.perf_counter()
    tools = build_tools(config)
    print(f"{name} built and meshed in {time.perf_counter() - start:.1f} s: " +
          ", ".join(f"{k} {len(v.triangles)} triangles" for k, v in tools.items()))
    return config, tools


def flat_blank(dd_cfg, count):
    """About ``count`` points on a grid over the die's footprint, 1 mm under the plane z = 0:
    the punch's tips are 1 mm away."""
    side = int(np.sqrt(count * dd_cfg.die_width / dd_cfg.die_length))
    xs = np.linspace(-dd_cfg.die_length / 2, dd_cfg.die_length / 2, max(2, count // side))
    ys = np.linspace(-dd_cfg.die_width / 2, dd_cfg.die_width / 2, side)
    return np.stack(np.meshgrid(xs, ys, [-1.0], indexing="ij"), axis=-1).reshape(-1, 3)


def time_double_dome(dd, dd_cfg, n, rng, args):
    """The meshed punch and die on points near their surfaces, and the punch on a flat blank
    (with a 5 mm cutoff, and exact on --far-points points)."""
    print("double dome, meshed:")
    for name in ("punch", "die"):
        tool = MeshedSurface(dd[name], workers=args.workers)
        tool.query(near_points(dd[name], 1000, 1.0, rng))
        for label, spread in (("contact", 0.3), ("near", 3.0)):
            pts = near_points(dd[name], n, spread, rng)
            timed(f"{name}, {label} (+-{spread} mm)", lambda: tool.query(pts), n, args.repeats,
                  tool)
    punch = MeshedSurface(dd["punch"], workers=args.workers)
    blank = flat_blank(dd_cfg, n)
    timed(f"punch, flat blank ({len(blank)} pts), cutoff 5 mm",
          lambda: punch.query(blank, cutoff=5.0), len(blank), args.repeats, punch)
    few = flat_blank(dd_cfg, int(args.far_points))
    timed(f"punch, flat blank ({len(few)} pts), exact", lambda: punch.query(few), len(few),
          args.repeats, punch)


def time_hemisphere(hemi, hemi_cfg, n, rng, args):
    """The punch and the die, analytic and meshed, on points within +-3 mm of them."""
    print("hemisphere (+-3 mm of the surface):")
    exact = analytic_tools(hemi_cfg)
    for name in ("punch", "die"):
        pts = near_points(hemi[name], n, 3.0, rng)
        timed(f"{name}, analytic", lambda: exact[name].query(pts), n, args.repeats)
        meshed = MeshedSurface(hemi[name], workers=args.workers)
        timed(f"{name}, meshed", lambda: meshed.query(pts), n, args.repeats, meshed)


def time_contact_law(n, rng, args):
    """The penalty-and-friction traction and its tangent on n points in contact."""
    print("contact law:")
    normal = rng.normal(size=(n, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    gap = -rng.uniform(0.0, 1e-3, n)
    slip = rng.normal(size=(n, 3)) * 0.05
    timed("traction and tangent", lambda: traction(gap, normal, slip, 2500.0, 0.2, 0.05), n,
          args.repeats)


if __name__ == "__main__":
    main()
