"""Measures of a realization, taken on the deposit."""
