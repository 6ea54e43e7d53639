"""The campaign directory: identity (``campaign.json``), layout, lock, records and
``results.csv``."""
from __future__ import annotations

import csv
import dataclasses
import fcntl
import io
import json
import math
import os
import re
import shutil
import socket
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Sequence

from fem_rmpm import scene as S
from fem_rmpm.campaign.cases import CampaignError, Case, realization_seed
from fem_rmpm.io.output import _atomic_write_bytes, write_json
from fem_rmpm.measures import table
from fem_rmpm.scene import Scene, scene_to_dict

__all__ = ["FORMAT", "RECORD_COLUMNS", "result_columns", "column_unit", "write_results",
           "read_results", "import_records"]

FORMAT = "fem_rmpm campaign 1"
#: The columns of ``results.csv`` that describe a realization's run, not its slope, with
#: their units: ``case``, ``index``, ``seed``, ``status`` come first, then the core measures
#: (:func:`fem_rmpm.measures.table.core`), every other scalar measure a record holds (in
#: alphabetical order; profiles go to ``profiles/``), then the rest.
RECORD_COLUMNS = {"case": "-", "index": "-", "seed": "-", "status": "ok | failed",
                  "stop_reason": "-", "steps": "count", "simulated_time": "s",
                  "particles": "count", "frozen_points": "count", "scheme": "-", "error": "-"}
_FIRST = ("case", "index", "seed", "status")
#: Keys that do not change a realization (left out of the campaign identity).
_NOT_IDENTITY = {"montecarlo": ("realizations", "keep_vtk", "cases", "runs_to_rest"),
                 "output": None,
                 "scene": ("description",)}


def _identity_dict(scene: Scene) -> dict:
    return _strip_identity(json.loads(json.dumps(scene_to_dict(scene))))


def _strip_identity(d: dict) -> dict:
    """Drop the keys that do not change a realization (also from stored campaign files)."""
    d = json.loads(json.dumps(d))
    for sec, keys in _NOT_IDENTITY.items():
        if keys is None:
            d.pop(sec, None)
        elif sec in d:
            for k in keys:
                d[sec].pop(k, None)
    return d


def _json_form(v: Any) -> Any:
    """A default value as scene_to_dict writes it (tuples -> lists, inf -> 'inf')."""
    if isinstance(v, (list, tuple)):
        return [_json_form(x) for x in v]
    if isinstance(v, float) and not math.isfinite(v):
        return str(v)
    return v


def _field_default(path: str) -> tuple[bool, Any]:
    """(True, default as written by scene_to_dict) of a scene key like ``solver.kernel``
    or ``soil[0].model``; (False, None) if the key is unknown or has no default."""
    classes = {"scene": S.SceneInfo, "grid": S.GridSpec, "boundary": S.BoundarySpec,
               "soil": S.SoilSpec, "bedrock": S.BedrockSpec,
               "random_field": S.RandomFieldSpec, "solver": S.SolverSpec,
               "montecarlo": S.MonteCarloSpec, "output": S.OutputSpec}
    section, _, name = path.partition(".")
    cls = classes.get(section.split("[")[0])
    if cls is None or "." in name:
        return False, None
    for f in dataclasses.fields(cls):
        if f.name == name and f.default is not dataclasses.MISSING:
            return True, _json_form(f.default)
    return False, None


