"""Load a script of ``validation/`` as a module, for tests of its functions (the scripts
are not a package)."""
from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

VALIDATION = Path(__file__).resolve().parents[1] / "validation"


def load(name: str) -> ModuleType:
    """``validation/<name>.py`` imported under the module name ``name``."""
    spec = importlib.util.spec_from_file_location(name, VALIDATION / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod
