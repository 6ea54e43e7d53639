"""Discretisation: the background grid, the material points and their seeding, the basis functions
at the points, and the points' order; in three dimensions the hexahedral grid (``grid3d``), its
points (``points3d``) and its trilinear basis (``basis3d``)."""
