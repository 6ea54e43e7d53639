"""The MPM schemes: the run vocabulary both share, the explicit and the implicit scheme, volumetric
locking, regularisation, the pore water (``pore_pressure``) and the static FEM reference."""
