"""Which realizations keep their VTK output (``--keep-vtk K`` or ``--keep-vtk 0,5,9``)."""
from __future__ import annotations

from typing import Sequence

from fem_rmpm.campaign.cases import CampaignError

__all__ = ["parse_keep_vtk", "kept"]


def parse_keep_vtk(text: str | int | Sequence[int] | None, default: int = 0):
    """``None`` -> first ``default``; ``"3"``/3 -> the first 3 of each case;
    ``"0,5,9"`` or a list -> those indices; ``"0"``/``"none"`` -> none.
    Returns an int (first k) or a frozenset of indices."""
    if text is None:
        return int(default)
    if isinstance(text, int) and not isinstance(text, bool):
        if text < 0:
            raise CampaignError(f"--keep-vtk {text}: expected K >= 0 or a list of indices")
        return text
    if isinstance(text, (list, tuple, set, frozenset)):
        idx = [int(i) for i in text]
    else:
        t = str(text).strip().lower()
        if t in ("", "none"):
            return 0
        if "," not in t:
            try:
                k = int(t)
            except ValueError:
                raise CampaignError(f"--keep-vtk {text!r}: expected K (the first K "
                                    "realizations) or indices like 0,5,9") from None
            return parse_keep_vtk(k)
        try:
            idx = [int(s) for s in t.split(",") if s.strip()]
        except ValueError:
            raise CampaignError(f"--keep-vtk {text!r}: expected K (the first K realizations) "
                                "or indices like 0,5,9") from None
    if any(i < 0 for i in idx):
        raise CampaignError(f"--keep-vtk {text!r}: indices must be >= 0")
    return frozenset(idx)


def kept(keep, index: int) -> bool:
    return index < keep if isinstance(keep, int) else index in keep

