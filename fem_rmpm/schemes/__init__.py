"""The MPM schemes: the run vocabulary both share, the explicit and the implicit scheme, volumetric
locking, regularisation and the static FEM reference."""
