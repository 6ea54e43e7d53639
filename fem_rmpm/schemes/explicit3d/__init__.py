"""The explicit scheme on hexahedra (three-dimensional scenes): ``loop`` (the time loop),
``step`` (the compiled MUSL step on one or two threads) with its stages in ``kernels``
(map, nodal solve, map back) and ``stress3d`` (the stress pass), ``elastic`` (the 3-D
elastic update: small strain and finite-strain Hencky with a 3x3 spectral log / exp),
``plastic`` (the returns)."""
from fem_rmpm.schemes.explicit3d.loop import run_explicit_3d

__all__ = ["run_explicit_3d"]
