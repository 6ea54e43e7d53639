"""Output: VTK, JSON summaries, run directories and PNG figures."""
