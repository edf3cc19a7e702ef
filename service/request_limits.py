"""Request limits: body size (413) and per-capture frame-set rate (429), each with a reason."""

from __future__ import annotations

import json
import re
import threading
import time

from fastapi import HTTPException

# A JSON body is parsed whole into Python objects (about 10-20 bytes of memory per byte of JSON,
# docs/reliability.md), so JSON routes get a limit of their own, far below the uploads': 5,000
# blob sets of 8 cameras with two blobs each are ~1.5 MB; 8 MiB leaves room for more blobs.
MAX_BLOBSETS_BODY_BYTES = 8 * 1024 * 1024
MAX_JSON_BODY_BYTES = 1024 * 1024  # a job, a live capture's start with an inline rig.json: kilobytes
JSON_ROUTE = re.compile(r"/api/v1/(jobs|capture(/[a-z]+)?)/?$")
BLOBSETS_ROUTE = re.compile(r"/api/v1/captures/[^/]+/blobsets/?$")
# a check posts a whole wandcal-result/1 document: 40 KiB at 16 cameras, about 0.3 MiB at 128
MAX_CHECK_BODY_BYTES = 4 * 1024 * 1024
CHECK_ROUTE = re.compile(r"/api/v1/captures/[^/]+/check/?$")


def body_limit(path: str, max_upload_bytes: int) -> tuple[int, str]:
    """The largest body a route takes, and the setting or limit that says so."""
    if BLOBSETS_ROUTE.match(path):
        return min(MAX_BLOBSETS_BODY_BYTES, max_upload_bytes), "the blob-set limit; send fewer sets a request"
    if CHECK_ROUTE.match(path):
        return min(MAX_CHECK_BODY_BYTES, max_upload_bytes), "the check's limit (a result document of 1,000 cameras)"
    if JSON_ROUTE.match(path):
        return min(MAX_JSON_BODY_BYTES, max_upload_bytes), "the JSON request limit"
    return max_upload_bytes, "upload smaller files or raise WANDCAL_MAX_UPLOAD_BYTES"


class BodySizeLimit:
    """ASGI middleware refusing bodies over the route's limit (:func:`body_limit`): at once from
    Content-Length, or as the body streams in (chunked uploads), before any of it is parsed or spooled."""

    def __init__(self, app, max_bytes: int):
        self.app = app
        self.max_bytes = max_bytes

    def message(self, limit: int | None = None, what: str = "upload smaller files or raise "
                "WANDCAL_MAX_UPLOAD_BYTES") -> str:
        return f"request body larger than this server's limit of {limit or self.max_bytes} bytes; {what}"

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        limit, what = body_limit(scope.get("path", ""), self.max_bytes)
        length = dict(scope.get("headers") or []).get(b"content-length")
        if length is not None and (not length.isdigit() or int(length) > limit):
            status = 413 if length.isdigit() else 400
            detail = self.message(limit, what) if status == 413 else "Content-Length is not a whole number"
            body = json.dumps({"detail": detail}).encode()
            await send({"type": "http.response.start", "status": status,
                        "headers": [(b"content-type", b"application/json"), (b"connection", b"close")]})
            await send({"type": "http.response.body", "body": body})
            return
        seen = 0

        async def counted():
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > limit:
                    raise HTTPException(413, self.message(limit, what))
            return message

        await self.app(scope, counted, send)


class RateLimiter:
    """A token bucket per key: ``rate`` per second, bursts of up to one second's worth."""

    def __init__(self, rate: float, clock=time.monotonic):
        self.rate = rate
        self.capacity = max(1.0, rate)
        self.clock = clock
        self._buckets: dict[str, tuple[float, float]] = {}
        self._lock = threading.Lock()

    def take(self, key: str) -> float:
        """Spend one token; returns 0 on success, else the seconds to wait for the next token."""
        with self._lock:
            now = self.clock()
            tokens, last = self._buckets.get(key, (self.capacity, now))
            tokens = min(self.capacity, tokens + (now - last) * self.rate)
            if tokens >= 1.0:
                self._buckets[key] = (tokens - 1.0, now)
                return 0.0
            self._buckets[key] = (tokens, now)
            return (1.0 - tokens) / self.rate
