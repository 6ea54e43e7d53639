"""The MPM schemes: the run vocabulary both share, the explicit and the implicit scheme, volumetric
locking, regularisation, the pore water (``pore_pressure``), the static FEM reference (``fem``,
and ``fem3d`` on hexahedra), the nodal contact with frictional bedrock (``contact``); the
explicit scheme on hexahedra (``explicit3d``)."""
