"""Fuzz targets of the web API's upload checks: the names and folders strangers send."""

from __future__ import annotations

from harness import Target
from hypothesis import strategies as st

from daemon.web.uploads import Refused, check_folder, check_upload_name

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
