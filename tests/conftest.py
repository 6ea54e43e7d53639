"""Shared fixtures: paths to the shipped scenes and a helper to write scene variants."""
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MESHES = ROOT / "meshes"


@pytest.fixture
def meshes() -> Path:
    return MESHES


@pytest.fixture
def column_text() -> str:
    return (MESHES / "column.toml").read_text()


@pytest.fixture(scope="session")
def meshes_dir_fx():
    """The reference slope grid (shared, read-only)."""
    from fem_rmpm.grid import make_grid
    from fem_rmpm.scene import load_scene
    return make_grid(load_scene(MESHES / "slope_elastic.toml"))
