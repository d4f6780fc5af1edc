"""Settings: defaults, file, flags; every mistake is named."""

import pytest

from server.config import ConfigError, load_settings, parse_override, parse_source


def write(tmp_path, text):
    path = tmp_path / "site.toml"
    path.write_text(text)
    return path


def test_defaults_and_file_and_overrides(tmp_path):
    s = load_settings()
    assert s.server.port == 8000 and s.sky.source.kind == "sim" and s.stream.smoothing_s == 2.0
    path = write(tmp_path, '[server]\nport = 9001\n[stream]\nsmoothing_s = 5\n'
                           '[sky]\nphotometric_factor = [1.0, 1.1, 0.9]\n')
    s = load_settings(path, {"server.port": 9002})
    assert s.server.port == 9002 and s.stream.smoothing_s == 5.0
    assert s.sky.photometric_factor == [1.0, 1.1, 0.9]
    assert s.origin["server.port"] == "command line"
    assert s.origin["stream.smoothing_s"] == str(path)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[sky]\nrate_hz = -2\n", "[sky] rate_hz must be a number > 0, got -2"),
        ("[sky]\nrat_hz = 2\n", "unknown key [sky] rat_hz"),
        ("[skies]\nrate_hz = 2\n", "unknown section [skies]"),
        ('[server]\nport = "eighty"\n', "[server] port must be an integer, got 'eighty'"),
        ("[server]\nport = 70000\n", "[server] port must be a number <= 65535"),
        ("[sky]\nphotometric_factor = [1, 2]\n", "three positive numbers"),
        ('[sky]\nsource = "webcam"\n', "[sky] source: source 'webcam' is not one of"),
        ('[site_camera]\nsource = "sim"\n', "replay:PATH | camera:INDEX_OR_URL"),
        ("[stream]\nchange_threshold = 2\n", "[stream] change_threshold must be a number <= 1"),
        ("[server\nport = 1\n", "not valid TOML"),
        ("[sky]\nreconnect_min_s = 60\n", "reconnect_min_s must not exceed"),
        ("sky = 3\n", "sky must be a [section] of keys"),
        ("[sky]\nrate_hz = inf\n", "[sky] rate_hz must be a number <= 120, got inf"),
        ("[sky]\nrate_hz = nan\n", "[sky] rate_hz must be a number > 0 and <= 120 (finite)"),
        ('[occlusion]\nresponse = "log"\n', "[occlusion] response must be srgb, linear or "
                                            "gamma:G, got 'log'"),
        ('[occlusion]\nworker = "fork"\n', "[occlusion] worker must be process | thread"),
        ("[sun]\nenabled = 1\n", "[sun] enabled must be true or false, got 1"),
        ("[server]\nallowed_origins = [1]\n", "allowed_origins must be a list of strings"),
    ],
)
def test_mistakes_are_reported_with_the_file_and_key(tmp_path, text, message):
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_settings(path)
    assert message in str(info.value)
    if "TOML" not in message and "exceed" not in message:
        assert str(path) in str(info.value)


def test_missing_file_and_bad_overrides():
    with pytest.raises(ConfigError, match="no such config file"):
        load_settings("/nonexistent/site.toml")
    with pytest.raises(ConfigError, match="unknown setting 'sky.colour'"):
        load_settings(None, {"sky.colour": 1})
    assert parse_override("stream.smoothing_s=5") == ("stream.smoothing_s", 5)
    assert parse_override("sim.start=2026-06-21T07:00") == ("sim.start", "2026-06-21T07:00")
    assert parse_override('sky.source="camera:0"') == ("sky.source", "camera:0")
    with pytest.raises(ConfigError, match="section.key=value"):
        parse_override("smoothing")


def test_source_specs(tmp_path):
    assert parse_source("sim").kind == "sim"
    cam = parse_source("camera:0")
    assert cam.camera_target == 0
    assert parse_source("camera:rtsp://10.0.0.5/stream").camera_target == "rtsp://10.0.0.5/stream"
    assert parse_source(f"replay:{tmp_path}").target == str(tmp_path)
    with pytest.raises(ConfigError, match="does not exist"):
        parse_source(f"replay:{tmp_path / 'missing'}")
    with pytest.raises(ConfigError):
        parse_source("sim", allow_sim=False)


def test_the_settings_schema_is_json_schema():
    """The keys are checked by jsonschema against a valid draft 2020-12 schema holding every
    key with its default (docs/server.md's tables are generated from it)."""
    import jsonschema

    from server.config import SCHEMA, json_schema

    schema = json_schema()
    jsonschema.Draft202012Validator.check_schema(schema)
    for section, keys in SCHEMA.items():
        props = schema["properties"][section]["properties"]
        assert list(props) == list(keys)
        for name, key in keys.items():
            assert props[name]["default"] == key.default and props[name]["description"]
    defaults = {s: {k: p["default"] for k, p in v["properties"].items()}
                for s, v in schema["properties"].items()}
    assert not list(jsonschema.Draft202012Validator(schema).iter_errors(defaults))
