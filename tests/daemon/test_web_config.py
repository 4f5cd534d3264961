"""The [web] section: its defaults, turning the API off, errors that name the key."""

import pytest

from daemon.config import ConfigError, parse_config, split_listen


def test_web_defaults_listen_on_8080_with_a_1024_mb_limit():
    cfg = parse_config({})
    assert cfg.web.listen == "0.0.0.0:8080"
    assert cfg.web.max_upload_mb == 1024
    assert split_listen(cfg.web.listen) == ("0.0.0.0", 8080)


def test_web_listen_forms():
    assert parse_config({"web": {"listen": ""}}).web.listen == ""
    assert split_listen("127.0.0.1:0") == ("127.0.0.1", 0)
    assert split_listen("[::]:8080") == ("::", 8080)
    cfg = parse_config({"web": {"listen": "192.168.1.5:80", "max_upload_mb": 50}})
    assert (cfg.web.listen, cfg.web.max_upload_mb) == ("192.168.1.5:80", 50)


@pytest.mark.parametrize("bad, words", [
    ({"listen": "8080"}, "[web] listen"), ({"listen": "host:port"}, "[web] listen"),
    ({"listen": ":8080"}, "[web] listen"), ({"listen": "0.0.0.0:70000"}, "[web] listen"),
    ({"listen": 8080}, "[web] listen"), ({"max_upload_mb": 0}, "[web] max_upload_mb"),
    ({"max_upload_mb": "big"}, "[web] max_upload_mb"), ({"port": 1}, "[web] port: unknown"),
])
def test_bad_web_values_name_the_key(bad, words):
    with pytest.raises(ConfigError, match=words.replace("[", r"\[").replace("]", r"\]")):
        parse_config({"web": bad})


def test_upload_limit_is_the_smaller_of_the_web_and_spool_limits():
    from daemon.web.uploads import size_limit

    cfg = parse_config({})  # [limits] max_file_mb 200 < [web] max_upload_mb 1024
    assert size_limit(cfg).max_bytes == 200 * 1048576
    assert "[limits] max_file_mb" in size_limit(cfg).refusal("the file").reason
    cfg = parse_config({"web": {"max_upload_mb": 10}})
    assert (size_limit(cfg).max_bytes, size_limit(cfg).key) == (10 * 1048576,
                                                                "[web] max_upload_mb")
    assert size_limit(cfg).refusal("the file").status == 413
