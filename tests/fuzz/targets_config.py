"""Fuzz targets for the daemon's TOML config: well-formed documents with random keys and
values in the schema's sections, and random text, through the config loader.

A refusal is a :class:`daemon.config.ConfigError` whose one-line message names the key
(``[section] key: ...``) or, for a file that is not TOML at all, the file.
"""

from __future__ import annotations

import datetime
import tempfile
from pathlib import Path

import tomli_w
from harness import Target
from hypothesis import strategies as st

from daemon.config import PROFILE, SECTIONS, ConfigError, check_profile, load_config, rules

_FOLDER = Path(tempfile.mkdtemp(prefix="preflight-fuzz-config-"))

SECTION_NAMES = [*SECTIONS, PROFILE]
KEY_NAMES = sorted({key for section in SECTIONS.values() for key, _, _ in rules(section)})

names = st.text(min_size=1, max_size=12)
scalars = st.one_of(
    st.booleans(),
    st.integers(min_value=-(2**63), max_value=2**63 - 1),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=40),
    st.text(min_size=400, max_size=800),
    st.sampled_from(["virtual", "auto", "buffered", "INFO", "debug", "marlin", "/tmp/x", "~",
                     "relative/dir", "M502", " ", "", "~nobody/x"]),
    st.datetimes(min_value=datetime.datetime(1970, 1, 1)),
    st.dates(),
)
values = st.recursive(scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(names, inner, max_size=3)), max_leaves=6)
tables = st.dictionaries(st.one_of(st.sampled_from(KEY_NAMES), names), values, max_size=5)
documents = st.dictionaries(st.one_of(st.sampled_from(SECTION_NAMES), names),
                            st.one_of(tables, values), max_size=4)
raw_text = st.one_of(
    st.text(max_size=300),
    st.lists(st.sampled_from(["[spool]", "[printer]", "[daemon]", "[limits]", "[safety]",
                              "[profile]", 'path = "', "baud = 1e400", "port = 3",
                              "x = [1, 2", "= 1", "[[spool]]", "nozzle_diameter = nan",
                              "\x00", "\ufeff", "\\u0000", "workers = 0x10"]),
             max_size=12).map("\n".join),
)


def _load(text: str) -> object:
    path = _FOLDER / "preflight.toml"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    try:
        return load_config(path)
    except ConfigError as e:
        message = str(e)
        assert message.startswith(("[", "config file ")), f"names no key: {message!r}"
        raise


def load_document(document: dict) -> object:
    """A well-formed TOML document through the loader, then the [profile] check."""
    cfg = _load(tomli_w.dumps(document))
    check_profile(cfg)  # type: ignore[arg-type]
    return cfg


def load_text(text: str) -> object:
    return _load(text)


TARGETS = [
    Target("config-document", documents, load_document, (ConfigError,),
           ("daemon.config",)),
    Target("config-text", raw_text, load_text, (ConfigError,), ("daemon.config",)),
]
