"""gmsh plumbing for the tool builders: a scratch model, curvature-based surface sizes, and the
extraction of an oriented triangulated surface with smooth vertex normals.

gmsh is one global session per process. Builders never finalize it (another part of drape may
hold a model open): :func:`scratch_model` initializes gmsh if it is not yet, adds a fresh model,
restores the options it changed and the model that was current, and removes its own model.
"""

from __future__ import annotations

import contextlib
import itertools
import math

import numpy as np

from drape.forming.triangulated import TriangleSurface

_counter = itertools.count()


def _gmsh():
    import gmsh
    return gmsh


def ensure_initialized():
    """Initialize gmsh unless it is running (drape never finalizes it; if someone else did,
    it is initialized again)."""
    gmsh = _gmsh()
    try:
        # gmsh.initialize() sets General.AbortOnError to 2; before it the option reads 0
        running = gmsh.option.getNumber("General.AbortOnError") != 0
    except Exception:   # finalized: start again
        running = False
    if not running:
        gmsh.initialize(readConfigFiles=False)
        gmsh.option.setNumber("General.Terminal", 0)


@contextlib.contextmanager
def scratch_model(prefix: str = "drape-tools", options: dict | None = None):
    """A fresh gmsh model, removed on exit; the options given are set and restored."""
    gmsh = _gmsh()
    ensure_initialized()
    previous = gmsh.model.getCurrent()
    defaults = {"General.Terminal": 0, "General.NumThreads": 1, "Geometry.OCCParallel": 0}
    options = {**defaults, **(options or {})}
    saved = {}
    for key, value in options.items():
        try:
            saved[key] = gmsh.option.getNumber(key)
            gmsh.option.setNumber(key, value)
        except Exception:  # an option this gmsh does not know
            saved.pop(key, None)
    name = f"{prefix}-{next(_counter)}"
    gmsh.model.add(name)
    try:
        yield gmsh
    finally:
        try:
            gmsh.model.mesh.removeSizeCallback()
        except Exception:
            pass
        gmsh.model.setCurrent(name)
        gmsh.model.remove()
        for key, value in saved.items():
            gmsh.option.setNumber(key, value)
        if previous and previous in gmsh.model.list():
            gmsh.model.setCurrent(previous)


# --- mesh sizes from curvature ----------------------------------------------------------------

def face_min_radius(tag: int, samples: int = 13) -> float:
    """Smallest principal radius of curvature of a surface, sampled on a parametric grid
    (inf for a plane). Exact for OCC planes, cylinders, cones, spheres and tori."""
    gmsh = _gmsh()
    lo, hi = gmsh.model.getParametrizationBounds(2, tag)
    u = np.linspace(lo[0], hi[0], samples)
    v = np.linspace(lo[1], hi[1], samples)
    uv = np.stack(np.meshgrid(u, v, indexing="ij"), axis=-1).reshape(-1, 2)
    kmax, kmin, _, _ = gmsh.model.getPrincipalCurvatures(tag, uv.ravel().tolist())
    k = np.abs(np.concatenate([np.asarray(kmax), np.asarray(kmin)]))
    k = k[np.isfinite(k)]
    kappa = float(k.max()) if k.size else 0.0
    return math.inf if kappa < 1e-9 else 1.0 / kappa


def size_for_radius(radius: float, chord_tolerance: float, elements_per_radius: float,
                    min_size: float, max_size: float) -> float:
    """The element size for a face whose smallest curvature radius is ``radius``:
    h = min(sqrt(3 R s), R / n), clamped to [min_size, max_size] (docs/contact.md)."""
    if not math.isfinite(radius):
        return max_size
    h = min(math.sqrt(3.0 * radius * chord_tolerance), radius / elements_per_radius)
    return min(max(h, min_size), max_size)


def mesh_surfaces(meshing, surfaces: list[int] | None = None) -> dict[int, float]:
    """Mesh the model's surfaces (2-D) with one size per face from its curvature; returns the
    sizes used. ``meshing`` is a :class:`geometry.tools.ToolMeshing`."""
    gmsh = _gmsh()
    faces = surfaces if surfaces is not None else [t for _, t in gmsh.model.getEntities(2)]
    sizes = {}
    for tag in faces:
        if meshing.size is not None:
            sizes[tag] = meshing.size
        else:
            sizes[tag] = size_for_radius(face_min_radius(tag), meshing.chord_tolerance,
                                         meshing.elements_per_radius, meshing.min_size,
                                         meshing.max_size)
    curve_size = {}
    for tag, h in sizes.items():
        for _, curve in gmsh.model.getBoundary([(2, tag)], combined=False, oriented=False):
            curve = abs(curve)
            curve_size[curve] = min(curve_size.get(curve, math.inf), h)
    largest = max(sizes.values())

    def size(dim, tag, x, y, z):
        if dim == 2:
            return sizes.get(tag, largest)
        if dim == 1:
            return curve_size.get(tag, largest)
        return largest

    gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
    gmsh.option.setNumber("Mesh.MeshSizeMin", min(sizes.values()))
    gmsh.option.setNumber("Mesh.MeshSizeMax", largest)
    gmsh.model.mesh.setSizeCallback(size)
    gmsh.model.mesh.generate(2)
    return sizes


