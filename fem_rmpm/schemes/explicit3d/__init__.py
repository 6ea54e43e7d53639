"""The explicit scheme on hexahedra (three-dimensional scenes): ``loop`` (the time loop),
``kernels`` (the compiled MUSL step), ``elastic`` (the 3-D linear elastic stress update:
small strain and finite-strain Hencky with a 3x3 spectral log / exp)."""
from fem_rmpm.schemes.explicit3d.loop import run_explicit_3d

__all__ = ["run_explicit_3d"]
