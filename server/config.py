"""Settings of ``daylit serve``: defaults, a TOML file, then command-line flags.

Every setting has a section, a key, a type, a default and a check; a wrong one stops the server
before it starts with a message that names it, e.g.
``site.toml: [sky] rate_hz must be a number > 0, got -2``. Unknown keys are errors too (a typo
would otherwise be silently ignored). ``docs/server.md`` lists every key; ``SCHEMA`` is the
source of that list.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

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
        "web_root": Key(str(REPO_ROOT / "web"), "str", "folder served at /"),
        "three_root": Key(str(REPO_ROOT / "node_modules" / "three"), "str",
                          "the three package, served at /vendor/three/"),
    },
    "sky": {
        "source": Key("sim", "source", "sim | replay:PATH | camera:INDEX_OR_URL"),
        "rate_hz": Key(2.0, "float", "frames per second of the simulated sky and of replays; "
                       "the most a camera is measured per second", 0.0, 120.0, True),
        "stale_after_s": Key(5.0, "float", "no frame for this long marks the light stale", 0.1),
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
                        "the camera's fixed exposure", 0.0, None, True),
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
                       "sun stays in its patch as before (protocol 2 clients then get no sun)"),
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
                        "gamma:G"),
        "worker": Key("process", "str", "where frames are processed: process (a worker "
                      "process; the light stream never waits for it) | thread",
                      choices=("process", "thread")),
    },
}


@dataclass(frozen=True)
class SourceSpec:
    """A parsed ``sim``, ``replay:PATH`` or ``camera:INDEX_OR_URL``."""

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
    if text == "sim" and allow_sim:
        return SourceSpec("sim")
    kind, _, target = text.partition(":")
    if kind == "replay" and target:
        path = Path(target).expanduser()
        if not path.exists():
            raise ConfigError(f"replay source {target!r} does not exist")
        return SourceSpec("replay", str(path))
    if kind == "camera" and target:
        return SourceSpec("camera", target)
    choices = ("sim | " if allow_sim else "") + "replay:PATH | camera:INDEX_OR_URL"
    raise ConfigError(f"source {text!r} is not one of {choices}")


def _check(where: str, key: Key, value: Any) -> Any:
    """Coerce and check one value against its key; raise ConfigError naming ``where``."""
    kind = key.kind

    def fail(what: str) -> ConfigError:
        return ConfigError(f"{where} must be {what}, got {value!r}")

    if kind == "str":
        if not isinstance(value, str):
            raise fail("a string")
        if key.choices is not None and value not in key.choices:
            raise fail(" | ".join(key.choices))
        return value
    if kind == "source":
        if not isinstance(value, str):
            raise fail("a string such as sim, replay:PATH or camera:0")
        if value == "":
            return None
        try:
            return parse_source(value, allow_sim=not where.startswith("[site_camera]"))
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None
    if kind == "bool":
        if not isinstance(value, bool):
            raise fail("true or false")
        return value
    if kind in ("int", "float"):
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise fail("an integer" if kind == "int" else "a number")
        if kind == "int" and not float(value).is_integer():
            raise fail("an integer")
        value = int(value) if kind == "int" else float(value)
        if not math.isfinite(value):
            raise fail("a finite number")
        lo, hi = key.minimum, key.maximum
        if lo is not None and (value <= lo if key.exclusive_minimum else value < lo):
            raise fail(f"a number {'>' if key.exclusive_minimum else '>='} {lo:g}")
        if hi is not None and value > hi:
            raise fail(f"a number <= {hi:g}")
        return value
    if kind in ("list[str]", "list[float]", "rgb"):
        if not isinstance(value, list):
            raise fail("a list")
        if kind == "list[str]":
            if not all(isinstance(v, str) for v in value):
                raise fail("a list of strings")
            return list(value)
        if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value):
            raise fail("a list of numbers")
        out = [float(v) for v in value]
        if kind == "rgb" and (len(out) != 3 or min(out) <= 0):
            raise fail("three positive numbers [r, g, b]")
        return out
    raise AssertionError(kind)


class Settings:
    """Checked settings: ``settings.sky.rate_hz`` and so on (read-only sections)."""

    def __init__(self, values: dict[str, dict[str, Any]], origin: dict[str, str]):
        self._values = values
        self.origin = origin  # "section.key" -> where the value came from
        for section, keys in values.items():
            setattr(self, section, _Section(section, keys))

    def as_dict(self) -> dict[str, dict[str, Any]]:
        out = {}
        for section, keys in self._values.items():
            out[section] = {k: (str(v) if isinstance(v, SourceSpec) else v)
                            for k, v in keys.items()}
        return out


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
    raw: dict[str, dict[str, Any]] = {s: {} for s in SCHEMA}
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
            if section not in SCHEMA:
                raise ConfigError(
                    f"{path}: unknown section [{section}] (known: {', '.join(SCHEMA)})")
            if not isinstance(keys, dict):
                raise ConfigError(f"{path}: {section} must be a [section] of keys")
            for key, value in keys.items():
                if key not in SCHEMA[section]:
                    raise ConfigError(
                        f"{path}: unknown key [{section}] {key} "
                        f"(known: {', '.join(SCHEMA[section])})")
                raw[section][key] = value
                origin[f"{section}.{key}"] = str(path)
    for dotted, value in (overrides or {}).items():
        section, _, key = dotted.partition(".")
        if section not in SCHEMA or key not in SCHEMA[section]:
            raise ConfigError(f"unknown setting {dotted!r}")
        raw[section][key] = value
        origin[dotted] = "command line"
    values: dict[str, dict[str, Any]] = {}
    for section, keys in SCHEMA.items():
        values[section] = {}
        for key, spec in keys.items():
            value = raw[section].get(key, spec.default)
            src = origin.get(f"{section}.{key}", "default")
            where = f"[{section}] {key}"
            prefix = f"{src}: " if src not in ("default",) else ""
            try:
                values[section][key] = _check(where, spec, value)
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
    response = settings.occlusion.response
    if response not in ("srgb", "linear") and not response.startswith("gamma:"):
        raise ConfigError(f"{origin.get('occlusion.response', label)}: [occlusion] response "
                          f"must be srgb, linear or gamma:G, got {response!r}")
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
