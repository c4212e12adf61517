"""The one question every rigid tool answers, and the helpers its answers share (numpy only).

``tool.query(points, offset=None, cutoff=None) -> ContactQuery(gap, normal, closest)``: points
(N, 3) in mm, the tool translated by ``offset`` (3,); the meaning of each field is in
:mod:`drape.forming.surfaces`. Every tool kind (:mod:`drape.forming.axisymmetric`,
:mod:`drape.forming.meshed_search`, :mod:`drape.forming.signed_distance`) returns this.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

import numpy as np


class ContactQuery(NamedTuple):
    """What a tool reports for N points (see the module docstring)."""

    gap: np.ndarray
    normal: np.ndarray
    closest: np.ndarray


class RigidSurface(Protocol):
    name: str

    def query(self, points, offset=None, cutoff: float | None = None) -> ContactQuery: ...


def tool_frame(points, offset) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 3) in the frame of a tool moved by ``offset`` (mm), and that offset (3,)."""
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), not {points.shape}")
    shift = np.zeros(3) if offset is None else np.asarray(offset, dtype=float).reshape(3)
    return points - shift, shift


def unit(v: np.ndarray) -> np.ndarray:
    """The rows of v scaled to unit length (zero rows stay zero)."""
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(norm > 0.0, norm, 1.0)
