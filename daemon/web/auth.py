"""The API key: made at the first start, kept in ``state_dir/api_key`` (mode 0600),
accepted as ``X-Api-Key``, ``?apikey=`` or ``Authorization: Bearer``.

The comparison is constant-time (:func:`hmac.compare_digest`) and never looks at the
``Host`` header: a slicer may address the Pi by IP or by name.
"""

from __future__ import annotations

import hmac
import os
import secrets
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the CLI reads the key without loading aiohttp
    from aiohttp import web

KEY_FILE = "api_key"

#: Endpoints a slicer calls before it has been told the key (its connection test).
PUBLIC = frozenset({("GET", "/api/version"), ("GET", "/server/info")})

#: The status page and its static files: they hold no data (it is read with the key).
PUBLIC_PAGE = ("/", "/static/")


def is_public(method: str, path: str) -> bool:
    if (method, path) in PUBLIC:
        return True
    return method in ("GET", "HEAD") and (path == "/" or path.startswith(PUBLIC_PAGE[1]))


def key_path(state_dir: Path) -> Path:
    return state_dir / KEY_FILE


def read_key(state_dir: Path) -> str | None:
    """The stored key, or None if the daemon has not made one yet."""
    try:
        key = key_path(state_dir).read_text(encoding="ascii").strip()
    except (FileNotFoundError, UnicodeDecodeError):
        return None
    return key or None


def load_or_create_key(state_dir: Path) -> str:
    """The stored key; a new random one (written with mode 0600) if there is none."""
    key = read_key(state_dir)
    if key:
        return key
    key = secrets.token_urlsafe(24)
    path = key_path(state_dir)
    tmp = path.with_name(f".{KEY_FILE}.{os.getpid()}")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        os.write(fd, (key + "\n").encode("ascii"))
        os.fsync(fd)
    finally:
        os.close(fd)
    os.chmod(tmp, 0o600)
    os.replace(tmp, path)
    return key


def presented_key(request: web.Request) -> str:
    """The key the client sent, from whichever of the three places it used."""
    key = request.headers.get("X-Api-Key")
    if key:
        return key.strip()
    auth = request.headers.get("Authorization", "")
    scheme, _, token = auth.partition(" ")
    if scheme.lower() == "bearer" and token.strip():
        return token.strip()
    return request.query.get("apikey", "")


UNAUTHORISED = "invalid or missing API key (see `preflight api-key`)"


def key_ok(request: web.Request, key: str) -> bool:
    """True for a public endpoint or a request carrying ``key`` (constant-time compare)."""
    if is_public(request.method, request.path):
        return True
    return hmac.compare_digest(presented_key(request).encode("utf-8", "replace"),
                               key.encode("utf-8"))


def key_middleware(key: str) -> Callable:
    """An aiohttp middleware answering 401 to every non-public request without the key."""
    from aiohttp import web

    @web.middleware
    async def check_key(request: web.Request,
                        handler: Callable[[web.Request], Awaitable[web.StreamResponse]]
                        ) -> web.StreamResponse:
        if not key_ok(request, key):
            return web.json_response({"error": UNAUTHORISED}, status=401)
        return await handler(request)

    return check_key
