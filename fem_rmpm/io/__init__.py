"""Output: VTK, JSON summaries, run directories and PNG figures; ``output3d``: the
hexahedral grid."""
