"""Discretisation: the background grid, the material points and their seeding, the basis functions
at the points, and the points' order."""
