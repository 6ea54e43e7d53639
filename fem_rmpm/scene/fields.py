"""The ``[random_field]`` section of a scene: read it and check it against the soils.

One property (the simple form)::

    [random_field]
    property = "cohesion_peak"       # a parameter of the soil's material model
    distribution = "lognormal"       # "normal" | "lognormal" | "beta" (with low, high)
    cov = 0.3
    theta_v = 0.5                    # m
    anisotropy = 12.0                # xi = theta_h / theta_v

Several cross-correlated properties: the shared keys (correlation structure, field cells,
soil) in ``[random_field]``, one ``[[random_field.properties]]`` table per property (its
marginal, optionally its own ``theta_v`` / ``anisotropy`` / ``correlation`` /
``layering_angle_deg`` and its own ``data``) and the correlation matrix of their standard
Gaussian fields::

    [random_field]
    theta_v = 0.5
    anisotropy = 12.0
    cross_correlation = [[1.0, -0.5], [-0.5, 1.0]]

    [[random_field.properties]]
    property = "cohesion_peak"
    distribution = "lognormal"
    cov = 0.3

    [[random_field.properties]]
    property = "friction_angle_peak"
    distribution = "beta"            # bounded: low <= phi <= high (deg)
    cov = 0.1
    low = 10.0
    high = 35.0

The checks use the material model's parameter declarations: a property must be a numeric
parameter of the model of every soil the field applies to (not a ``*_residual``: the
residual follows its peak in proportion); a parameter with a finite upper bound (an angle)
needs the bounded ``beta`` marginal with ``[low, high]`` inside the declared range; the
soil's value (the field's mean) must lie strictly inside ``(low, high)`` and its standard
deviation ``cov * mean`` must be reachable by a beta distribution there
(``sigma^2 < (mean - low)(high - mean)``).  ``cross_correlation`` must be p x p (p
properties), symmetric, with a unit diagonal, ``|rho| < 1`` off it and positive definite.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from fem_rmpm import materials
from fem_rmpm.scene.spec import PropertyFieldSpec, RandomFieldSpec, Scene
from fem_rmpm.scene.values import _build, _fail

__all__ = ["build_random_field", "check_random_field", "random_field_to_dict"]

#: keys of one property's marginal: in ``[[random_field.properties]]`` when that list is given
_PER_PROPERTY = ("property", "distribution", "cov", "low", "high", "data")


def build_random_field(source: str, data: Any) -> RandomFieldSpec:
    """The :class:`RandomFieldSpec` of a ``[random_field]`` table (types, ranges, choices,
    the shape of ``cross_correlation``); the checks against the soils are
    :func:`check_random_field`."""
    if not isinstance(data, dict):
        raise _fail(source, "random_field", f"expected a table, got {type(data).__name__}")
    data = dict(data)
    props_raw = data.pop("properties", None)
    rho_raw = data.pop("cross_correlation", None)
    props: tuple[PropertyFieldSpec, ...] = ()
    if props_raw is not None:
        if not isinstance(props_raw, list) or not props_raw:
            raise _fail(source, "random_field.properties", "expected one or more "
                        "[[random_field.properties]] tables")
        given = [k for k in _PER_PROPERTY if k in data]
        if given:
            raise _fail(source, f"random_field.{given[0]}", "a property's key in [random_field] "
                        "beside [[random_field.properties]]; allowed: give it in each "
                        "[[random_field.properties]] table")
        props = tuple(_build(source, "random_field.properties", PropertyFieldSpec, d,
                             label=f"random_field.properties[{i}]")
                      for i, d in enumerate(props_raw))
    spec = _build(source, "random_field", RandomFieldSpec, data)
    n = max(len(props), 1)
    rho = () if rho_raw is None else _matrix(source, rho_raw, n)
    return RandomFieldSpec(**{**{f: getattr(spec, f) for f in spec.__dataclass_fields__},
                              "properties": props, "cross_correlation": rho})


def random_field_to_dict(rf: RandomFieldSpec) -> dict:
    """Plain data of the section, as :func:`build_random_field` reads it back: the keys of
    several properties only when they are used (a campaign's identity, which hashes this
    data, does not depend on keys it does not use), the per-property keys of
    ``[random_field]`` not beside them."""
    out = dataclasses.asdict(rf)
    if rf.properties:
        for key in _PER_PROPERTY:
            del out[key]
    else:
        del out["properties"]
    if not rf.cross_correlation:
        del out["cross_correlation"]
    for key in ("box", "theta_strike"):      # written only when given, as above
        if out[key] is None:
            del out[key]
    return out


def _matrix(source: str, value: Any, n: int) -> tuple[tuple[float, ...], ...]:
    """``cross_correlation``: a symmetric positive definite n x n correlation matrix."""
    key = "random_field.cross_correlation"
    allowed = (f"allowed: a symmetric positive definite {n} x {n} matrix (one row per "
               "property, in the order of [[random_field.properties]]) with 1 on the diagonal "
               "and -1 < rho < 1 off it")
    ok = isinstance(value, list) and all(
        isinstance(r, list) and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                    for v in r) for r in value)
    if not ok:
        raise _fail(source, key, f"expected a list of rows of numbers, got {value!r}; {allowed}")
    if len(value) != n or any(len(r) != n for r in value):
        shape = f"{len(value)} x " + "/".join(sorted({str(len(r)) for r in value}) or ["0"])
        raise _fail(source, key, f"shape {shape} for {n} properties; {allowed}")
    R = np.array(value, dtype=float)
    if not np.all(np.isfinite(R)):
        raise _fail(source, key, f"non-finite entries; {allowed}")
    if np.any(np.diag(R) != 1.0):
        raise _fail(source, key, f"diagonal {np.diag(R).tolist()} is not all 1; {allowed}")
    i, j = np.nonzero(R != R.T)
    if len(i):
        raise _fail(source, key, f"not symmetric (row {i[0] + 1}, column {j[0] + 1}: "
                    f"{R[i[0], j[0]]:g} vs {R[j[0], i[0]]:g}); {allowed}")
    off = np.abs(R - np.eye(n))
    if off.max(initial=0.0) >= 1.0:
        i, j = np.unravel_index(np.argmax(off), off.shape)
        raise _fail(source, key, f"|rho| = {off[i, j]:g} >= 1 (row {i + 1}, column {j + 1}); "
                    f"{allowed}")
    lam = float(np.linalg.eigvalsh(R).min())
    if lam <= 1e-12:
        raise _fail(source, key, f"not positive definite (smallest eigenvalue {lam:.3g}); "
                    f"{allowed}")
    return tuple(tuple(float(v) for v in r) for r in value)


def _label(rf: RandomFieldSpec, k: int) -> str:
    return f"random_field.properties[{k}]" if rf.properties else "random_field"


def _scope(s: Scene) -> list:
    rf = s.random_field
    return [so for so in s.soils if rf.soil is None or so.name == rf.soil]


def check_random_field(s: Scene) -> None:
    """Cross checks of the field against the soils and their material models."""
    rf = s.random_field
    names = [so.name for so in s.soils]
    if rf.box is not None:
        half = len(rf.box) // 2                  # 2 (a rectangle) or 3 (a 3-D box)
        lo, hi = rf.box[:half], rf.box[half:]
        if rf.cell_size is None:
            raise _fail(s.source, "random_field.box", "needs random_field.cell_size (the "
                        "field's own cells); allowed: give cell_size, or leave box out")
        if not all(b > a for a, b in zip(lo, hi)):
            form = ("[x0, y0, x1, y1] with x1 > x0 and y1 > y0" if half == 2 else
                    "[x0, y0, z0, x1, y1, z1] with x1 > x0, y1 > y0 and z1 > z0")
            raise _fail(s.source, "random_field.box", f"{list(rf.box)}: allowed: {form} (m)")
    if rf.soil is not None and rf.soil not in names:
        raise _fail(s.source, "random_field.soil", f"{rf.soil!r} is not a soil; allowed: {names}")
    fields = rf.fields()
    seen: dict[str, int] = {}
    for k, f in enumerate(fields):
        key = _label(rf, k)
        if f.property in seen:
            raise _fail(s.source, f"{key}.property", f"{f.property!r} repeats "
                        f"{_label(rf, seen[f.property])}; allowed: each property once")
        seen[f.property] = k
        _check_property(s, key, f)


def _declared(s: Scene, key: str, prop: str):
    """The :class:`~fem_rmpm.materials.Parameter` of ``prop`` in the models of the field's
    soils (the soils without strength, linear elastic, are skipped when not named)."""
    rf = s.random_field
    soils = _scope(s)
    found = []
    for so in soils:
        params = {p.name: p for p in materials.model(so.model).PARAMETERS}
        if prop in params:
            found.append((so, params[prop]))
        elif rf.soil is not None or so.model != "linear_elastic":
            allowed = [p.name for p in params.values()
                       if not p.choices and not p.name.endswith("_residual")]
            raise _fail(s.source, f"{key}.property", f"{prop!r} is not a parameter of model "
                        f"{so.model!r} (soil {so.name!r}); allowed: "
                        + (", ".join(allowed) or "none (this model has no random parameter)"))
    if not found:
        raise _fail(s.source, f"{key}.property", f"{prop!r}: no soil of the field has a model "
                    "with this parameter; allowed: a parameter of the field's soil model")
    p = found[0][1]
    if p.choices or prop.endswith("_residual"):
        raise _fail(s.source, f"{key}.property", f"{prop!r} cannot be random (a choice, or a "
                    "residual that follows its peak in proportion); allowed: a numeric peak "
                    "or other parameter")
    return p, [so for so, _ in found]


def _check_property(s: Scene, key: str, f: RandomFieldSpec) -> None:
    p, soils = _declared(s, key, f.property)
    bounded = math.isfinite(p.high)
    if f.distribution != "beta":
        if f.low is not None or f.high is not None:
            raise _fail(s.source, f"{key}.{'low' if f.low is not None else 'high'}",
                        "bounds are only for distribution = 'beta'; allowed: no low/high "
                        f"with {f.distribution!r}")
        if bounded:
            raise _fail(s.source, f"{key}.distribution", f"{f.distribution!r} for "
                        f"{f.property!r}, whose values are bounded ({p.allowed()}); allowed: "
                        "'beta' with low and high inside that range")
        if f.distribution == "normal" and f.cov > 0.5:
            raise _fail(s.source, f"{key}.cov", f"{f.cov:g} with a normal distribution gives "
                        "negative strengths too often; allowed: cov <= 0.5 or 'lognormal'")
        for so in soils:
            mean = so.value(f.property, p.default)
            if f.distribution == "lognormal" and math.isfinite(mean) and not mean > 0:
                raise _fail(s.source, f"{key}.distribution", f"lognormal field of "
                            f"{f.property!r} with soil {so.name!r} value {mean:g} (its mean); "
                            "allowed: a positive mean, or distribution = 'normal'")
        return
    _check_beta(s, key, f, p, soils)


def _check_beta(s: Scene, key: str, f: RandomFieldSpec, p, soils) -> None:
    for b in ("low", "high"):
        if getattr(f, b) is None:
            raise _fail(s.source, f"{key}.{b}", f"missing; allowed: the {b} bound of the beta "
                        f"distribution of {f.property!r} ({p.allowed()})")
    lo_ok = f.low > p.low or (f.low == p.low and p.low_inclusive)
    hi_ok = f.high < p.high or (f.high == p.high and p.high_inclusive)
    if not (lo_ok and hi_ok) or not f.low < f.high:
        raise _fail(s.source, f"{key}.{'low' if not lo_ok else 'high'}",
                    f"bounds [{f.low:g}, {f.high:g}] of {f.property!r}; allowed: low < high, "
                    f"both in the parameter's range {p.allowed().replace('a number in ', '')}")
    for so in soils:
        mean = so.value(f.property, p.default)
        if not f.low < mean < f.high:
            raise _fail(s.source, f"{key}.low", f"soil {so.name!r} {f.property} = {mean:g} "
                        f"(the field's mean) is not inside (low, high) = ({f.low:g}, "
                        f"{f.high:g}); allowed: low < mean < high")
        sd = f.cov * mean
        if not sd * sd < (mean - f.low) * (f.high - mean):
            raise _fail(s.source, f"{key}.cov", f"{f.cov:g}: standard deviation {sd:g} is too "
                        f"large for a beta distribution on [{f.low:g}, {f.high:g}] with mean "
                        f"{mean:g}; allowed: cov < "
                        f"{math.sqrt((mean - f.low) * (f.high - mean)) / mean:.4g}")
