"""Rigid tool surfaces for contact: signed gap, normal and closest point (numpy and scipy only).

Every tool answers one question, vectorised over points (no Python loop over points)::

    gap, normal, closest = tool.query(points, offset)

* ``points`` (N, 3): current positions x = X + u of the membrane's quadrature points (mm).
* ``offset`` (3,): the tool's current rigid translation (the punch moved by the stroke); the
  tool is stored in its working position, so ``offset`` is (0, 0, -stroke) for the punch.
* ``gap`` (N,): signed distance to the tool's surface, positive in front of it (outside the
  tool's solid), negative inside (penetration).
* ``normal`` (N, 3): unit normal of the tool surface at the closest point, pointing away from
  the tool's solid (the direction the tool pushes the fabric).
* ``closest`` (N, 3): the closest point of the tool's surface, in the global frame.
* ``cutoff`` (mm, optional): exact answers are needed only for points within ``cutoff`` of the
  tool; farther points may get an upper bound of their distance (still > cutoff, positive
  outside). It makes queries of points far from a meshed tool cheap.

Three implementations, each in its own module (this one gathers their names):

* :class:`AxisymmetricSurface` (:mod:`drape.forming.axisymmetric`) -- exact, for tools of
  revolution about the z axis described by an (r, z) profile of segments and arcs (hemisphere
  punch and shank, die with its entry fillet, blank-holder ring). The closest point of a
  surface of revolution lies in the point's meridian half-plane, so the 3-D problem is a 2-D
  closest point on the profile.
* :class:`MeshedSurface` (:mod:`drape.forming.meshed_search`) -- any triangulated surface
  (:class:`TriangleSurface`, :mod:`drape.forming.triangulated`: gmsh tools, STEP files): k-d
  trees on triangle centroids propose candidates, the exact point-triangle projection is
  evaluated over them, and lower bounds certify the answer (candidates are added until they
  do), so the result is the exact closest point of the triangulation. Normals are
  interpolated from vertex normals with the barycentric coordinates of the closest point: a
  continuous normal field.
* :class:`~drape.forming.signed_distance.SignedDistanceSurface`
  (:mod:`drape.forming.signed_distance`, the double dome's solids in
  :mod:`drape.forming.double_dome`) -- exact signed distances of solids made of smooth pieces.

The query's types (:class:`ContactQuery`, :class:`RigidSurface`) are in
:mod:`drape.forming.tool_query`. The method and its accuracy are described in
``docs/contact.md``.
"""

from drape.forming.axisymmetric import Arc, AxisymmetricSurface, Piece, Profile, Segment
from drape.forming.meshed_search import MeshedSurface
from drape.forming.tool_query import ContactQuery, RigidSurface
from drape.forming.triangulated import TriangleSurface, closest_point_on_triangles

__all__ = ["Arc", "AxisymmetricSurface", "ContactQuery", "MeshedSurface", "Piece", "Profile",
           "RigidSurface", "Segment", "TriangleSurface", "closest_point_on_triangles"]