# --- extraction of an oriented surface with vertex normals ------------------------------------

def _surface_pieces(tags):
    """Per surface: node tags, coordinates, triangles (node tags) and gmsh's normals."""
    gmsh = _gmsh()
    pieces = []
    for tag in tags:
        # interior nodes come with their (u, v); nodes on the surface's boundary curves are
        # projected (getParametrization is slow, and they are few)
        inner_tags, inner_xyz, inner_uv = gmsh.model.mesh.getNodes(
            2, tag, includeBoundary=False, returnParametricCoord=True)
        all_tags, all_xyz, _ = gmsh.model.mesh.getNodes(2, tag, includeBoundary=True,
                                                        returnParametricCoord=False)
        _, tri = gmsh.model.mesh.getElementsByType(2, tag)
        tri = np.asarray(tri, dtype=np.int64).reshape(-1, 3)
        if tri.size == 0:
            continue
        inner_tags = np.asarray(inner_tags, dtype=np.int64)
        all_tags = np.asarray(all_tags, dtype=np.int64)
        all_xyz = np.asarray(all_xyz, dtype=float).reshape(-1, 3)
        on_boundary = ~np.isin(all_tags, inner_tags)
        uv = np.zeros((all_tags.size, 2))
        order = np.argsort(all_tags)
        where_inner = order[np.searchsorted(all_tags[order], inner_tags)]
        uv[where_inner] = np.asarray(inner_uv, dtype=float).reshape(-1, 2)
        done = ~on_boundary
        for _, curve in gmsh.model.getBoundary([(2, tag)], combined=False, oriented=False):
            curve = abs(curve)
            c_tags, _, c_t = gmsh.model.mesh.getNodes(1, curve, includeBoundary=False,
                                                      returnParametricCoord=True)
            if len(c_tags) == 0:
                continue
            try:
                c_uv = gmsh.model.reparametrizeOnSurface(1, curve, list(c_t), tag)
            except Exception:
                continue
            where = order[np.searchsorted(all_tags[order], np.asarray(c_tags, dtype=np.int64))]
            uv[where] = np.asarray(c_uv, dtype=float).reshape(-1, 2)
            done[where] = True
        if not np.all(done):  # corner nodes: project them
            uv[~done] = np.asarray(gmsh.model.getParametrization(
                2, tag, all_xyz[~done].ravel().tolist())).reshape(-1, 2)
        normals = np.asarray(gmsh.model.getNormal(tag, uv.ravel().tolist()),
                             dtype=float).reshape(-1, 3)
        pieces.append((tag, all_tags, all_xyz, tri, normals))
    return pieces


