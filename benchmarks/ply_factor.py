"""MUMPS's factor of the two-ply hemisphere's Jacobian against what the coupling of two plies
costs at the least (issue 29): is the factor the pattern's or the coupling's?

    .venv/bin/python benchmarks/ply_factor.py

Runs the first load step (the punch 0.5 mm down, one rank) of configs/hemisphere.toml and of
configs/hemisphere_2ply.toml with PETSc writing each Newton iteration's matrix
(``ksp_view_mat``), reads the first of each, and factors with MUMPS as drape does (LU, its
default ordering, PORD here): the single ply; two copies of it uncoupled; two copies coupled
dof to dof with its twin only (the fewest coupling entries any contact of two stacked plies
has); and the stack's own matrix. Printed: the matrix's entries, the factor's entries
(INFOG(29)) and the factorisation's flops (RINFOG(1)).
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def first_matrix(config: str, folder: Path):
    """The first Jacobian of the first load step of a config, as a scipy CSR matrix."""
    import scipy.sparse as sp
    from petsc4py import PETSc
    path = folder / (Path(config).stem + ".bin")
    subprocess.run([sys.executable, "-m", "drape.cli", "run", str(REPO / config), "--quiet",
                    "--output", str(folder / Path(config).stem), "--set", "process.stroke=0.5",
                    "--set", "steps.initial=1", "--set", "steps.maximum=1",
                    "--set", "output.xdmf=false",
                    "--petsc-option", f"ksp_view_mat=binary:{path}"], check=True, cwd=REPO)
    matrix = PETSc.Mat().create(PETSc.COMM_SELF)
    matrix.setType("aij")
    matrix.load(PETSc.Viewer().createBinary(str(path), "r"))
    rows, columns, values = matrix.getValuesCSR()
    return sp.csr_matrix((values, columns, rows), shape=matrix.getSize())


def factor(matrix) -> tuple[int, float]:
    """MUMPS's LU of a scipy matrix: factor entries and flops."""
    from petsc4py import PETSc
    matrix = matrix.tocsr()
    matrix.sort_indices()
    A = PETSc.Mat().createAIJ(size=matrix.shape, comm=PETSc.COMM_SELF,
                              csr=(matrix.indptr.astype(PETSc.IntType),
                                   matrix.indices.astype(PETSc.IntType), matrix.data))
    ksp = PETSc.KSP().create(PETSc.COMM_SELF)
    ksp.setOperators(A)
    ksp.setType("preonly")
    pc = ksp.getPC()
    pc.setType("lu")
    pc.setFactorSolverType("mumps")
    pc.setUp()
    F = pc.getFactorMatrix()
    return F.getMumpsInfog(29), F.getMumpsRinfog(1)


def main() -> int:
    import scipy.sparse as sp
    with tempfile.TemporaryDirectory() as tmp:
        one = first_matrix("configs/hemisphere.toml", Path(tmp))
        stack = first_matrix("configs/hemisphere_2ply.toml", Path(tmp))
    twin = sp.identity(one.shape[0], format="csr") * 1e-3 * abs(one).max()
    cases = {"one ply": one,
             "two plies, uncoupled": sp.block_diag([one, one]),
             "two plies, twin dofs coupled": sp.bmat([[one, twin], [twin, one]]),
             "the stack (drape)": stack}
    print(f"{'':>30} {'entries':>10} {'factor entries':>15} {'flops':>10}")
    for name, matrix in cases.items():
        entries, flops = factor(matrix)
        print(f"{name:>30} {matrix.nnz:>10} {entries:>15} {flops:>10.3g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