def _first_difference(a: Any, b: Any, path: str = "") -> str | None:
    """First difference of scene dicts ``a`` (this scene) and ``b`` (the campaign's).
    A key only in ``a`` that holds its default value is no difference: it is a key added
    to fem_rmpm after the campaign started, whose default keeps the old behaviour."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                key = f"{path}.{k}".strip(".")
                if k in a:
                    has, default = _field_default(key)
                    if has and a[k] == default:
                        continue
                return key + (" (only in this scene)" if k in a
                              else " (only in the campaign's scene)")
            d = _first_difference(a[k], b[k], f"{path}.{k}")
            if d:
                return d
        return None
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return f"{path.strip('.')} ({len(a)} vs {len(b)} entries)"
        for i, (x, y) in enumerate(zip(a, b)):
            d = _first_difference(x, y, f"{path}[{i}]")
            if d:
                return d
        return None
    return None if a == b else f"{path.strip('.')} = {a!r} here, {b!r} in the campaign"


def _case_dir(root: Path, case: str, single: bool) -> Path:
    return root if single else root / case


def _record_name(index: int) -> str:
    return f"realization_{index:05d}.json"


@dataclass
class Layout:
    out: Path
    cases: list[Case]

    @property
    def single(self) -> bool:
        return len(self.cases) == 1

    def record(self, case: str, index: int) -> Path:
        return _case_dir(self.out / "records", case, self.single) / _record_name(index)

    def profile(self, case: str, index: int) -> Path:
        return _case_dir(self.out / "profiles", case, self.single) / _record_name(index)

    def vtk(self, case: str, index: int) -> Path:
        return _case_dir(self.out / "vtk", case, self.single) / f"realization_{index:05d}"


def campaign_doc(cases: list[Case], campaign_seed: int) -> dict:
    return {"format": FORMAT, "campaign_seed": int(campaign_seed),
            "seed_rule": "seed_i = SeedSequence([campaign_seed, i]).generate_state(1, "
                         "uint64)[0] >> 1 (fem_rmpm.campaign.realization_seed)",
            "cases": [{"name": c.name, "spec": c.spec, "scene": _identity_dict(c.scene)}
                      for c in cases]}


def check_directory(out: Path, doc: dict, fmt: str = FORMAT) -> bool:
    """Raise CampaignError unless ``out`` is free or holds this campaign (of format ``fmt``);
    True if it exists."""
    meta = out / "campaign.json"
    if out.exists() and not out.is_dir():
        raise CampaignError(f"{out}: --out is a file, not a directory")
    if not meta.exists():
        if out.exists() and any(p.name != ".campaign.lock" for p in out.iterdir()):
            raise CampaignError(f"{out}: directory is not empty and holds no campaign.json "
                                "(not a campaign directory); choose another --out")
        return False
    try:
        old = json.loads(meta.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise CampaignError(f"{meta}: unreadable campaign file ({exc}); choose another "
                            "--out") from None
    if old.get("format") != fmt:
        raise CampaignError(f"{meta}: not a {fmt!r} campaign; choose another --out")
    if old.get("campaign_seed") != doc["campaign_seed"]:
        raise CampaignError(f"{out}: holds a campaign with seed {old.get('campaign_seed')}, "
                            f"this scene has [montecarlo] seed = {doc['campaign_seed']}; "
                            "nothing was changed; choose another --out")
    old_names = [c["name"] for c in old.get("cases", [])]
    new_names = [c["name"] for c in doc["cases"]]
    if old_names != new_names:
        raise CampaignError(f"{out}: holds a campaign of the cases {old_names}, not "
                            f"{new_names}; nothing was changed; choose another --out")
    for o, n in zip(old["cases"], doc["cases"]):
        diff = _first_difference(n["scene"], _strip_identity(o.get("scene", {})))
        if diff:
            where = f"case {n['name']}: " if len(new_names) > 1 else ""
            raise CampaignError(f"{out}: holds the campaign of a different scene ({where}"
                                f"[{diff}]); nothing was changed; choose another --out")
    return True


class Lock:
    """Exclusive, non-blocking flock on ``out/.campaign.lock`` (freed when the process dies)."""

    def __init__(self, out: Path):
        self.path = out / ".campaign.lock"
        self.fh = None

    def __enter__(self):
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.fh = open(self.path, "a+")
        except OSError as exc:
            raise CampaignError(f"{self.path.parent}: cannot write the campaign directory "
                                f"({exc.strerror or exc}); choose another --out") from None
        try:
            fcntl.flock(self.fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self.fh.seek(0)
            who = self.fh.read().strip() or "another process"
            self.fh.close()
            raise CampaignError(f"{self.path.parent}: the campaign is being run by {who}; "
                                "wait for it or choose another --out") from None
        self.fh.seek(0)
        self.fh.truncate()
        self.fh.write(f"pid {os.getpid()} on {socket.gethostname()}\n")
        self.fh.flush()
        return self

    def __exit__(self, *exc):
        fcntl.flock(self.fh, fcntl.LOCK_UN)
        self.fh.close()


def read_record(path: Path) -> dict | None:
    try:
        rec = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    return rec if isinstance(rec, dict) and rec.get("format") == FORMAT else None


def clean_temporaries(out: Path) -> None:
    """Remove temporary files left by a client killed while writing (never a record)."""
    for sub in ("records", "profiles"):
        for p in (out / sub).rglob(".realization_*.tmp"):
            try:
                p.unlink()
            except OSError:
                pass


# --------------------------------------------------------------------------- table and statistics

def _fmt(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "1" if v else "0"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def column_unit(name: str) -> str:
    """The unit of a ``results.csv`` column (a measure's from the table)."""
    return RECORD_COLUMNS.get(name) or table.unit(name)


def result_columns(records: Iterable[dict]) -> list[str]:
    """The columns of ``results.csv`` for ``records`` (see :data:`RECORD_COLUMNS`)."""
    core = table.core()
    extra = sorted({k for r in records for k in (r.get("measures") or {})} - set(core))
    rest = [k for k in RECORD_COLUMNS if k not in _FIRST]
    return [*_FIRST, *core, *extra, *rest]


def _row(rec: dict, columns: Sequence[str]) -> dict:
    m = rec.get("measures") or {}
    return {k: _fmt(m.get(k) if k in m or k not in rec else rec.get(k)) for k in columns}


def write_results(path: Path, records: Iterable[dict], order: Sequence[str]) -> None:
    """``results.csv`` from records, sorted by case (campaign order) and index (atomic),
    without the columns equal in every row; ``results.units.json`` beside it holds the
    unit of every column and the constant columns with their value."""
    rank = {c: i for i, c in enumerate(order)}
    rows = sorted(records, key=lambda r: (rank.get(r["case"], len(rank)), r["index"]))
    columns, constant = _drop_constant(result_columns(rows), rows)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow(_row(r, columns))
    _atomic_write_bytes(path, buf.getvalue().encode())
    _atomic_write_bytes(_sidecar(path), json.dumps(
        {"units": {k: column_unit(k) for k in columns}, "constant": constant,
         "constant_units": {k: column_unit(k) for k in constant}}, indent=1).encode())


def _always_kept() -> set[str]:
    """Columns kept even when constant over the rows (identity and the core measures)."""
    return {*_FIRST, *table.core()}


def _sidecar(path: Path) -> Path:
    """``results.units.json`` beside ``results.csv``: the unit of every column and the
    columns left out because every row had the same value (with that value)."""
    return Path(path).with_name(Path(path).stem + ".units.json")


def _drop_constant(columns: list[str], rows: list[dict]) -> tuple[list[str], dict]:
    """Columns without those (other than :func:`_always_kept`) equal in every row (when
    there are at least 2 rows); returns (columns, {dropped column: its value})."""
    if len(rows) < 2:
        return columns, {}
    kept = _always_kept()
    cells = {k: {_row(r, [k])[k] for r in rows} for k in columns}
    constant = {k: _row(rows[0], [k])[k] for k in columns
                if k not in kept and len(cells[k]) == 1}
    return [k for k in columns if k not in constant], constant


def read_results(path: str | Path) -> list[dict]:
    """Rows of a ``results.csv`` with numbers parsed (empty cells -> None; the measure
    table's flags -> bool); the columns left out as constant (``results.units.json``) are
    restored in every row."""
    rows = []
    side = _sidecar(Path(path))
    constant = json.loads(side.read_text()).get("constant", {}) if side.exists() else {}
    with open(path, newline="") as fh:
        for r in csv.DictReader(fh):
            r = {**r, **constant}               # columns constant over every row
            out: dict[str, Any] = {}
            for k, v in r.items():
                if v == "":
                    out[k] = None
                elif k in ("index", "seed", "steps", "particles", "frozen_points"):
                    out[k] = int(v)
                elif getattr(table.MEASURES.get(k), "kind", None) == "flag":
                    out[k] = v == "1"
                elif k in ("case", "status", "stop_reason", "scheme", "error"):
                    out[k] = v
                elif re.fullmatch(r"-?[0-9]+", v):
                    out[k] = int(v)          # integer measures (floats are written as repr)
                else:
                    out[k] = float(v)
            rows.append(out)
    return rows



# --------------------------------------------------------------------------- importing records

def import_records(src: Path, dst: Path, doc: dict, cases: list[Case]) -> dict[str, int]:
    """Copy the finished records of campaign ``src`` (with their profiles and kept VTK)
    into campaign ``dst`` of identity ``doc`` (:func:`campaign_doc` of ``cases``;
    ``campaign.json`` is written if ``dst`` holds none), for the cases both campaigns have.

    Checked first, nothing copied otherwise (:class:`CampaignError`): ``dst`` is free or
    holds this campaign; ``src`` is a campaign of the same format and campaign seed, and
    each common case has the same scene in both (the identity test of resuming:
    :func:`check_directory`); neither directory is being run (locks).  Each record must
    have the case's name, status ``ok`` and the seed of its index
    (:func:`fem_rmpm.campaign.realization_seed`), else it is skipped.  A record ``dst``
    already holds is kept.  Returns ``{case: records copied}``.  A realization is a pure
    function of scene and seed, so an imported record is the one ``dst`` would compute."""
    src, dst = Path(src), Path(dst)
    try:
        old = json.loads((src / "campaign.json").read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise CampaignError(f"{src}: not a readable campaign ({exc})") from None
    if old.get("format") != FORMAT or old.get("campaign_seed") != doc["campaign_seed"]:
        raise CampaignError(f"{src}: not a {FORMAT!r} campaign with campaign seed "
                            f"{doc['campaign_seed']}; nothing was imported")
    src_names = [c["name"] for c in old.get("cases", [])]
    common = [(c, n) for c, n in zip(cases, doc["cases"]) if c.name in src_names]
    for c, n in common:
        diff = _first_difference(n["scene"], _strip_identity(
            old["cases"][src_names.index(c.name)].get("scene", {})))
        if diff:
            raise CampaignError(f"{src}: case {c.name} has a different scene ([{diff}]); "
                                "nothing was imported")
    lay, copied = Layout(dst, cases), {}
    with Lock(src), Lock(dst):
        check_directory(dst, doc)
        if not (dst / "campaign.json").exists():
            write_json(dst / "campaign.json", doc)
        for c, _ in common:
            copied[c.name] = 0
            for p in sorted(_case_dir(src / "records", c.name,
                                      len(src_names) == 1).glob("realization_*.json")):
                rec = read_record(p)
                if (rec is None or rec.get("case") != c.name or rec.get("status") != "ok"
                        or rec.get("seed") != realization_seed(doc["campaign_seed"],
                                                               int(rec["index"]))
                        or lay.record(c.name, rec["index"]).exists()):
                    continue
                _copy_realization(src, len(src_names) == 1, lay, rec)
                copied[c.name] += 1
    return copied


def _copy_realization(src: Path, src_single: bool, lay: Layout, rec: dict) -> None:
    """Profile and kept VTK first, the record last (a record is what marks it finished)."""
    case, i = rec["case"], int(rec["index"])
    prof = _case_dir(src / "profiles", case, src_single) / _record_name(i)
    if prof.exists():
        _atomic_write_bytes(lay.profile(case, i), prof.read_bytes())
    if rec.get("vtk") and (src / rec["vtk"]).is_dir():
        rel = lay.vtk(case, i).relative_to(lay.out)
        if not lay.vtk(case, i).exists():
            shutil.copytree(src / rec["vtk"], lay.vtk(case, i))
        rec = {**rec, "vtk": str(rel)}
    write_json(lay.record(case, i), rec)
