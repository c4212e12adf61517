"""What a run writes, one converged step at a time, in its results folder.

* ``fields.xdmf`` / ``fields.h5``: one XDMF time series (time = load factor t): the mesh once,
  then per written step the displacement (mm, nodal) and cell fields (DG0): the shear angle
  gamma_t and the plastic shear angle gamma_p (deg), tau and the yarn tensions S11, S22 (N/mm),
  the deformed warp and weft directions (unit vectors), the active surface (-1 elastic, k the
  surface index; a cell average of its points) -- quadrature values averaged over each cell;
  for a stack of plies also the DG0 ``ply`` and each interface's nodal pressure and slips
  (``extra_fields``, :mod:`drape.forming.stack_reports`). The file is closed after every
  step, so it is readable whenever a step has converged.
* ``steps.csv``: one row per converged step (written and flushed as it converges).
* ``result.npz``: fields gathered on rank 0 and sorted by coordinates, independent of the
  number of ranks (nodes: x, y, u; law points: x, y, tau, gamma_p, gamma_t, ...).
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

FIELDS_FILE = "fields.xdmf"
STEPS_FILE = "steps.csv"
SNAPSHOT_FILE = "result.npz"


class ResultsWriter:
    def __init__(self, folder: Path, problem, *, xdmf: bool = True, xdmf_every: int = 1,
                 snapshot: str = "final", append: bool = False,
                 resumed_from_ranks: int | None = None,
                 extra_cell_fields: dict | None = None, extra_fields=None):
        """``append``: continue the files of a resumed run (rewound to its checkpoint by
        :func:`drape.io.rewind.rewind_outputs`) instead of starting them;
        ``resumed_from_ranks`` the number of ranks that wrote the checkpoint (its fields refer
        to a mesh of that partition: on another number of ranks the mesh is written again,
        :meth:`_mesh_for_this_partition`).
        ``extra_cell_fields``: {name: function returning one value per local cell}, written
        as DG0 fields next to the law's (e.g. the contact pressure of a forming job).
        ``extra_fields``: an object with ``functions`` ({name: DOLFINx Function}) and
        ``update()``, called before each write (a stack's
        :class:`~drape.forming.stack_reports.StackFields`), its functions written too."""
        from dolfinx import fem

        self.folder = Path(folder)
        self.problem = problem
        self.comm = problem.comm
        if self.comm.rank == 0:
            self.folder.mkdir(parents=True, exist_ok=True)
        self.comm.barrier()
        self.xdmf, self.xdmf_every, self.snapshot = xdmf, xdmf_every, snapshot
        self._csv = None
        self._columns = None
        self.append = append
        msh = problem.mesh
        W0 = fem.FunctionSpace(msh, ("DG", 0))
        W3 = fem.VectorFunctionSpace(msh, ("DG", 0), dim=3)
        self.cell_fields = {
            name: fem.Function(space, name=name) for name, space in (
                ("shear_angle_deg", W0), ("plastic_shear_angle_deg", W0), ("tau", W0),
                ("warp_tension", W0), ("weft_tension", W0), ("active_surface", W0),
                ("warp_direction", W3), ("weft_direction", W3))}
        self.extra_cell_fields = dict(extra_cell_fields or {})
        self.extra_fields = extra_fields
        for name in self.extra_cell_fields:
            self.cell_fields[name] = fem.Function(W0, name=name)
        n = problem.n_cells
        self._dg0 = W0.dofmap.list.array[:n]
        self._dg3 = W3.dofmap.list.array[:n]
        #: the XDMF grid of the mesh this run's fields refer to (DOLFINx's default: the first)
        self.mesh_xpath = "/Xdmf/Domain/Grid[@GridType='Uniform'][1]"
        if self.xdmf and not append:
            self._write_mesh("w")
        elif self.xdmf:
            self._mesh_for_this_partition(resumed_from_ranks)
        self.remember_fields()

    def _write_mesh(self, mode: str, name: str | None = None) -> None:
        """The mesh into fields.xdmf/.h5 (``mode`` "w" or "a"), under ``name`` if given."""
        from dolfinx import io
        msh = self.problem.mesh
        stream = io.XDMFFile(self.comm, str(self.folder / FIELDS_FILE), mode)
        default, msh.name = msh.name, name or msh.name
        try:
            stream.write_mesh(msh)
            stream.close()
        except RuntimeError:
            _abandon(stream)
            raise
        finally:
            msh.name = default

    def _mesh_for_this_partition(self, resumed_from_ranks: int | None) -> None:
        """A resumed run's fields are written in its partition's order of nodes and cells,
        which is the same only on the same number of ranks. So on another number M of
        ranks they refer to the mesh written again as grid ``mesh-r<M>`` (once per M: a
        later resume on M ranks finds it); on the checkpoint's number, to that grid if there
        is one, else to the first (the interrupted run's)."""
        name = f"mesh-r{self.comm.size}"
        path = self.folder / FIELDS_FILE
        found = None
        if self.comm.rank == 0 and path.is_file():
            import xml.etree.ElementTree as ET
            found = any(grid.get("Name") == name for grid in ET.parse(path).getroot().iter("Grid"))
        found = self.comm.bcast(found, root=0)
        if found is None:           # no XDMF to continue (written without fields so far)
            return
        if not found and resumed_from_ranks not in (None, self.comm.size):
            self._write_mesh("a", name)
            found = True
        if found:
            self.mesh_xpath = f"/Xdmf/Domain/Grid[@Name='{name}']"

    # --- per step ---------------------------------------------------------------------------------
    def write_step(self, record, t: float, *, last: bool = False) -> None:
        """Append the step's row (a drape.step_record.StepRecord) to steps.csv; write the fields
        if due (every ``xdmf_every`` steps, and the last). If the fields fail (a full disk), the
        row is cut off again."""
        end = self._write_row(record.row())
        try:
            due = last or record.step % self.xdmf_every == 0
            if self.xdmf and due:
                self.write_fields(t)
            if self.snapshot == "every" or (self.snapshot == "final" and last):
                self.write_snapshot(t)
        except BaseException:
            if end is not None:
                self._stream.truncate(end)
            raise

    def _write_row(self, row: dict) -> int | None:
        """Append the row to steps.csv (rank 0), unbuffered; a failed write (a full disk) is
        cut off again, so that the file ends with the last complete row. Returns the file's
        length before the row (rank 0)."""
        if self.comm.rank != 0:
            return None
        path = self.folder / STEPS_FILE
        text = io.StringIO(newline="")
        writer = csv.writer(text)
        if self._csv is None:
            if self.append and path.is_file():
                with path.open(newline="") as stream:
                    self._columns = next(csv.reader(stream))
                self._stream = path.open("ab", buffering=0)
            else:
                self._columns = list(row)
                self._stream = path.open("wb", buffering=0)
                writer.writerow(self._columns)
            self._csv = writer
        writer.writerow([csv_text(row.get(name, "")) for name in self._columns])
        data = text.getvalue().encode()
        end = self._stream.seek(0, io.SEEK_END)
        try:
            while data:
                data = data[self._stream.write(data):]
        except OSError:
            self._stream.truncate(end)
            raise
        return end

    def update_cell_fields(self) -> None:
        """Cell averages of the committed response at the law's points."""
        p = self.problem
        response = p.response
        values = {"shear_angle_deg": response.gamma_t_deg,
                  "plastic_shear_angle_deg": np.degrees(response.trial.gamma_p),
                  "tau": response.tau, "warp_tension": response.S11, "weft_tension": response.S22,
                  "active_surface": response.active_surface}
        averages = {name: p.cell_average(data) for name, data in values.items()}
        averages.update({name: compute() for name, compute in self.extra_cell_fields.items()})
        for name, data in averages.items():
            function = self.cell_fields[name]
            function.x.array[self._dg0] = data
            function.x.scatter_forward()
        warp, weft = p.yarn_directions()
        for name, data in (("warp_direction", warp), ("weft_direction", weft)):
            average = p.cell_average(data)
            average /= np.linalg.norm(average, axis=1)[:, None]
            function = self.cell_fields[name]
            function.x.array[(self._dg3[:, None] * 3 + np.arange(3)).ravel()] = average.ravel()
            function.x.scatter_forward()

    def extra_functions(self) -> list:
        """The functions of ``extra_fields``, updated (none without it)."""
        if self.extra_fields is None:
            return []
        self.extra_fields.update()
        return list(self.extra_fields.functions.values())

    def write_fields(self, t: float) -> None:
        from dolfinx import io
        self.update_cell_fields()
        stream = io.XDMFFile(self.comm, str(self.folder / FIELDS_FILE), "a")
        try:
            for function in [self.problem.u, *self.cell_fields.values(),
                             *self.extra_functions()]:
                stream.write_function(function, t, self.mesh_xpath)
            stream.close()
        except RuntimeError:
            _abandon(stream)
            raise
        self.remember_fields()

    def remember_fields(self) -> None:
        """Rank 0 keeps the text of fields.xdmf as after the last complete write (DOLFINx
        rewrites it whole with every step: a full disk can leave it cut short)."""
        path = self.folder / FIELDS_FILE
        if self.xdmf and self.comm.rank == 0 and path.is_file():
            self._xdmf_text = path.read_text()

    def rewind_fields(self) -> None:
        """Rank 0, after a failed write: fields.xdmf back to its last complete text (in place
        when the disk has no room for a new file)."""
        text = getattr(self, "_xdmf_text", None)
        if self.comm.rank != 0 or text is None:
            return
        from drape.io.atomic import replace_text
        path = self.folder / FIELDS_FILE
        try:
            replace_text(path, text)
        except OSError:
            with path.open("r+b") as stream:
                stream.write(text.encode())
                stream.truncate()

    def write_snapshot(self, t: float) -> None:
        """result.npz: nodal and point fields gathered on rank 0, sorted by coordinates."""
        data = gather_sorted(self.problem)
        if self.comm.rank == 0:     # to a temporary file, renamed: never a cut-off result
            from drape.io.atomic import replace_atomically, savez
            replace_atomically(self.folder / SNAPSHOT_FILE,
                               lambda stream: savez(stream, dict(t=t, **data)))

    def close(self) -> None:
        if self._csv is not None:
            self._stream.close()
            self._csv = None


def gather_sorted(problem) -> dict[str, np.ndarray] | None:
    """Nodal u and point values of the committed response, on rank 0, in the order of
    (ply, x, y) (the same for any number of ranks: the plies of a stack share their x, y);
    None on other ranks. A stack also gets each node's and point's ply (``node_ply``,
    ``point_ply``)."""
    comm = problem.comm
    V = problem.V
    n_owned = V.dofmap.index_map.size_local
    nodes = V.tabulate_dof_coordinates()[:n_owned, :2]
    u = problem.u.x.array.reshape(-1, 3)[:n_owned]
    response = problem.response
    points = problem.point_coordinates
    point_values = np.column_stack([response.tau, np.degrees(response.trial.gamma_p),
                                    response.gamma_t_deg, response.dtau_dC12])
    node_ply, point_ply = _plies(problem, n_owned, len(points))
    gathered = comm.gather((nodes, u, points, point_values, node_ply, point_ply), root=0)
    if comm.rank != 0:
        return None
    nodes, u, points, point_values, node_ply, point_ply = (np.concatenate(part)
                                                           for part in zip(*gathered))
    node_order = _coordinate_order(nodes, node_ply)
    point_order = _coordinate_order(points, point_ply)
    out = {"node_xy": nodes[node_order], "u": u[node_order],
           "point_xy": points[point_order], "tau": point_values[point_order, 0],
           "gamma_p_deg": point_values[point_order, 1],
           "gamma_t_deg": point_values[point_order, 2],
           "dtau_dC12": point_values[point_order, 3]}
    if getattr(problem.blank_mesh, "n_plies", 1) > 1:
        out.update(node_ply=node_ply[node_order], point_ply=point_ply[point_order])
    return out


def _plies(problem, n_owned: int, n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """The ply of each owned node and of each law point (zeros for one ply)."""
    cell_ply = getattr(problem, "cell_ply", None)
    if cell_ply is None or not np.any(cell_ply):
        return np.zeros(n_owned, dtype=np.int32), np.zeros(n_points, dtype=np.int32)
    dofmap = problem.V.dofmap
    cells = dofmap.list.array.reshape(-1, dofmap.dof_layout.num_dofs)
    node_ply = np.zeros(n_owned + dofmap.index_map.num_ghosts, dtype=np.int32)
    node_ply[cells.ravel()] = np.repeat(cell_ply[: len(cells)], cells.shape[1])
    n_cells = problem.n_cells
    point_ply = np.repeat(cell_ply[:n_cells], n_points // n_cells if n_cells else 0)
    return node_ply[:n_owned], point_ply.astype(np.int32)


def _coordinate_order(xy: np.ndarray, ply: np.ndarray) -> np.ndarray:
    scale = max(1.0, float(np.abs(xy).max())) if xy.size else 1.0
    key = np.round(xy / scale, 9)
    return np.lexsort((key[:, 1], key[:, 0], ply))


def _abandon(stream) -> None:
    """Never destroy a DOLFINx XDMFFile whose write failed (a full disk): DOLFINx 0.5's
    destructor closes the HDF5 file again, and when that fails it throws from the destructor,
    which aborts the process (SIGABRT, a C++ backtrace). The file stays open until the process
    ends."""
    import ctypes
    ctypes.pythonapi.Py_IncRef(ctypes.py_object(stream))


def write_table(path: Path, columns, rows: list) -> None:
    """A CSV file of the given columns of ``rows`` (dicts): integers as they are, every other
    value as a float to full precision (repr), so a table reads back to the bit."""
    with Path(path).open("w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(columns)
        for row in rows:
            writer.writerow([row[c] if isinstance(row[c], int) else repr(float(row[c]))
                             for c in columns])


def csv_text(value) -> str:
    """A steps.csv cell: floats (numpy's too) to full precision (repr), the rest as str."""
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    return str(value)
