"""The upload name and folder checks on their own, with the inputs fuzzing found."""

import pytest

from daemon.safety import display_name
from daemon.web.uploads import Refused, check_folder, check_upload_name


def test_a_lone_surrogate_in_a_name_is_refused_not_a_crash():
    # found by tests/fuzz/test_fuzz_web.py: display_name raised UnicodeEncodeError
    for check in (check_upload_name, check_folder):
        with pytest.raises(Refused) as err:
            check("\ud800")
        assert err.value.status == 400 and "not valid UTF-8" in err.value.reason
    assert display_name("\ud800.stl") == "\ufffd\ufffd\ufffd.stl"
    assert display_name("caf\udce9.stl") == "caf\ufffd.stl"  # a Latin-1 byte from listdir


@pytest.mark.parametrize("name, status", [
    ("part.gcode", None), ("Part (2) v1.3MF", None), ("a.bgcode", 415), ("a.txt", 415),
    ("../a.gcode", 400), ("a/b.gcode", 400), ("a\\b.gcode", 400), ("a\x00.gcode", 400),
    ("x" * 250 + ".gcode", 400), ("é" * 126 + ".stl", 400),
])
def test_upload_names(name, status):
    if status is None:
        check_upload_name(name)
        return
    with pytest.raises(Refused) as err:
        check_upload_name(name)
    assert err.value.status == status


@pytest.mark.parametrize("folder, ok", [
    ("", True), ("/", True), ("prints/today", True), ("a/./b/", True), ("../x", False),
    ("/etc", False), ("\\\\server\\share", False), ("C:\\x", False), ("a/../../b", False),
    ("x\x00y", False), ("ok/" + "f" * 300, False),
])
def test_upload_folders(folder, ok):
    if ok:
        check_folder(folder)
        return
    with pytest.raises(Refused) as err:
        check_folder(folder)
    assert err.value.status == 400


def test_a_long_hostile_folder_gets_a_short_one_line_reason():
    # found by tests/fuzz/test_fuzz_web.py: the folder and its part were both echoed, 501 chars
    folder = ("000000\x1f000\U0002ebe100\x1f\x1f00\x1f\x1f000\x1f\x1f000000000000000\U0001e8c5"
              "\U0002ebe1000000000\x1f\x1f\x1f\x1f\x08\U00011747\U0003134b00000000000\x1f\x1f"
              "\x1f\x1f\x08\U00018cd600000000000\x1f\x1f\x1f\x1f\x08\U00018cd6")
    with pytest.raises(Refused) as err:
        check_folder(folder)
    assert err.value.status == 400 and len(err.value.reason) <= 300
    assert "\n" not in err.value.reason and err.value.reason.startswith("refused: the path")
