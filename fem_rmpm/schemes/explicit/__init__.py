"""The explicit MPM scheme: the time loop, its compiled kernels and the stability (CFL) limit."""
