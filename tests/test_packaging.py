"""The embedded default scene is the shipped reference slope."""
from fem_rmpm.cli import default_scene_path
from fem_rmpm.scene import load_scene


def test_embedded_default_is_the_reference_slope(meshes):
    """`fem-rmpm mc` without a scene runs fem_rmpm/data/slope_reference.toml, which must be
    byte-identical to meshes/slope_reference.toml (one scene, two places to find it)."""
    embedded = default_scene_path()
    assert embedded.read_bytes() == (meshes / "slope_reference.toml").read_bytes()
    assert load_scene(embedded).scene.name == "slope_reference"
