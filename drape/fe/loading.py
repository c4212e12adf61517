"""Prescribed boundary motion as a function of the load factor t in [0, 1] (numpy only).

A job prescribes displacement components (mm) on named boundaries of the blank. Each component
is a formula: a numpy expression in

* ``x``, ``y``: reference coordinates of the node (mm),
* ``t``: the load factor, 0 at the start of the job, 1 at its end,
* ``theta``: the yarn angle of the blank (radians),
* the name of every history of the job (a piecewise-linear function of t, in its own units,
  e.g. a frame angle in degrees),
* ``pi``, ``e`` and the functions in :data:`FUNCTIONS` (sin, cos, radians, ...).

Formulas are parsed once (Python's ``ast``): anything else (attribute access, unknown names,
keyword arguments, strings) is refused with an :class:`~drape.errors.InputError` naming the key.
They are evaluated with numpy on arrays of node coordinates, vectorised.
"""

from __future__ import annotations

import ast
import dataclasses
import math

import numpy as np

from drape.errors import InputError

#: functions a formula may call (numpy's, element-wise)
FUNCTIONS = {
    name: getattr(np, name) for name in (
        "sin", "cos", "tan", "arcsin", "arccos", "arctan", "arctan2", "sinh", "cosh", "tanh",
        "exp", "log", "log10", "sqrt", "abs", "sign", "radians", "degrees", "minimum", "maximum",
        "where", "clip", "floor", "ceil", "hypot")
}
CONSTANTS = {"pi": math.pi, "e": math.e}
#: variables every formula may use, with their meaning (for messages and docs)
VARIABLES = {"x": "reference x (mm)", "y": "reference y (mm)", "t": "load factor in [0, 1]",
             "theta": "yarn angle (rad)"}
COMPONENTS = ("ux", "uy", "uz")

_ALLOWED_NODES = (
    ast.Expression, ast.BinOp, ast.UnaryOp, ast.Call, ast.Name, ast.Load, ast.Constant,
    ast.Add, ast.Sub, ast.Mult, ast.Div, ast.Pow, ast.Mod, ast.FloorDiv, ast.USub, ast.UAdd,
    ast.Compare, ast.Lt, ast.LtE, ast.Gt, ast.GtE, ast.BitAnd, ast.BitOr, ast.Invert,
)


@dataclasses.dataclass(frozen=True)
class History:
    """A piecewise-linear function of the load factor through waypoints (t_i, value_i)."""

    name: str
    t: np.ndarray
    values: np.ndarray

    def __call__(self, t):
        return np.interp(t, self.t, self.values)


class Formula:
    """One displacement component as a numpy expression; ``key``/``source`` locate it in errors."""

    def __init__(self, text: str, names: set[str], *, key: str, source: str | None = None):
        self.text, self.key, self.source = text, key, source
        expected = ("a numpy expression in " + ", ".join(sorted(names)) + ", pi, e and the "
                    "functions " + ", ".join(sorted(FUNCTIONS)))
        try:
            tree = ast.parse(text.strip(), mode="eval")
        except SyntaxError as error:
            raise InputError(f"not an expression ({error.msg})", source=source, key=key,
                             value=text, expected=expected) from None
        for node in ast.walk(tree):
            if not isinstance(node, _ALLOWED_NODES):
                shown = ast.unparse(node) if isinstance(node, ast.expr) else type(node).__name__
                raise InputError(f"'{shown}'"
                                 " is not allowed in a formula", source=source, key=key, value=text,
                                 expected=expected)
            if isinstance(node, ast.Constant) and not isinstance(node.value, (int, float)):
                raise InputError(f"constant {node.value!r} is not a number", source=source, key=key,
                                 value=text, expected=expected)
            if isinstance(node, ast.Call):
                if not isinstance(node.func, ast.Name) or node.func.id not in FUNCTIONS:
                    raise InputError(f"unknown function '{ast.unparse(node.func)}'", source=source,
                                     key=key, value=text, expected=expected)
                if node.keywords:
                    raise InputError("keyword arguments are not allowed", source=source, key=key,
                                     value=text, expected=expected)
            elif isinstance(node, ast.Name) and node.id not in names and node.id not in CONSTANTS \
                    and node.id not in FUNCTIONS:
                raise InputError(f"unknown name '{node.id}'", source=source, key=key, value=text,
                                 expected=expected)
        self._code = compile(tree, f"<{key}>", "eval")

    def __call__(self, namespace: dict) -> np.ndarray:
        scope = dict(FUNCTIONS)
        scope.update(CONSTANTS)
        scope.update(namespace)
        with np.errstate(all="ignore"):
            value = eval(self._code, {"__builtins__": {}}, scope)  # noqa: S307 - checked by ast
        return value


