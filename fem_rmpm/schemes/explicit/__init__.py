"""The explicit MPM scheme.

:mod:`.reference` the method's step in numpy (map to the nodes, solve on the mesh, map
back and move the points, reset); :mod:`.step` the step the time loop runs, compiled
(:mod:`.kernels`) or numpy; :mod:`.loop` the time loop; :mod:`.threads` the thread
count; :mod:`.stability` the stability (CFL) limit.
"""
