"""Who may reach what: the Host allow-list, the operator's token, and the build files offered.

Every request passes :func:`access_middleware` (``create_app`` and the fan-out workers' app
install it with :func:`install_access`):

- **Host.** A ``Host`` header naming something other than this server is refused with
  ``421 Misdirected Request``: a page of another site whose name an attacker re-pointed at this
  machine (DNS rebinding) sends its own name, so it cannot read this server's answers nor pass
  the light stream's same-origin check. Allowed: an IP address (a rebinding needs a name),
  ``localhost`` and ``*.localhost``, the machine's host name (also with ``.local`` and its fully
  qualified name), and the names in ``[access] allowed_hosts`` (``--allow-host``; ``*.example.org``
  for a domain's names, ``*`` for any).
- **Operator.** ``/api/status``, ``/api/sky.jpg`` and the ``site-camera`` and ``occlusion``
  streams show the site and its visitors: only an *operator* gets them. With a token configured
  (``[access] operator_token``, or the environment variable ``DAYLIT_OPERATOR_TOKEN``, which
  takes precedence) a request is an operator's when it carries that token, as ``?token=`` or
  ``Authorization: Bearer TOKEN``, compared in constant time (:func:`hmac.compare_digest`),
  from any address. Without a token only a request from this machine (a loopback peer, with no
  ``Forwarded`` / ``X-Forwarded-For`` header: a reverse proxy on this machine would otherwise
  make every visitor look local) is an operator's.
- **Build files.** ``/build/`` serves ``manifest.json`` and the files the manifest lists for
  clients: not the EXR masters (``*.exr``, gigabytes no client reads) unless ``[access]
  serve_masters`` is true, and never a file the manifest does not list.

Every answer also carries ``Referrer-Policy: same-origin`` so a kiosk URL's token never leaves
in a ``Referer`` header.
"""

from __future__ import annotations

import hmac
import ipaddress
import logging
import os
import socket
from dataclasses import dataclass

from aiohttp import web

from server.throttledlog import ThrottledWarnings

log = logging.getLogger("daylit.access")

TOKEN_ENV = "DAYLIT_OPERATOR_TOKEN"
OPERATOR = web.RequestKey("daylit_operator", bool)  # True for an operator's request
OPERATOR_PATHS = frozenset({"/api/status", "/api/sky.jpg"})
PRIVATE_STREAMS = frozenset({"site-camera", "occlusion"})  # server.lightstream's names
MASTER_SUFFIXES = (".exr",)
PROXY_HEADERS = ("Forwarded", "X-Forwarded-For", "X-Real-IP")
MIN_TOKEN_CHARS = 16


@dataclass(frozen=True)
class AccessPolicy:
    """The checked ``[access]`` settings.

    ``token``: the operator's token ("" for none: operators are local requests);
    ``allowed_hosts``: extra Host names (lower case; ``*.domain`` patterns, ``*`` any);
    ``serve_masters``: offer the EXR masters under ``/build/``.
    """

    token: str = ""
    allowed_hosts: tuple[str, ...] = ()
    serve_masters: bool = False

    @classmethod
    def from_settings(cls, settings, environ: dict[str, str] | None = None) -> AccessPolicy:
        environ = os.environ if environ is None else environ
        access = settings.access
        token = environ.get(TOKEN_ENV, "") or access.operator_token
        return cls(token=token,
                   allowed_hosts=tuple(h.strip().lower().rstrip(".")
                                       for h in access.allowed_hosts),
                   serve_masters=access.serve_masters)

    # ---------------------------------------------------------------------------- Host

    def host_allowed(self, host_header: str | None) -> bool:
        """Whether a ``Host`` header (``name[:port]``, ``[v6]:port``; None: absent) names
        this server."""
        if host_header is None or "*" in self.allowed_hosts:
            return True  # HTTP/1.0 without Host: aiohttp answers for the socket's address
        name = host_name(host_header)
        if not name:
            return False
        try:
            ipaddress.ip_address(name)
            return True
        except ValueError:
            pass
        if name == "localhost" or name.endswith(".localhost"):
            return True
        if name in machine_names():
            return True
        for allowed in self.allowed_hosts:
            if allowed.startswith("*.") and name.endswith(allowed[1:]):
                return True
            if name == allowed:
                return True
        return False

    # ----------------------------------------------------------------------- operators

    def is_operator(self, request: web.Request) -> bool:
        """Whether ``request`` is an operator's (see the module's docstring)."""
        if self.token:
            given = request.query.get("token", "")
            auth = request.headers.get("Authorization", "")
            if not given and auth[:7].lower() == "bearer ":
                given = auth[7:].strip()
            return hmac.compare_digest(given.encode("utf-8"), self.token.encode("utf-8"))
        if any(h in request.headers for h in PROXY_HEADERS):
            return False
        return is_loopback(request.remote)

    # ---------------------------------------------------------------------- build files

    def client_files(self, manifest: dict) -> frozenset[str]:
        """The paths under ``/build/`` a client may fetch: ``manifest.json`` and the listed
        files, without the EXR masters unless ``serve_masters``."""
        paths = {f["path"] for f in manifest["files"]}
        if not self.serve_masters:
            paths = {p for p in paths if not p.lower().endswith(MASTER_SUFFIXES)}
        return frozenset(paths | {"manifest.json"})