@dataclasses.dataclass(frozen=True)
class Prescribed:
    """Components (ux, uy, uz: Formula or None = free) prescribed on one named boundary."""

    boundary: str
    components: tuple


class Loading:
    """All prescribed motion of a job: histories and the formulas of each named boundary."""

    def __init__(self, histories: list[History], prescribed: list[Prescribed], theta_rad: float):
        self.histories = {h.name: h for h in histories}
        self.prescribed = prescribed
        self.theta = float(theta_rad)

    @classmethod
    def from_config(cls, job, source: str | None = None) -> "Loading":
        """Build from a :class:`drape.job.JobConfig`; formulas are parsed and test-evaluated."""
        histories = []
        for name, spec in job.history.items():
            n = len(spec.values)
            t = np.linspace(0.0, 1.0, n) if spec.t is None else np.asarray(spec.t, dtype=float)
            histories.append(History(name, t, np.asarray(spec.values, dtype=float)))
        names = set(VARIABLES) | {h.name for h in histories}
        prescribed = []
        for i, entry in enumerate(job.boundary):
            formulas = []
            for component in COMPONENTS:
                text = getattr(entry, component)
                formulas.append(None if text is None else
                                Formula(text, names, key=f"boundary[{i}].{component}",
                                        source=source))
            prescribed.append(Prescribed(entry.on, tuple(formulas)))
        loading = cls(histories, prescribed, np.radians(job.blank.yarn_angle))
        loading.check(source)
        return loading

    # -- evaluation ---------------------------------------------------------------------------
    def namespace(self, t: float, overrides: dict | None = None) -> dict:
        # numpy scalars: 1/0 gives inf (refused as not finite), not a Python exception
        scope = {"t": np.float64(t), "theta": np.float64(self.theta)}
        for name, history in self.histories.items():
            scope[name] = np.float64(history(t))
        if overrides:
            scope.update(overrides)
        return scope

    def history_values(self, t: float) -> dict[str, float]:
        return {name: float(h(t)) for name, h in self.histories.items()}

    def evaluate(self, formula: Formula, xy: np.ndarray, t: float, overrides: dict | None = None):
        """Values (mm) of one formula at points xy (n, 2) for load factor t."""
        scope = self.namespace(t, overrides)
        scope["x"], scope["y"] = xy[:, 0], xy[:, 1]
        value = np.broadcast_to(np.asarray(formula(scope), dtype=float), (xy.shape[0],))
        return value

    def breakpoints(self) -> np.ndarray:
        """Load factors a load step must land on: every history waypoint, and 1."""
        points = {1.0}
        for history in self.histories.values():
            points.update(float(v) for v in history.t if 0.0 < v <= 1.0)
        return np.array(sorted(points))

    def check(self, source: str | None = None) -> None:
        """Evaluate every formula at a few points and every breakpoint: errors are input errors."""
        xy = np.array([[0.0, 0.0], [1.0, 0.5], [-2.0, 3.0]])
        for t in np.concatenate([[0.0], self.breakpoints()]):
            for entry in self.prescribed:
                for formula in entry.components:
                    if formula is None:
                        continue
                    try:
                        value = self.evaluate(formula, xy, t)
                    except Exception as error:  # numpy raises many kinds (TypeError, ValueError)
                        raise InputError(f"cannot be evaluated at t = {t:g} ({error})",
                                         source=source,
                                         key=formula.key, value=formula.text,
                                         expected="a formula giving a displacement in mm") from None
                    if not np.all(np.isfinite(value)):
                        raise InputError(f"is not finite at t = {t:g}", source=source,
                                         key=formula.key, value=formula.text,
                                         expected="a formula giving a finite displacement in mm")
