"""Run directories that never claim a success they do not hold.

A run writes into a fresh (absent or empty) directory, or refuses one that holds
anything (:class:`RunDirError`, exit 2 on the command line, nothing changed);
``force=True`` (``--force``) replaces the run in it.  The sequence is:

1. :func:`check_run_dir` — before anything is computed or written: ``out`` must not
   be a file, and must be absent or empty unless ``force``;
2. :func:`start_run_dir` — creates the directory and writes ``summary.json`` with
   ``"status": "running"`` *first* (atomically, replacing an older summary), then
   deletes the files of the earlier run and any temporaries a killed writer left
   (only the names a run writes, :data:`RUN_FILES`; other files are left alone);
3. the run writes its VTK and figures; the final ``summary.json`` (``"ok"`` or
   ``"failed"``, with ``"files"``: every file the run wrote) is written *last*.

A run stopped by Ctrl-C or SIGTERM rewrites its summary as ``"interrupted"``
(:func:`mark_interrupted`).  A run killed at any point therefore leaves either the
earlier, complete run untouched, or a summary saying ``"running"`` or
``"interrupted"``: never an ``"ok"`` beside output of another run or beside partial
output.
"""
from __future__ import annotations

import contextlib
import fnmatch
import json
import os
import shutil
from pathlib import Path

from fem_rmpm.io.output import write_json
from fem_rmpm.runtime.errors import InputError
from fem_rmpm.scene import SceneError

__all__ = ["RunDirError", "RUN_FILES", "check_run_dir", "start_run_dir", "run_files",
           "output_dir_for", "make_dir", "mark_interrupted"]

#: File name patterns a run writes (and ``--force`` removes); ``.*.tmp*``: temporaries.
RUN_FILES = ("summary.json", "particles.pvd", "particles_*.vtu", "grid.vtu", "fem.vtu",
             "plastic_shear_strain.png", "profile.png", ".*.tmp*", ".*.tmp")


class RunDirError(InputError):
    """The output directory cannot take this run (a file, or it holds another run)."""


def _is_run_file(name: str) -> bool:
    return any(fnmatch.fnmatchcase(name, pat) for pat in RUN_FILES)


def _writable_problem(out: Path) -> str | None:
    """Why ``out`` cannot be created or written into (a dangling symbolic link, a parent
    that is a file, no write permission), or None.  Changes nothing."""
    if out.is_symlink() and not out.exists():
        return (f"is a symbolic link to {os.readlink(out)}, which does not exist; allowed: "
                "a new or empty directory, or a link to one")
    where = out
    while not where.exists():          # the nearest existing ancestor is where mkdir writes
        if where.is_symlink():
            return (f"its parent {where} is a symbolic link to {os.readlink(where)}, which "
                    "does not exist; allowed: a new or empty directory")
        where = where.parent
    if not where.is_dir():
        return f"{where} is a file; allowed: a new or empty directory"
    if not os.access(where, os.W_OK | os.X_OK):
        what = "the directory" if where == out else f"its parent {where}"
        return f"{what} is not writable; needed: write permission on {where}"
    return None


def make_dir(out: Path, option: str = "--out") -> None:
    """``mkdir -p out``; an operating-system refusal becomes a :class:`RunDirError`."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RunDirError(f"{option} {out}: [] cannot be created ({exc.strerror}); needed: "
                          "write permission on its parent directory") from None


def check_run_dir(out: str | Path, force: bool = False, option: str = "--out") -> Path:
    """Refuse ``out`` if it is a file, cannot be created or written (permissions, a
    dangling symbolic link), or is a non-empty directory without ``force``.
    Changes nothing."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise RunDirError(f"{option} {out}: [] is a file; allowed: a new or empty directory")
    problem = _writable_problem(out)
    if problem:
        raise RunDirError(f"{option} {out}: [] {problem}")
    if out.is_dir() and not force:
        entries = sorted(os.listdir(out))
        if entries:
            held = [e for e in entries if _is_run_file(e)]
            what = (f"holds another run ({', '.join(held[:3])}{', ...' if len(held) > 3 else ''})"
                    if held else f"is not empty ({', '.join(entries[:3])})")
            raise RunDirError(f"{option} {out}: [] {what}; allowed: a new or empty directory, "
                              "or --force to replace the run in it")
    return out


def start_run_dir(out: str | Path, running_summary: dict) -> Path:
    """Create ``out``, write the ``running`` summary first, then delete the earlier
    run's files and temporaries (only :data:`RUN_FILES` names)."""
    out = Path(out)
    make_dir(out)
    write_json(out / "summary.json", {**running_summary, "status": "running"})
    for name in os.listdir(out):
        if name != "summary.json" and _is_run_file(name) and (out / name).is_file():
            (out / name).unlink()
    return out


def mark_interrupted(out: str | Path, reason: str = "interrupted") -> None:
    """Rewrite the ``"running"`` summary of ``out`` as ``"interrupted"`` (with the files
    written so far), after Ctrl-C or SIGTERM stopped the run; nothing if there is none."""
    path = Path(out) / "summary.json"
    try:
        summary = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return
    if isinstance(summary, dict) and summary.get("status") == "running":
        write_json(path, {**summary, "status": "interrupted", "stop_reason": reason,
                          "files": run_files(out)})


def run_files(out: str | Path) -> list[str]:
    """The run's files now in ``out`` (sorted names, temporaries and summary excluded)."""
    return sorted(n for n in os.listdir(out)
                  if _is_run_file(n) and not n.startswith(".") and n != "summary.json")


@contextlib.contextmanager
def output_dir_for(out: str | Path, option: str = "--out", force: bool = False):
    """Create ``out`` for a command that writes into it: a new or empty directory, or
    with ``force`` any directory (:func:`check_run_dir`); if bad input
    (:class:`InputError`, :class:`SceneError`) stops the command, a directory this
    created is removed again (with the new parents it made), so bad input leaves nothing
    behind."""
    out = check_run_dir(out, force=force, option=option)
    top = next((p for p in reversed([out, *out.parents]) if not p.exists()), None)
    make_dir(out, option)
    try:
        yield out
    except (InputError, SceneError):
        if top is not None:             # the highest directory this created
            shutil.rmtree(top, ignore_errors=True)
        raise