def host_name(host_header: str) -> str:
    """The name of a ``Host`` header, lower case, without port, brackets or a final dot."""
    host = host_header.strip().lower()
    if host.startswith("["):
        end = host.find("]")
        return host[1:end] if end > 0 else ""
    if host.count(":") == 1:
        host = host.split(":", 1)[0]
    return host.rstrip(".")


_MACHINE_NAMES: frozenset[str] | None = None


def machine_names() -> frozenset[str]:
    """This machine's names (host name, ``NAME.local``, fully qualified), lower case."""
    global _MACHINE_NAMES
    if _MACHINE_NAMES is None:
        names = set()
        try:
            short = socket.gethostname().lower().rstrip(".")
            names |= {short, f"{short.split('.')[0]}.local", short.split(".")[0]}
            names.add(socket.getfqdn().lower().rstrip("."))
        except OSError:
            pass
        _MACHINE_NAMES = frozenset(n for n in names if n)
    return _MACHINE_NAMES


def is_loopback(remote: str | None) -> bool:
    """Whether a peer address is this machine's loopback (a Unix socket's peer counts)."""
    if not remote:
        return False
    try:
        return ipaddress.ip_address(remote.split("%", 1)[0]).is_loopback
    except ValueError:
        return False


_warnings = ThrottledWarnings(log, 10.0)


@web.middleware
async def access_middleware(request: web.Request, handler):
    """Refuse a foreign Host (421) and a non-operator on an operator path (403); mark the
    request with :data:`OPERATOR` for the light stream."""
    policy: AccessPolicy = request.app[POLICY]
    host = request.headers.get("Host")
    if not policy.host_allowed(host):
        _warnings.warn("foreign host", f"refused a request from {request.remote} for Host "
                       f"{host!r}: not a name of this server (add it with --allow-host or "
                       "[access] allowed_hosts)")
        raise web.HTTPMisdirectedRequest(
            text=f"this server does not answer for the name {host_name(host or '')!r} "
                 "(its operator may add it with --allow-host)\n",
            headers={"Cache-Control": "no-store"})
    request[OPERATOR] = operator = policy.is_operator(request)
    if request.path in OPERATOR_PATHS and not operator:
        raise web.HTTPForbidden(text=refusal(policy),
                                headers={"Cache-Control": "no-store"})
    response = await handler(request)
    if not response.prepared:
        response.headers.setdefault("Referrer-Policy", "same-origin")
    return response


def refusal(policy: AccessPolicy) -> str:
    """The text of a 403 for an operator's path."""
    if policy.token:
        return "for operators only: add ?token=THE_OPERATOR_TOKEN\n"
    return ("for operators only: open it on the server's machine (localhost), or configure "
            "[access] operator_token and add ?token=\n")


POLICY = web.AppKey("access_policy", AccessPolicy)


def install_access(app: web.Application, policy: AccessPolicy) -> None:
    """Check every request of ``app`` with ``policy`` (first of its middlewares)."""
    app[POLICY] = policy
    app.middlewares.insert(0, access_middleware)
    if policy.token and len(policy.token) < MIN_TOKEN_CHARS:
        log.warning("the operator token has %d characters: use at least %d random ones "
                    "(python3 -c 'import secrets; print(secrets.token_urlsafe(24))')",
                    len(policy.token), MIN_TOKEN_CHARS)
