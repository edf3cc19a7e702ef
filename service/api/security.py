"""ASGI guards for a server a browser on the same machine can reach (docs/reliability.md, Security).

- :class:`HostGuard`: the ``Host`` header must name this server (DNS rebinding: a page on
  ``evil.example`` whose name is made to resolve to 127.0.0.1 sends ``Host: evil.example``).
- :class:`CrossSiteGuard`: a request that changes state and that the browser marks cross-site
  (``Sec-Fetch-Site``, or an ``Origin`` other than the server's own) is refused unless it carries
  the bearer token (a browser cannot add one to a cross-site request without CORS, which is off).
- :class:`RelativePaths`: error bodies show paths relative to the data directory, never the
  server's absolute paths.
"""

from __future__ import annotations

import ipaddress
import json
import re
from urllib.parse import urlsplit

STATE_CHANGING = frozenset({"POST", "PUT", "PATCH", "DELETE"})
# what a browser sends for a navigation typed by the user ("none") or a request from the page itself
SAME_ORIGIN_FETCH = frozenset({"same-origin", "none"})
# an error body is a short JSON document; one larger than this is passed on untouched rather than held
MAX_REWRITTEN_BODY = 1 << 20


async def _refuse(send, status: int, detail: str) -> None:
    body = json.dumps({"detail": detail}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]})
    await send({"type": "http.response.body", "body": body})


def _header(scope, name: bytes) -> str | None:
    for key, value in scope.get("headers") or ():
        if key.lower() == name:
            return value.decode("latin-1")
    return None


def split_host(value: str) -> str:
    """The host name of a ``Host`` header or URL authority, lower case, without port or brackets."""
    value = value.strip().lower()
    if value.startswith("["):  # [::1]:8750
        return value[1:].partition("]")[0]
    if value.count(":") == 1:
        return value.partition(":")[0]
    return value


def is_ip_literal(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
        return True
    except ValueError:
        return False


class HostGuard:
    """Refuses (421) requests whose ``Host`` is a name other than the bound address, ``localhost``
    or one of ``allowed``. An IP literal is always let through: DNS rebinding needs a name."""

    def __init__(self, app, bound: str, allowed: list[str]):
        self.app = app
        self.names = {split_host(bound), "localhost"} | {split_host(h) for h in allowed}
        self.any = "*" in allowed

    def accepts(self, host_header: str | None) -> bool:
        if self.any:
            return True
        if not host_header:
            return False
        host = split_host(host_header)
        return is_ip_literal(host) or host in self.names or host.rstrip(".") in self.names

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or self.accepts(_header(scope, b"host")):
            return await self.app(scope, receive, send)
        await _refuse(send, 421, "this server does not answer to the Host name given; use its address "
                                 "(e.g. http://127.0.0.1:8750) or add the name to the setting 'allowed_hosts'")


class CrossSiteGuard:
    """Refuses (403) state-changing requests a browser marks cross-site, unless they carry a
    bearer token (which the token check then verifies)."""

    def __init__(self, app, has_token: bool):
        self.app = app
        self.has_token = has_token  # a server without a token has none a request could carry

    @staticmethod
    def cross_site(scope) -> bool:
        fetch_site = _header(scope, b"sec-fetch-site")
        if fetch_site is not None and fetch_site.strip().lower() not in SAME_ORIGIN_FETCH:
            return True
        origin = _header(scope, b"origin")
        if origin is None:
            return False  # not a browser's cross-origin request (curl, scripts, the lab's tools)
        parts = urlsplit(origin.strip())
        host = _header(scope, b"host") or ""
        return not parts.netloc or parts.netloc.lower() != host.strip().lower()

    async def __call__(self, scope, receive, send):
        if (scope["type"] != "http" or scope["method"] not in STATE_CHANGING or not self.cross_site(scope)
                or (self.has_token and (_header(scope, b"authorization") or "").lower().startswith("bearer "))):
            return await self.app(scope, receive, send)
        await _refuse(send, 403, "a cross-site request may not change anything on this server (its Origin or "
                                 "Sec-Fetch-Site says another site sent it); send it from the server's own page "
                                 "or a script, or with 'Authorization: Bearer <token>'")


def relative_paths(text: str, roots: list[str]) -> str:
    """``text`` with each of ``roots`` (absolute folders) cut from the paths under them; a root
    itself becomes ``.``. Roots are tried longest first, so a root inside another is cut whole."""
    for root in sorted({r.rstrip("/") for r in roots if r and r != "/"}, key=len, reverse=True):
        for form in {root, json.dumps(root)[1:-1]}:  # as written, and as JSON escapes it
            # only where the root starts a path: not "/a" inside "x/a", nor "/data" inside "/data2"
            text = re.sub(rf"(?<![\w.\-/]){re.escape(form)}(/|(?![\w.\-]))",
                          lambda m: "" if m.group(1) == "/" else ".", text)
    return text


class RelativePaths:
    """Rewrites error bodies (status >= 400) so the server's absolute ``roots`` do not appear:
    ``/srv/wandcal-data/captures/x/wand.csv`` becomes ``captures/x/wand.csv``."""

    def __init__(self, app, roots: list[str]):
        self.app = app
        self.roots = [r for r in roots if r and r != "/"]

    def rewrite(self, body: bytes) -> bytes:
        return relative_paths(body.decode("utf-8", "replace"), self.roots).encode()

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or not self.roots:
            return await self.app(scope, receive, send)
        start: dict | None = None
        held: list[bytes] = []

        async def rewriting(message):
            nonlocal start
            if message["type"] == "http.response.start":
                if message["status"] < 400:
                    return await send(message)
                start = message
                return None
            if start is None:
                return await send(message)
            held.append(message.get("body", b""))
            if message.get("more_body", False) and sum(map(len, held)) <= MAX_REWRITTEN_BODY:
                return None
            body = b"".join(held)
            body = self.rewrite(body) if not message.get("more_body", False) else body
            headers = [(k, v) for k, v in start["headers"] if k.lower() != b"content-length"]
            if not message.get("more_body", False):
                headers.append((b"content-length", str(len(body)).encode()))
            await send(dict(start, headers=headers))
            start = None
            held.clear()
            await send({"type": "http.response.body", "body": body, "more_body": message.get("more_body", False)})
            return None

        await self.app(scope, receive, rewriting)
