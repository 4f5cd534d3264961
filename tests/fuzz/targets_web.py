"""Fuzz targets of the web API's uploads: the names, folders and multipart bodies strangers
send (bodies go through aiohttp's real multipart reader and the upload's receive())."""

from __future__ import annotations

import asyncio
import tempfile
import warnings
from pathlib import Path

from aiohttp.base_protocol import BaseProtocol
from aiohttp.streams import StreamReader
from aiohttp.test_utils import make_mocked_request
from harness import Target
from hypothesis import strategies as st

from daemon.web.uploads import Refused, SizeLimit, check_folder, check_upload_name, receive

#: Any code point, surrogates and control characters included, plus the usual suspects.
_CHARS = st.characters(blacklist_categories=())
_PIECES = st.sampled_from(["..", "/", "\\", "\x00", ".gcode", ".bgcode", ".stl", "C:", " ",
                           "\u202e", "\ud800", "a" * 120])
_TEXT = st.lists(st.one_of(st.text(_CHARS, max_size=20), _PIECES), max_size=20).map("".join)

TARGETS = [
    Target("upload-name", _TEXT, check_upload_name, (Refused,),
           ("daemon.web.uploads", "daemon.safety")),
    Target("upload-folder", _TEXT, check_folder, (Refused,),
           ("daemon.web.uploads", "daemon.safety")),
]


# --- multipart bodies through the real aiohttp reader and the upload's receive() -----------

BOUNDARY = "XyZ"
_SPOOL = Path(tempfile.mkdtemp(prefix="preflight-fuzz-web-"))
_LIMIT = SizeLimit(1 << 16, "[web] max_upload_mb")


def _part(name: bytes, filename: bytes | None, data: bytes, extra: bytes) -> bytes:
    disp = b'Content-Disposition: form-data; name="' + name + b'"'
    if filename is not None:
        disp += b'; filename="' + filename + b'"'
    return b"--" + BOUNDARY.encode() + b"\r\n" + disp + b"\r\n" + extra + b"\r\n" + data + b"\r\n"


_NAMES = st.sampled_from([b"file", b"print", b"path", b"select", b"root", b"", b'a"b'])
_FILENAMES = st.one_of(st.none(), st.sampled_from([b"a.gcode", b"../a.gcode", b"a.bgcode",
                                                   b"\xff\xfe.stl", b"a\\\\b.gcode"]),
                       st.binary(max_size=40))
_EXTRA = st.sampled_from([b"", b"Content-Type: application/octet-stream\r\n",
                          b"Content-Transfer-Encoding: base64\r\n",
                          b"Content-Encoding: gzip\r\n", b"X: \x00\r\n"])
_BODIES = st.one_of(
    st.binary(max_size=300),
    st.tuples(st.lists(st.tuples(_NAMES, _FILENAMES, st.binary(max_size=200), _EXTRA),
                       max_size=5),
              st.sampled_from([b"--XyZ--\r\n", b"--XyZ--", b"", b"--XyZ", b"junk"]),
              st.integers(min_value=0, max_value=400))
    .map(lambda t: (b"".join(_part(*p) for p in t[0]) + t[1])[:t[2] or None]),
)


def _receive(body: bytes) -> None:
    async def go() -> None:
        loop = asyncio.get_running_loop()
        payload = StreamReader(BaseProtocol(loop), 2**16, loop=loop)
        payload.feed_data(body)
        payload.feed_eof()
        request = make_mocked_request("POST", "/api/files/local", headers={
            "Content-Type": f"multipart/form-data; boundary={BOUNDARY}",
            "Content-Length": str(len(body))}, payload=payload)
        try:
            up = await receive(request, _SPOOL, _LIMIT, None)
            up.discard()
        finally:
            leftovers = list(_SPOOL.iterdir())
            assert not leftovers, f"receive left {leftovers} behind"

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # aiohttp warns about odd Content-Disposition headers
        asyncio.run(go())


TARGETS.append(Target("upload-multipart", _BODIES, _receive, (Refused,),
                      ("daemon.web.uploads",)))
