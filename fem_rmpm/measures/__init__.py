"""Measures of a realization, taken on the deposit: :mod:`.table` declares every measure
once (name, unit, label, kind, subset response, how it is computed); :mod:`.deposit`
selects the points that count and computes the table's measures; :mod:`.geometry`
(surface profile, crest, slip surface, moved area) and :mod:`.blocks` (intact blocks)
hold the computations; :mod:`.deposit3d` the measures of a three-dimensional run and
:mod:`.slides3d` separate slides along the strike of a 3-D deposit (pure functions, not in
the table yet)."""