def _components_and_flips(tri, surf_id, n_surf):
    """Relative orientation of surfaces from shared mesh edges: flip[s] in {+1, -1} making the
    triangles of neighbouring surfaces consistently oriented; component id of each surface."""
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    owner = np.tile(surf_id, 3)
    direction = np.where(edges[:, 0] < edges[:, 1], 1, -1)
    key = np.sort(edges, axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    key, owner, direction = key[order], owner[order], direction[order]
    same_as_next = np.all(key[1:] == key[:-1], axis=1)
    # votes[(s, t)] > 0: s and t are consistently oriented as they are
    votes: dict[tuple[int, int], int] = {}
    i = np.nonzero(same_as_next & (owner[1:] != owner[:-1]))[0]
    for s, t, d in zip(owner[i], owner[i + 1], direction[i] * direction[i + 1]):
        pair = (int(min(s, t)), int(max(s, t)))
        votes[pair] = votes.get(pair, 0) + (1 if d < 0 else -1)
    neighbours: dict[int, list[tuple[int, int]]] = {s: [] for s in range(n_surf)}
    for (s, t), v in votes.items():
        if v != 0:
            neighbours[s].append((t, 1 if v > 0 else -1))
            neighbours[t].append((s, 1 if v > 0 else -1))
    flip = np.zeros(n_surf, dtype=int)
    component = np.full(n_surf, -1)
    for start in range(n_surf):
        if component[start] >= 0:
            continue
        component[start] = start
        flip[start] = 1
        stack = [start]
        while stack:
            s = stack.pop()
            for t, relation in neighbours[s]:
                if component[t] < 0:
                    component[t] = start
                    flip[t] = flip[s] * relation
                    stack.append(t)
    return component, flip


def extract_surface(name: str, surface_tags: list[int], side="solid") -> TriangleSurface:
    """The triangulated surface made of the given (meshed) gmsh surfaces, as one
    :class:`TriangleSurface` with its triangles and vertex normals oriented:

    * ``side="solid"``: the surfaces bound solids; normals point out of them (each connected
      piece is oriented so that its enclosed signed volume is positive);
    * ``side=(dx, dy, dz)``: an open surface; each connected piece is oriented so that its
      area-weighted normal points along the given direction (the working side).

    Vertex normals are gmsh's exact surface normals at the nodes (``getNormal``), averaged
    where surfaces meet; where gmsh has none (a parametric pole), the area-weighted normal of
    the triangles around the node.
    """
    pieces = _surface_pieces(surface_tags)
    if not pieces:
        raise ValueError(f"tool '{name}': no triangles in surfaces {surface_tags}")
    nodes, tri, surf_id, node_normals = _merged(pieces)
    component, flip = _components_and_flips(tri, surf_id, len(pieces))
    tri_flip = flip[surf_id]
    tri[tri_flip < 0] = tri[tri_flip < 0][:, ::-1]
    _orient_components(nodes, tri, surf_id, component, side)
    normals = _vertex_normals(nodes, tri, surf_id, node_normals)
    used = np.unique(tri)
    if used.size != len(nodes):  # drop nodes no triangle uses
        remap = np.full(len(nodes), -1)
        remap[used] = np.arange(used.size)
        nodes, normals, tri = nodes[used], normals[used], remap[tri]
    return TriangleSurface(name, nodes, tri, normals)


def _merged(pieces):
    """The pieces' nodes numbered once (by gmsh tag), their triangles in that numbering, each
    surface's oriented along gmsh's normal of it; the surface of each triangle; per surface
    (node indices, gmsh's normals there) where gmsh gives a normal."""
    all_tags = np.unique(np.concatenate([p[1] for p in pieces]))
    nodes = np.zeros((all_tags.size, 3))
    tris, surf_id, node_normals = [], [], []
    for s, (_, node_tags, coords, tri, normals) in enumerate(pieces):
        index = np.searchsorted(all_tags, node_tags)
        nodes[index] = coords
        local = np.searchsorted(all_tags, tri.ravel()).reshape(-1, 3)
        # orient this surface's triangles along gmsh's normal of the surface
        valid = np.all(np.isfinite(normals), axis=1) & (np.linalg.norm(normals, axis=1) > 0.5)
        gnormal = np.zeros((all_tags.size, 3))
        gnormal[index[valid]] = normals[valid]
        a, b, c = (nodes[local[:, k]] for k in range(3))
        tri_n = np.cross(b - a, c - a)
        reference = gnormal[local].sum(axis=1)
        flip = np.einsum("ij,ij->i", tri_n, reference) < 0
        local[flip] = local[flip][:, ::-1]
        tris.append(local)
        surf_id.append(np.full(len(local), s))
        node_normals.append((index[valid], normals[valid]))
    return nodes, np.concatenate(tris), np.concatenate(surf_id), node_normals


def _orient_components(nodes, tri, surf_id, component, side):
    """Turn each connected component's triangles (in place) so that it encloses a positive
    volume (side 'solid') or faces along the direction ``side``."""
    a, b, c = (nodes[tri[:, k]] for k in range(3))
    cross = np.cross(b - a, c - a)
    for comp in np.unique(component):
        in_comp = np.isin(surf_id, np.nonzero(component == comp)[0])
        if isinstance(side, str):
            measure = np.einsum("ij,ij->i", a[in_comp], np.cross(b[in_comp], c[in_comp])).sum()
        else:
            measure = float(np.sum(cross[in_comp] @ np.asarray(side, dtype=float)))
        if measure < 0:
            tri[in_comp] = tri[in_comp][:, ::-1]


def _vertex_normals(nodes, tri, surf_id, node_normals):
    """Unit vertex normals: gmsh's, with each surface's final orientation, averaged over the
    surfaces at a node; the area-weighted triangle normal where gmsh gives none."""
    sums = np.zeros_like(nodes)
    for s, (index, normals) in enumerate(node_normals):
        reference_sign = _surface_sign(tri[surf_id == s], nodes, index, normals)
        np.add.at(sums, index, reference_sign * normals)
    a, b, c = (nodes[tri[:, k]] for k in range(3))
    area_normals = np.cross(b - a, c - a)
    fallback = np.zeros_like(nodes)
    for k in range(3):
        np.add.at(fallback, tri[:, k], area_normals)
    norm = np.linalg.norm(sums, axis=1)
    use_fallback = norm < 0.5
    sums[use_fallback] = fallback[use_fallback]
    return sums / np.linalg.norm(sums, axis=1, keepdims=True)


def _surface_sign(tri, nodes, index, normals) -> float:
    """+1 if gmsh's normals of a surface agree with its (final) triangle orientation, else -1."""
    if len(index) == 0 or len(tri) == 0:
        return 1.0
    lookup = np.zeros((len(nodes), 3))
    lookup[index] = normals
    a, b, c = (nodes[tri[:, k]] for k in range(3))
    agreement = np.einsum("ij,ij->i", np.cross(b - a, c - a), lookup[tri].sum(axis=1)).sum()
    return 1.0 if agreement >= 0 else -1.0


def boundary_surfaces(volumes: list[int]) -> list[int]:
    gmsh = _gmsh()
    faces = gmsh.model.getBoundary([(3, v) for v in volumes], combined=False, oriented=False)
    return sorted({abs(t) for _, t in faces})


def edges_of(gmsh, dim_tags) -> set[int]:
    """Tags of the curves bounding the given (dim, tag) entities (without orientation)."""
    return {abs(t) for _, t in gmsh.model.getBoundary(dim_tags, combined=False, oriented=False)}
