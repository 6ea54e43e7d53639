"""The MPM schemes: the run vocabulary both share, the explicit and the implicit scheme, volumetric
locking, regularisation, the static FEM reference and the nodal contact with frictional bedrock
(``contact``)."""
