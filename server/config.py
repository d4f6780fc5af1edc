"""Settings of ``daylit serve``: defaults, a TOML file, then command-line flags.

Every setting has a section, a key, a type, a default and a range, declared compactly as a
:class:`Key` in ``SCHEMA``; :func:`json_schema` turns them into the JSON Schema the values are
checked against (daylit.settingschema, as every settings file and the manifest). A wrong one
stops the server before it starts with a message that names it, e.g.
``site.toml: [sky] rate_hz must be a number > 0, got -2``. Unknown keys are errors too (a typo
would otherwise be silently ignored). ``docs/server.md``'s tables of keys are generated from
the schema (tools/settings_tables.py).
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from daylit.settingschema import first_problem

REPO_ROOT = Path(__file__).resolve().parents[1]


class ConfigError(ValueError):
    """A setting that is missing, of the wrong type, or out of range."""


@dataclass(frozen=True)
class Key:
    default: Any
    kind: str  # "str", "int", "float", "bool", "list[str]", "list[float]", "rgb", "source"
    help: str
    minimum: float | None = None
    maximum: float | None = None
    exclusive_minimum: bool = False
    choices: tuple[str, ...] | None = None  # for "str": the only values allowed
    pattern: str | None = None  # for "str": a regular expression the value must match
    allowed: str | None = None  # words for what is allowed, in messages and docs


SCHEMA: dict[str, dict[str, Key]] = {
    "server": {
        "host": Key("0.0.0.0", "str", "address to listen on (0.0.0.0: every interface)"),
        "port": Key(8000, "int", "TCP port", 1, 65535),
        "max_clients": Key(1000, "int", "WebSocket clients served at once; more are refused "
                            "with close code 1013", 1, 100000),
        "allowed_origins": Key([], "list[str]", "origins (scheme://host[:port]) allowed to "
                               "open the light stream besides the page's own; \"*\" for any"),
        "client_max_messages_per_s": Key(10.0, "float", "messages a client may send per "
                                         "second (averaged over 5 s) before it is closed", 0.1),
        "slow_client_timeout_s": Key(30.0, "float", "a client whose connection accepts no "
                                     "data for this long is dropped", 1.0),
        "header_timeout_s": Key(10.0, "float", "a connection must send a request's headers "
                                "within this long of opening (or of its last answer), else it "
                                "is closed (slowloris)", 0.5, 3600.0),
        "max_connections_per_address": Key(256, "int", "open connections from one client "
                                           "address (all kinds: pages, files, light streams); "
                                           "more are closed at once", 1, 100000),
        "heartbeat_s": Key(30.0, "float", "the light stream pings each client this often; "
                           "one that does not answer within half of it is dropped (logged)",
                           0.1, 3600.0),
        "workers": Key(1, "int", "fan-out processes holding the WebSocket clients on the one "
                       "port (SO_REUSEPORT), fed by one measuring process; 1 without a broker: "
                       "one process does everything", 1, 256),
        "broker": Key("", "str", "where the measuring process publishes and fan-out workers "
                      "subscribe: redis://HOST:PORT/DB (Redis, across machines) | local:PATH "
                      "(a Unix socket of the measuring process, one machine); empty: none"),
        "role": Key("all", "str", "all (measuring and fan-out) | measure (the measuring "
                    "process alone, publishing to the broker) | fanout (fan-out workers alone, "
                    "fed by the broker)", choices=("all", "measure", "fanout")),
        "tls_cert": Key("", "str", "PEM certificate (chain) file: serve HTTPS and WSS "
                        "(--tls-cert; with tls_key); empty: plain HTTP"),
        "tls_key": Key("", "str", "PEM private key file of tls_cert (--tls-key)"),
        "web_root": Key(str(REPO_ROOT / "web"), "str", "folder served at /"),
        "three_root": Key(str(REPO_ROOT / "node_modules" / "three"), "str",
                          "the three package, served at /vendor/three/"),
    },
    "access": {
        "operator_token": Key("", "str", "token of kiosks and operators (?token= in the kiosk "
                              "URL): the site-camera and occlusion streams, /api/status and "
                              "/api/sky.jpg need it; the environment variable "
                              "DAYLIT_OPERATOR_TOKEN takes precedence; empty: those are served "
                              "only to requests from this machine"),
        "allowed_hosts": Key([], "list[str]", "Host names this server answers for besides IP "
                             "addresses, localhost and the machine's own names (--allow-host; "
                             "*.example.org for a domain, \"*\" for any); others get 421"),
        "serve_masters": Key(False, "bool", "also serve the build's EXR masters under /build/ "
                             "(gigabytes no client reads)"),
    },
    "sky": {
        "source": Key("sim", "source", "where the sky's frames come from: the simulated "
                      "sky, a replay or a live camera (Sky sources, above)"),
        "rate_hz": Key(2.0, "float", "frames per second of the simulated sky and of replays; "
                       "the most a camera is measured per second", 0.0, 120.0, True),
        "stale_after_s": Key(5.0, "float", "no frame for this long marks the light stale", 0.1),
        "fuse_scene": Key(True, "bool", "with a sky camera (camera: or replay:) and a site "
                          "camera: the sun estimated from the site camera's view of the scene "
                          "where the sky camera clips it, and the two compared in /api/status "
                          "(docs/server.md, \"Fusion\"); needs a fixed view in the build"),
        "reconnect_min_s": Key(1.0, "float", "first wait before reopening a camera", 0.01),
        "reconnect_max_s": Key(30.0, "float", "longest wait between reopening attempts", 0.01),
        "calibration": Key("", "str", "calibration JSON from `daylit calibrate` (intrinsics "
                           "and rotation to north); empty: ideal equidistant lens, north up"),
        "fov_deg": Key(180.0, "float", "field of view of the ideal lens when there is no "
                       "calibration; its circle touches the shorter image side", 10.0, 360.0),
        "sky_mask": Key("", "str", "image, white where the camera sees open sky (optional)"),
        "response": Key("srgb", "str", "inverse response: srgb | linear | gamma:G | path to "
                        "a JSON list of 256 values or RGB triples"),
        "exposure": Key(1.0, "float", "linear camera value of unit radiance, W/(m^2 sr), at "
                        "the camera's fixed exposure (merged brackets: in a 1 s exposure)", 0.0,
                        None, True),
        "photometric_factor": Key([1.0, 1.0, 1.0], "rgb", "multiplies the measured radiance "
                                  "(Sato Sec. 5 calibration, white balance)"),
        "vignetting": Key([], "list[float]", "relative illumination 1 + a1 t^2 + a2 t^4 + ... "
                          "(t: angle from the optical axis, rad): [a1, a2, ...]"),
        "saturation_level": Key(0.98, "float", "fraction of full scale counted as clipped",
                                0.5, 1.0),
        "supersample": Key(6, "int", "sub-pixel grid for pixels cut by patch edges", 1, 16),
        "max_working_pixels": Key(1 << 17, "int", "frames are binned (2 x 2, once or more) to "
                                  "at most this many pixels after linearising", 4096),
    },
    "sun": {
        "enabled": Key(True, "bool", "measure the sun apart from the sky (docs/sun.md): its "
                       "direction, normal irradiance and source in every vector; false: the "
                       "sun stays in its patch as before (protocol 2 and 3 clients then get "
                       "no sun)"),
        "linke_turbidity": Key(3.0, "float", "Linke turbidity of the clear-sky model (Ineichen) "
                               "that estimates the sun where the camera clips it, and of the "
                               "simulated sky: 2 very clear, 3 clear, 4-5 hazy, 6-7 polluted",
                               0.5, 10.0),
    },
    "stream": {
        "smoothing_s": Key(2.0, "float", "time constant of the exponential smoothing; 0: off",
                           0.0, 3600.0),
        "change_threshold": Key(0.002, "float", "send a new vector only when a light moved by "
                                "more than this fraction of the mean sky radiance", 0.0, 1.0),
        "max_interval_s": Key(5.0, "float", "send at least this often anyway", 0.1),
    },
    "sim": {
        "start": Key("auto", "str", "simulated start: auto (now if the sun is up at the site, "
                     "else the next 10:00 there; after each sunset the next 10:00 again), now, "
                     "or an ISO date-time (local time at the site if it has no offset), e.g. "
                     "2026-06-21T07:00"),
        "clock_speed": Key(20.0, "float", "simulated seconds per real second (20: an hour in "
                           "3 minutes; 1: real time)", 0.0, 100000.0, True),
        "cloud_cover": Key(0.3, "float", "fraction of the sky covered by cloud", 0.0, 1.0),
        "size_px": Key(640, "int", "width and height of the simulated fisheye image", 64, 4096),
        "noise": Key(0.002, "float", "sensor noise, fraction of full scale", 0.0, 0.2),
        "seed": Key(0, "int", "cloud pattern", 0),
    },
    "scene": {
        "view": Key("", "str", "with [sky] source = scene or fuse_scene: the build's fixed "
                    "view the site camera is calibrated to; empty: the first"),
        "samples": Key(500, "int", "surface pixels per estimate (Jensen et al. 2006 use 500)",
                       20, 100000),
        "radiance_per_unit": Key(1.0, "float", "W/(m^2 sr) that a linear pixel value of 1 "
                                 "stands for: the site camera's fixed exposure (auto-exposure "
                                 "must be off)", 0.0, None, True),
        "photometric_factor": Key([1.0, 1.0, 1.0], "rgb", "per-channel factor on linear "
                                  "values (the site camera's white balance against a grey card)"),
        "response": Key("srgb", "str", "inverse response of the site camera: srgb | linear | "
                        "gamma:G", pattern=r"^(srgb|linear|gamma:.+)$",
                        allowed="srgb, linear or gamma:G"),
        "disagreement_factor": Key(1.3, "float", "with [sky] fuse_scene: /api/status warns "
                                   "when the sky camera's sky or sun irradiance and the scene "
                                   "estimate's differ by more than this factor (median of 10 "
                                   "frames)", 1.0, 100.0, True),
        "drift_factor": Key(1.25, "float", "with [sky] fuse_scene: /api/status warns when "
                            "the sky camera's sky, fitted to the site camera's pixels, needs "
                            "a scale beyond this factor (a drifted or fogged sky camera; "
                            "median of 10 frames)", 1.0, 100.0, True),
    },
    "site_camera": {
        "source": Key("", "source", "kiosk camera: camera:INDEX_OR_URL | replay:PATH; empty: "
                      "none (kiosks then draw the baked surface images)"),
        "rate_hz": Key(10.0, "float", "most frames per second sent to kiosks", 0.0, 60.0, True),
        "jpeg_quality": Key(80, "int", "JPEG quality of streamed frames", 10, 100),
        "max_width": Key(1280, "int", "frames wider than this are scaled down", 64, 8192),
    },
    "occlusion": {
        "enabled": Key(True, "bool", "find visitors in front of the virtual buildings in the "
                       "site camera's frames and stream their mask (needs a site camera and a "
                       "fixed view in the build)"),
        "view": Key("", "str", "the build's fixed view the site camera is calibrated to; "
                    "empty: the first"),
        "max_width": Key(1024, "int", "frames wider than this are scaled down for occlusion; "
                         "masks have that size", 64, 8192),
        "learn_frames": Key(10, "int", "frames of the empty site learned as the background at "
                            "start and after a relearn (SIGHUP)", 1, 1000),
        "response": Key("srgb", "str", "inverse response of the site camera: srgb | linear | "
                        "gamma:G", pattern=r"^(srgb|linear|gamma:.+)$",
                        allowed="srgb, linear or gamma:G"),
        "worker": Key("process", "str", "where frames are processed: process (a worker "
                      "process; the light stream never waits for it) | thread",
                      choices=("process", "thread")),
    },
}


@dataclass(frozen=True)
class SourceSpec:
    """A parsed ``sim``, ``scene``, ``replay:PATH`` or ``camera:INDEX_OR_URL``."""

    kind: str
    target: str = ""

    def __str__(self) -> str:
        return self.kind if not self.target else f"{self.kind}:{self.target}"

    @property
    def camera_target(self) -> int | str:
        """A device index (int) or a file/stream URL (str)."""
        return int(self.target) if self.target.isdigit() else self.target


def parse_source(text: str, allow_sim: bool = True) -> SourceSpec:
    """Parse a source spec; raises :class:`ConfigError` naming what is wrong."""
    text = text.strip()
    if text in ("sim", "scene") and allow_sim:
        return SourceSpec(text)
    kind, _, target = text.partition(":")
    if kind == "replay" and target:
        path = Path(target).expanduser()
        if not path.exists():
            raise ConfigError(f"replay source {target!r} does not exist")
        return SourceSpec("replay", str(path))
    if kind == "camera" and target:
        return SourceSpec("camera", target)
    choices = ("sim | scene | " if allow_sim else "") + "replay:PATH | camera:INDEX_OR_URL"
    raise ConfigError(f"source {text!r} is not one of {choices}")


_ALLOWED = {
    "source": "sim | scene | replay:PATH | camera:INDEX_OR_URL",
    "rgb": "three positive numbers [r, g, b]",
}


def _property(key: Key, section: str) -> dict:
    """One key as a JSON Schema property (with its default and meaning)."""
    kind = key.kind
    prop: dict[str, Any] = {}
    if kind == "str":
        prop = {"type": "string"} if key.choices is None else {"enum": list(key.choices)}
        if key.pattern is not None:
            prop["pattern"] = key.pattern
    elif kind == "source":
        # The form (and that a replay exists) is parse_source's, which builds the SourceSpec.
        allowed = _ALLOWED["source"]
        if section == "site_camera":
            allowed = "empty | replay:PATH | camera:INDEX_OR_URL"
        prop = {"type": "string", "x-allowed": allowed}
    elif kind == "bool":
        prop = {"type": "boolean"}
    elif kind in ("int", "float"):
        prop = {"type": "integer" if kind == "int" else "number"}
        if key.minimum is not None:
            prop["exclusiveMinimum" if key.exclusive_minimum else "minimum"] = key.minimum
        if key.maximum is not None:
            prop["maximum"] = key.maximum
    elif kind in ("list[str]", "list[float]"):
        prop = {"type": "array", "items": {"type": "string" if kind == "list[str]" else "number"}}
    elif kind == "rgb":
        prop = {"type": "array", "items": {"type": "number", "exclusiveMinimum": 0},
                "minItems": 3, "maxItems": 3, "x-allowed": _ALLOWED["rgb"]}
    else:
        raise AssertionError(kind)
    if key.allowed is not None:
        prop["x-allowed"] = key.allowed
    return {**prop, "default": key.default, "description": key.help}


def json_schema() -> dict:
    """The JSON Schema of a settings file: ``{section: {key: value}}``, every key known."""
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "type": "object",
        "additionalProperties": False,
        "properties": {
            section: {"type": "object", "additionalProperties": False,
                      "properties": {name: _property(key, section) for name, key in keys.items()}}
            for section, keys in SCHEMA.items()
        },
    }


def _coerce(where: str, key: Key, value: Any) -> Any:
    """A checked value as Settings holds it (int, float, list of float, SourceSpec or None)."""
    kind = key.kind
    if kind == "source":
        if value == "":
            return None
        try:
            return parse_source(value, allow_sim=not where.startswith("[site_camera]"))
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None
    if kind == "int":
        return int(value)
    if kind == "float":
        return float(value)
    if kind in ("list[float]", "rgb"):
        return [float(v) for v in value]
    if kind == "list[str]":
        return list(value)
    return value


class Settings:
    """Checked settings: ``settings.sky.rate_hz`` and so on (read-only sections)."""

    def __init__(self, values: dict[str, dict[str, Any]], origin: dict[str, str]):
        self._values = values
        self.origin = origin  # "section.key" -> where the value came from
        for section, keys in values.items():
            setattr(self, section, _Section(section, keys))


class _Section:
    def __init__(self, name: str, values: dict[str, Any]):
        self.__dict__.update(values)
        self._name = name

    def __repr__(self) -> str:
        return f"[{self._name}] " + ", ".join(
            f"{k}={v!r}" for k, v in self.__dict__.items() if not k.startswith("_"))


def load_settings(
    path: Path | str | None = None, overrides: dict[str, Any] | None = None
) -> Settings:
    """Defaults, then the TOML file at ``path``, then ``overrides`` {"section.key": value}."""
    raw: dict[str, Any] = {s: {} for s in SCHEMA}
    origin: dict[str, str] = {}
    label = "config"
    if path is not None:
        path = Path(path)
        label = str(path)
        try:
            data = tomllib.loads(path.read_text("utf-8"))
        except FileNotFoundError:
            raise ConfigError(f"{path}: no such config file") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{path}: cannot read: {exc}") from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{path}: not valid TOML: {exc}") from None
        for section, keys in data.items():
            raw[section] = keys
            origin[section] = str(path)
            for key in keys if isinstance(keys, dict) else ():
                origin[f"{section}.{key}"] = str(path)
    for dotted, value in (overrides or {}).items():
        section, _, key = dotted.partition(".")
        if section not in SCHEMA or key not in SCHEMA[section]:
            raise ConfigError(f"unknown setting {dotted!r}")
        raw[section][key] = value
        origin[dotted] = "command line"
    merged = {section: ({name: k.default for name, k in SCHEMA.get(section, {}).items()} | keys
                        if isinstance(keys, dict) else keys) for section, keys in raw.items()}
    problem = first_problem(merged, json_schema(), depth=2)
    if problem is not None:
        src = origin.get(".".join(problem.path), origin.get(problem.path[0], "default"))
        prefix = f"{src}: " if src != "default" else ""
        if problem.unknown and len(problem.path) == 1:
            raise ConfigError(f"{prefix}unknown section [{problem.path[0]}] "
                              f"{problem.words}")
        if problem.unknown:
            raise ConfigError(f"{prefix}unknown key [{problem.path[0]}] {problem.path[1]} "
                              f"{problem.words}")
        if len(problem.path) == 1:
            raise ConfigError(f"{prefix}{problem.path[0]} must be a [section] of keys")
        raise ConfigError(f"{prefix}[{problem.path[0]}] {problem.path[1]} {problem.words}")
    values: dict[str, dict[str, Any]] = {}
    for section, keys in SCHEMA.items():
        values[section] = {}
        for key, spec in keys.items():
            src = origin.get(f"{section}.{key}", "default")
            where = f"[{section}] {key}"
            prefix = f"{src}: " if src != "default" else ""
            try:
                values[section][key] = _coerce(where, spec, merged[section][key])
            except ConfigError as exc:
                raise ConfigError(f"{prefix}{exc}") from None
    settings = Settings(values, origin)
    sky = settings.sky
    if sky.reconnect_min_s > sky.reconnect_max_s:
        raise ConfigError(f"{label}: [sky] reconnect_min_s must not exceed reconnect_max_s")
    start = settings.sim.start
    if start not in ("auto", "now"):
        import datetime as dt

        try:
            dt.datetime.fromisoformat(start)
        except ValueError:
            raise ConfigError(f"{origin.get('sim.start', label)}: [sim] start must be auto, now "
                              f"or an ISO date-time such as 2026-06-21T10:00, got {start!r}"
                              ) from None
    _check_serving(settings, origin, label)
    return settings


BROKER_SCHEMES = ("redis://", "rediss://", "unix://", "local:")


def _check_serving(settings: Settings, origin: dict[str, str], label: str) -> None:
    """``[server] broker``, ``role`` and ``workers`` together."""
    srv = settings.server
    if srv.broker and not srv.broker.startswith(BROKER_SCHEMES):
        raise ConfigError(f"{origin.get('server.broker', label)}: [server] broker must be "
                          f"redis://HOST:PORT/DB or local:PATH, got {srv.broker!r}")
    if srv.broker.startswith("local:") and not srv.broker.removeprefix("local:"):
        raise ConfigError(f"{origin.get('server.broker', label)}: [server] broker local:PATH "
                          "needs the path of its Unix socket")
    if srv.role != "all" and not srv.broker:
        raise ConfigError(f"{origin.get('server.role', label)}: [server] role {srv.role} needs "
                          "a broker (--broker redis://HOST:PORT/DB)")
    if bool(srv.tls_cert) != bool(srv.tls_key):
        given, missing = ("tls_cert", "tls_key") if srv.tls_cert else ("tls_key", "tls_cert")
        raise ConfigError(f"{origin.get('server.' + given, label)}: [server] {given} needs "
                          f"{missing} too (--tls-cert FILE --tls-key FILE)")
    if srv.role == "measure" and srv.workers > 1:
        raise ConfigError(f"{origin.get('server.workers', label)}: [server] workers: the "
                          "measuring process alone (role measure) runs no fan-out workers; "
                          "start them with --role fanout")


def parse_override(text: str) -> tuple[str, Any]:
    """``section.key=value`` from ``--set``; the value is read as TOML, else as a string."""
    dotted, sep, value = text.partition("=")
    if not sep or "." not in dotted:
        raise ConfigError(f"--set {text!r}: expected section.key=value")
    try:
        parsed = tomllib.loads(f"v = {value}")["v"]
    except tomllib.TOMLDecodeError:
        parsed = value
    return dotted.strip(), parsed
