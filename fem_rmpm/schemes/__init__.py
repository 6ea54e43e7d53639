"""The MPM schemes: the run vocabulary both share, the explicit and the implicit scheme, volumetric
locking, regularisation and the static FEM reference (``fem``, and ``fem3d`` on hexahedra);
the explicit scheme on hexahedra (``explicit3d``)."""
