"""scene.toml checked against its JSON Schema (bake/scene_schema.py): each mistake named by
file, key and what is allowed, in the words docs/scene-format.md shows; and a site loads with
the schema's defaults (tests/bake/test_bad_input.py runs the same through `daylit bake`)."""

from __future__ import annotations

import jsonschema
import pytest

from bake.scene import SceneError, load_site
from bake.scene_schema import SCHEMA
from tests.sites import make_site

VIEW = ('\n[[view]]\nname = "k"\nwidth = 64\nheight = 48\nposition_m = [0, 2, 10]\n'
        'look_at_m = [0, 1, 0]\n')


@pytest.mark.parametrize(("old", "new", "key", "words"), [
    ("latitude_deg = 34.47", "latitude_deg = 95", "site.latitude_deg",
     "must be at most 90.0, got 95"),
    ("latitude_deg = 34.47", "latitude = 34.47", "site.latitude",
     "unknown key (did you mean 'latitude_deg'?)"),
    ("latitude_deg = 34.47", "", "site.latitude_deg", "is required but missing"),
    ("latitude_deg = 34.47", "latitude_deg = inf", "site.latitude_deg", "must be finite"),
    ('id = "test"', 'id = "a b"', "site.id", "may hold only letters, digits, - and _"),
    ('name = "test site"', 'name = "  "', "site.name", "must be a non-empty string"),
    ("lights = 40", "lights = 40.5", "dome.lights", "must be a whole number, got 40.5"),
    ("lights = 40", 'lights = "many"', "dome.lights", "must be a number, got a string"),
    ("lights = 40", "lights = true", "dome.lights", "must be a number, got a boolean"),
    ('default = "draft"', 'default = "best"', "quality.default",
     "must be one of draft, final; got 'best'"),
    ("direct_rays = 160", "direct_rays = 4", "quality.draft.direct_rays",
     "must be at least 8, got 4"),
    ("albedo = [0.2, 0.2, 0.2]", "albedo = [0.2, 0.2]", "ground.albedo",
     "must be a list of 3 numbers, got [0.2, 0.2]"),
    ("albedo = [0.2, 0.2, 0.2]", "albedo = [0.2, 1.5, 0.2]", "ground.albedo[1]",
     "must be within [0.0, 1.0], got 1.5"),
    ("size_m = [40.0, 40.0]", "size_m = [40.0, 0.0]", "ground.size_m[1]", "must be positive"),
    ("[ground]", "ground = 3\n[grund]", "grund", "unknown key (did you mean 'ground'?)"),
    ("[site]", "view = 3\n[site]", "view", "must be an array of tables ([[...]])"),
    ("[shadowing]", "[shadowing]\nmax_atlas_size = 10", "shadowing.max_atlas_size",
     "must be at least 64, got 10"),
])
def test_a_mistake_names_the_file_the_key_and_what_is_allowed(tmp_path, old, new, key, words):
    scene = make_site(tmp_path / "scene")
    toml = scene / "scene.toml"
    text = toml.read_text()
    assert old in text, old
    toml.write_text(text.replace(old, new, 1))
    with pytest.raises(SceneError) as info:
        load_site(scene)
    assert (info.value.key, str(toml)) == (key, info.value.path)
    assert words in info.value.message, info.value.message


@pytest.mark.parametrize(("view", "key", "words"), [
    (VIEW, "view[0].fov_y_deg", "give exactly one of fov_y_deg or intrinsics"),
    (VIEW + "fov_y_deg = 200\n", "view[0].fov_y_deg", "must be at most 170.0, got 200"),
    (VIEW + "intrinsics = { fx = 50, fy = 50, cx = 80, cy = 24 }\n", "view[0].intrinsics.cx",
     "must be at most 64, got 80.0"),
    (VIEW + "intrinsics = { fx = 50, fy = 50, cx = 32 }\n", "view[0].intrinsics.cy",
     "is required but missing"),
])
def test_view_mistakes(tmp_path, view, key, words):
    scene = make_site(tmp_path / "scene", extra=view)
    with pytest.raises(SceneError) as info:
        load_site(scene)
    assert info.value.key == key and words in info.value.message, str(info.value)


def test_the_schema_is_json_schema_and_its_defaults_load(tmp_path):
    jsonschema.Draft202012Validator.check_schema(SCHEMA)
    site = load_site(make_site(tmp_path / "scene"))
    props = SCHEMA["properties"]
    assert site.settings.max_atlas_size == props["shadowing"]["properties"]["max_atlas_size"][
        "default"] == 2048
    assert site.settings.compression == {k: p["default"] for k, p in
                                         props["compression"]["properties"].items()}
    assert site.north_deg == 0.0 and site.scene_id == "test"


def test_the_sun_bounce_encoding_and_sharing_reach_the_compressor(tmp_path):
    """``[compression] sun_bounce_encoding`` and ``sun_bounce_sharing`` (docs/scene-format.md)
    are read from the scene file and handed to the compression settings the baker uses; a
    word it does not know is an error that names the key and what is allowed."""
    from bake.compressor import Compressor

    site = load_site(make_site(tmp_path / "a", extra='[compression]\nsun_bounce_encoding = '
                                                      '"uastc"\nsun_bounce_lights = 0\n'
                                                      'sun_bounce_sharing = "always"\n'))
    settings = Compressor(site, log=lambda msg: None).settings
    assert settings.sun_bounce_encoding == "uastc" and settings.sun_bounce_lights is None
    assert settings.sun_bounce_sharing == "always"
    default = Compressor(load_site(make_site(tmp_path / "b")), log=lambda msg: None).settings
    assert default.sun_bounce_encoding == "smallest" and default.sun_bounce_lights == 196
    assert default.sun_bounce_sharing == "within_budget"
    with pytest.raises(SceneError) as info:
        load_site(make_site(tmp_path / "c", extra='[compression]\nsun_bounce_encoding = "etc1s"\n'))
    assert info.value.key == "compression.sun_bounce_encoding", str(info.value)
    assert "smallest" in info.value.message, str(info.value)
    with pytest.raises(SceneError) as info:
        load_site(make_site(tmp_path / "d", extra='[compression]\nsun_bounce_sharing = "no"\n'))
    assert info.value.key == "compression.sun_bounce_sharing", str(info.value)
    assert "within_budget" in info.value.message, str(info.value)
