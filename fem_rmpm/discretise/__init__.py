"""Discretisation: the background grid, the material points and their seeding, the basis functions
at the points, the points' order, and the contact nodes of frictional bedrock (``contact``); in
three dimensions the hexahedral grid (``grid3d``), its points (``points3d``) and its trilinear
basis (``basis3d``)."""
