"""Profile defaults follow the printer; overrides and TOML files are validated."""

from __future__ import annotations

import pytest

from slicer.profile import Profile, ProfileError, load_profile


def test_defaults_follow_the_nozzle_and_printer():
    p = Profile.for_printer(nozzle_diameter=0.6, build_volume=(300, 250, 200),
                            filament_diameter=2.85, flavour="klipper")
    assert p.line_width == pytest.approx(1.125 * 0.6)
    assert p.layer_height == pytest.approx(0.3)
    assert p.build_volume == (300.0, 250.0, 200.0)
    assert p.filament_diameter == 2.85
    assert p.flavour == "klipper"
    assert Profile.for_printer(flavour="rrf").flavour == "reprapfirmware"
    assert Profile.for_printer(flavour="buddy").flavour == "marlin"
    with pytest.raises(ProfileError, match="flavour"):
        Profile.for_printer(flavour="makerbot")


def test_overrides_parse_strings_and_reject_unknown_keys():
    p = Profile.for_printer().with_overrides(
        {"infill_percent": "35", "relative_e": "false", "perimeters": 3,
         "build_volume": "180,180,180", "infill_pattern": "rectilinear"})
    assert p.infill_percent == 35.0
    assert p.relative_e is False
    assert p.perimeters == 3
    assert p.build_volume == (180.0, 180.0, 180.0)
    with pytest.raises(ProfileError, match="infil_percent"):
        p.with_overrides({"infil_percent": 10})
    with pytest.raises(ProfileError, match="perimeters"):
        p.with_overrides({"perimeters": "2.5"})
    with pytest.raises(ProfileError, match="infill_pattern"):
        p.with_overrides({"infill_pattern": "honeycomb"})
    with pytest.raises(ProfileError, match="layer_height"):
        p.with_overrides({"layer_height": 0.9})


def test_toml_profile_round_trip(tmp_path):
    base = Profile.for_printer(nozzle_diameter=0.4)
    f = tmp_path / "p.toml"
    f.write_text('[slicer]\ninfill_percent = 50\nskirts = 2\nstart_gcode = "M109 S{temperature}"\n')
    p = load_profile(f, base)
    assert (p.infill_percent, p.skirts) == (50.0, 2)
    assert p.line_width == base.line_width
    d = p.to_dict()
    assert d["infill_percent"] == 50.0 and d["build_volume"] == list(base.build_volume)
    assert Profile().with_overrides(d) == p
    bad = tmp_path / "bad.toml"
    bad.write_text("colour = 'red'\n")
    with pytest.raises(ProfileError, match="colour"):
        load_profile(bad, base)
    broken = tmp_path / "broken.toml"
    broken.write_text("infill_percent = = 3\n")
    with pytest.raises(ProfileError, match="TOML"):
        load_profile(broken, base)
