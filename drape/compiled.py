"""The kernels drape compiles with numba (the law; the tools' contact and closest points),
warmed up together at install time and in the container image so that the first job does not
compile them."""

from __future__ import annotations


def warm_up() -> None:
    """Compile each kernel, or load it from numba's cache beside its module."""
    from drape.forming import axisymmetric, contact, meshed_search
    from drape.law import kernel
    kernel.warm_up()
    contact.warm_up()
    axisymmetric.warm_up()
    meshed_search.warm_up()
