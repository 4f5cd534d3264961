"""Raw HTTP for the web tests: requests written byte for byte on a real socket, the way
the slicers send them, and the daemon started with its API on a free loopback port."""

from __future__ import annotations

import json
import secrets
import socket
from dataclasses import dataclass
from pathlib import Path

from daemon_helpers import DaemonProc

from daemon.web.auth import read_key


@dataclass
class Answer:
    status: int
    headers: dict[str, str]
    body: bytes
    continued: bool = False  # the server sent "100 Continue" before the answer

    def json(self):
        return json.loads(self.body)


def start_web_daemon(d: DaemonProc) -> tuple[int, str]:
    """Start the daemon; once its web API listens and its printer is connected, return
    the web port and the API key."""
    d.start()
    web = d.wait_for(lambda: (d.status().get("web") or {}).get("port") and d.status()["web"],
                     what="the web server")
    d.wait_for(lambda: (d.status().get("printer") or {}).get("state") == "connected",
               what="the printer connected")
    key = read_key(d.cfg.daemon.state_dir)
    assert key
    return int(web["port"]), key


def _read_head(sock: socket.socket, buf: bytearray) -> tuple[int, dict[str, str], bytearray]:
    while b"\r\n\r\n" not in buf:
        chunk = sock.recv(65536)
        if not chunk:
            raise ConnectionError(f"connection closed after {bytes(buf)[:200]!r}")
        buf += chunk
    head, _, rest = bytes(buf).partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    status = int(lines[0].split()[1])
    headers = {}
    for line in lines[1:]:
        k, _, v = line.partition(":")
        headers[k.strip().lower()] = v.strip()
    return status, headers, bytearray(rest)


def _read_body(sock: socket.socket, headers: dict[str, str], rest: bytearray) -> bytes:
    if "content-length" in headers:
        n = int(headers["content-length"])
        while len(rest) < n:
            chunk = sock.recv(65536)
            if not chunk:
                break
            rest += chunk
        return bytes(rest[:n])
    while True:
        chunk = sock.recv(65536)
        if not chunk:
            return bytes(rest)
        rest += chunk


def send_raw(port: int, head: bytes, body: bytes = b"", *, wait_continue: bool = False,
             chunks: list[bytes] | None = None) -> Answer:
    """Send ``head`` (request line and headers, ending in a blank line) then ``body``
    (or ``chunks``, sent one by one); with ``wait_continue`` the body is sent only
    after the server's ``100 Continue`` (as curl does), and not at all if it answers."""
    with socket.create_connection(("127.0.0.1", port), timeout=60) as sock:
        sock.sendall(head)
        buf = bytearray()
        continued = False
        if wait_continue:
            status, headers, rest = _read_head(sock, buf)
            if status != 100:
                return Answer(status, headers, _read_body(sock, headers, rest))
            continued = True
            buf = rest
        try:
            for piece in chunks if chunks is not None else [body]:
                sock.sendall(piece)
        except (BrokenPipeError, ConnectionResetError):
            pass  # the server answered early and closed: read its answer
        status, headers, rest = _read_head(sock, buf)
        return Answer(status, headers, _read_body(sock, headers, rest), continued)


def request(port: int, method: str, path: str, *, headers: dict[str, str] | None = None,
            body: bytes = b"", host: str | None = None) -> Answer:
    lines = [f"{method} {path} HTTP/1.1", f"Host: {host or f'127.0.0.1:{port}'}"]
    lines += [f"{k}: {v}" for k, v in (headers or {}).items()]
    if body or method in ("POST", "PUT"):
        lines.append(f"Content-Length: {len(body)}")
    lines.append("Connection: close")
    return send_raw(port, ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1"), body)


def curl_boundary() -> str:
    """libcurl's boundary style (PrusaSlicer, OrcaSlicer): 24 dashes and 16 hex digits."""
    return "-" * 24 + secrets.token_hex(8)


def multipart(parts: list[tuple[str, bytes, str | None, str | None]], boundary: str) -> bytes:
    """``parts``: (field name, data, file name or None, content type or None), in order."""
    out = bytearray()
    for name, data, filename, ctype in parts:
        out += f"--{boundary}\r\n".encode()
        disp = f'Content-Disposition: form-data; name="{name}"'
        if filename is not None:  # quoted-string escapes, as libcurl writes them
            quoted = filename.replace("\\", "\\\\").replace('"', '\\"')
            disp += f'; filename="{quoted}"'
        out += disp.encode("utf-8") + b"\r\n"
        if ctype:
            out += f"Content-Type: {ctype}\r\n".encode()
        out += b"\r\n" + data + b"\r\n"
    out += f"--{boundary}--\r\n".encode()
    return bytes(out)


def upload_head(port: int, path: str, boundary: str, length: int | None, key: str | None, *,
                agent: str = "PrusaSlicer/2.8.1+linux-x64-GTK3", expect: bool = True,
                quote_boundary: bool = False, extra: str = "") -> bytes:
    """Request head of a multipart POST the way libcurl writes it."""
    b = f'"{boundary}"' if quote_boundary else boundary
    lines = [f"POST {path} HTTP/1.1", f"Host: 127.0.0.1:{port}", f"User-Agent: {agent}",
             "Accept: */*"]
    if key is not None:
        lines.append(f"X-Api-Key: {key}")
    if length is not None:
        lines.append(f"Content-Length: {length}")
    else:
        lines.append("Transfer-Encoding: chunked")
    lines.append(f"Content-Type: multipart/form-data; boundary={b}")
    if expect:
        lines.append("Expect: 100-continue")
    if extra:
        lines.append(extra)
    return ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1")


def outside_files(root: Path, spool: Path, state: Path) -> set[str]:
    """Every file under ``root`` that is not inside the spool or the state folder."""
    found = set()
    for p in root.rglob("*"):
        if p.is_file() and spool not in p.parents and state not in p.parents:
            found.add(str(p.relative_to(root)))
    return found


def executed_once(log: list[str], commands: list[str]) -> int:
    """Index where ``commands`` run contiguously in the printer's log; asserts exactly once."""
    n = len(commands)
    hits = [i for i in range(len(log) - n + 1)
            if log[i] == commands[0] and log[i:i + n] == commands]
    assert len(hits) == 1, f"the {n} commands ran {len(hits)} times"
    return hits[0]
