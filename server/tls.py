"""HTTPS for ``daylit serve --tls-cert FILE --tls-key FILE``: the server's TLS context.

Phones allow the camera and WebXR only in a secure context (HTTPS, or localhost), so the site's
visitors need the page over HTTPS. :func:`server_context` loads a PEM certificate (chain) and
its private key into an :class:`ssl.SSLContext` (TLS 1.2 at least) before the server binds its
port, and turns each way it can fail into a :class:`server.config.ConfigError` that says which
file and what is wrong: missing, unreadable, not PEM, or a key that is not the certificate's.
"""

from __future__ import annotations

import ssl
from pathlib import Path

from server.config import ConfigError


def _readable(path: Path, what: str, flag: str) -> None:
    if not path.exists():
        raise ConfigError(f"{flag} {path}: no such file (the {what})")
    if not path.is_file():
        raise ConfigError(f"{flag} {path}: not a file (the {what})")
    try:
        with open(path, "rb") as f:
            head = f.read(1 << 16)
    except OSError as exc:
        raise ConfigError(f"{flag} {path}: cannot read the {what}: {exc.strerror}") from None
    if b"-----BEGIN " not in head:
        raise ConfigError(f"{flag} {path}: not a PEM file (the {what} must be PEM text "
                          "starting with -----BEGIN ...)")


def server_context(cert_file: str | Path, key_file: str | Path) -> ssl.SSLContext:
    """A server-side TLS context for the certificate chain ``cert_file`` and its private key
    ``key_file`` (both PEM); raises :class:`ConfigError` naming the file at fault."""
    cert, key = Path(cert_file).expanduser(), Path(key_file).expanduser()
    _readable(cert, "certificate", "--tls-cert")
    _readable(key, "private key", "--tls-key")
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.minimum_version = ssl.TLSVersion.TLSv1_2

    def encrypted() -> bytes:  # else OpenSSL would ask for the passphrase on the terminal
        raise ConfigError(f"--tls-key {key}: the key is encrypted with a passphrase; give an "
                          "unencrypted key (readable by this user alone)")

    try:
        context.load_cert_chain(cert, key, password=encrypted)
    except ssl.SSLError as exc:
        reason = f"{exc.reason or ''} {exc}"
        if "KEY_VALUES_MISMATCH" in reason.upper():
            raise ConfigError(f"--tls-key {key} is not the private key of the certificate "
                              f"{cert} (they do not match)") from None
        raise ConfigError(f"--tls-cert {cert} / --tls-key {key}: not a certificate and its "
                          f"private key ({exc})") from None
    except OSError as exc:
        raise ConfigError(f"--tls-cert {cert} / --tls-key {key}: cannot read: {exc}") from None
    return context
