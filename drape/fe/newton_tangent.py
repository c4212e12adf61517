"""The shear tangent that Newton's Jacobian uses near the law's elastic-plastic kink.

Only the Jacobian changes: the residual, and so what a converged step satisfies, is the law's
own (docs/fe-solver.md, ``solver.neutral_loading_band``).
"""

from __future__ import annotations

import numpy as np


def neutral_loading_tangent(consistent, plastic, plastic_increment, elastic, band):
    """The shear tangent d tau / d C12 (N/mm) that Newton's Jacobian uses, per law point.

    A point that the step loads only just past its elastic range (near neutral loading) lies on
    the law's kink: from one Newton iterate to the next it switches between the elastic branch
    (2 mu Ksh, 284 N/mm with the paper's values) and the plastic one (0.01 N/mm at 3 deg,
    0.6 at 20 deg, 7 at 35 deg after a monotonic loading), and with the plastic tangent
    Newton's step overshoots it back onto the elastic branch (on
    the hemisphere, hundreds of points per iteration; docs/benchmarks.md, "Where the slow
    stretch comes from"). Where a point is plastic (``plastic``) by less than ``band`` (rad)
    of plastic shear in the step (``plastic_increment``, from the committed state) this gives
    the geometric mean of the elastic and the consistent tangent, sqrt(elastic * |consistent|);
    elsewhere the consistent tangent. Only the Jacobian changes: the residual, and so what
    a converged step satisfies, is the law's own."""
    consistent = np.asarray(consistent, dtype=float)
    near_neutral = np.asarray(plastic) & (np.abs(plastic_increment) < band)
    return np.where(near_neutral, np.sqrt(elastic * np.abs(consistent)), consistent)
