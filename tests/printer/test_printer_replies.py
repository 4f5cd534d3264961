"""Reply parsing, table-driven over real reply strings from each firmware family."""

import pytest

from printer import replies
from printer.gcode import checksum, clean_line, frame


@pytest.mark.parametrize(
    ("number", "command", "framed"),
    [(0, "M110 N0", "N0 M110 N0*125"), (1, "M115", "N1 M115*39"), (2, "M105", "N2 M105*37")],
)
def test_checksum_vectors(number, command, framed):
    assert frame(number, command) == framed
    body, cs = framed.split("*")
    assert checksum(body) == int(cs)


@pytest.mark.parametrize(
    ("raw", "clean"),
    [
        ("G1 X10 Y10 ; move", "G1 X10 Y10"),
        ("  ; only a comment", None),
        ("", None),
        ("M117 (hello) world", "M117  world"),
        ("G28\r", "G28"),
    ],
)
def test_clean_line(raw, clean):
    assert clean_line(raw) == clean


# (line, kind, number) -- strings as Marlin 2.x, Prusa MK3, Buddy, Klipper and RRF print them
KIND_TABLE = [
    ("ok", "ok", None),
    ("ok N10 P15 B3", "ok", 10),  # Marlin ADVANCED_OK
    ("ok T:210.00 /210.00 B:60.00 /60.00 @:127 B@:0", "ok", None),
    ("Resend: 6", "resend", 6),
    ("Resend:6", "resend", 6),
    ("rs 6", "resend", 6),  # RepRapFirmware / Teacup
    ("rs N6", "resend", 6),
    ("Error:checksum mismatch, Last Line: 5", "line_error", 5),
    ("Error:Line Number is not Last Line Number+1, Last Line: 5", "line_error", 5),
    ("Error:No Checksum with line number, Last Line: 5", "line_error", 5),
    ("echo:busy: processing", "busy", None),
    ("echo:busy: paused for user", "busy", None),
    ("start", "start", None),
    ("Error:Printer halted. kill() called!", "fatal", None),
    ("Error:Thermal Runaway, system stopped! Heater_ID: 0", "fatal", None),
    ("Error:MINTEMP triggered, system stopped! Heater_ID: bed", "fatal", None),
    ("!! Lost communication with MCU 'mcu'", "fatal", None),  # Klipper
    ("!! Move out of range: 300.000 0.000 0.200 [0.000]", "fatal", None),
    ('echo:Unknown command: "M862.1 Q"', "unknown_command", None),  # Marlin
    ('// Unknown command:"M862.1"', "unknown_command", None),  # Klipper
    ("Error: M862.1: Command is not supported", "unknown_command", None),
    (" T:210.00 /210.00 B:60.00 /60.00 @:127 B@:0", "temperature", None),  # M155 report
    ("T:20.2 /0.0 B:19.6 /0.0 T0:20.2 /0.0 @:0 B@:0 P:0.0 A:26.4", "temperature", None),
    ("// Klipper state: Ready", "comment", None),
    ("echo:Marlin 2.1.2.1", "echo", None),
    ("X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0", "other", None),
]


@pytest.mark.parametrize(("line", "kind", "number"), KIND_TABLE)
def test_reply_kinds(line, kind, number):
    reply = replies.parse_reply(line)
    assert reply.kind == kind
    assert reply.number == number


def test_advanced_ok_fields():
    reply = replies.parse_reply("ok N10 P15 B3")
    assert (reply.number, reply.planner_free, reply.queue_free) == (10, 15, 3)
    assert not reply.is_temperature_ok


def test_heating_keepalive_marks_waiting():
    reply = replies.parse_reply(" T:180.52 /210.00 B:60.01 /60.00 @:127 B@:0 W:?")
    assert reply.kind == "temperature" and reply.waiting


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("T:210.00 /210.00", {"T": (210.0, 210.0)}),
        ("T:210.00/210.00", {"T": (210.0, 210.0)}),
        ("ok T:19.57 /0.00 B:20.62 /30.00 @:0 B@:127", {"T": (19.57, 0.0), "B": (20.62, 30.0)}),
        ("ok B:60.0 /60.0 T0:210.0 /210.0", {"B": (60.0, 60.0), "T0": (210.0, 210.0)}),
        ("T0:205.3 /205.0 T1:24.1 /0.0 B:59.9 /60.0", {
            "T0": (205.3, 205.0), "T1": (24.1, 0.0), "B": (59.9, 60.0)}),
        ("T:25.0 B:24.0", {"T": (25.0, None), "B": (24.0, None)}),
    ],
)
def test_temperatures_all_spacings(text, expected):
    temps = replies.parse_temperatures(text)
    for key, value in expected.items():
        assert temps[key] == value
    assert "@" not in temps and "W" not in temps


def test_m115_marlin_fields_caps_and_area():
    line = (
        "FIRMWARE_NAME:Marlin 2.1.2.1 (Feb  1 2024 12:00:00) SOURCE_CODE_URL:github.com/"
        "MarlinFirmware/Marlin PROTOCOL_VERSION:1.0 MACHINE_TYPE:Ender-3 V2 EXTRUDER_COUNT:1 "
        "UUID:cede2a2f-41a2-4748-9b12-c55c62f367ff"
    )
    fields = replies.parse_firmware_fields(line)
    assert fields["FIRMWARE_NAME"] == "Marlin 2.1.2.1 (Feb  1 2024 12:00:00)"
    assert fields["MACHINE_TYPE"] == "Ender-3 V2"
    assert fields["EXTRUDER_COUNT"] == "1"
    assert replies.parse_capability("Cap:AUTOREPORT_TEMP:1") == ("AUTOREPORT_TEMP", True)
    assert replies.parse_capability("Cap:EMERGENCY_PARSER:0") == ("EMERGENCY_PARSER", False)
    assert replies.parse_capability("ok") is None
    area = replies.parse_area(
        "area:{full:{min:{x:-5.00,y:-5.00,z:0.00},max:{x:240.00,y:240.00,z:250.00}},"
        "work:{min:{x:0.00,y:0.00,z:0.00},max:{x:230.00,y:230.00,z:250.00}}}"
    )
    assert area["work"] == ((0.0, 0.0, 0.0), (230.0, 230.0, 250.0))
    assert area["full"] == ((-5.0, -5.0, 0.0), (240.0, 240.0, 250.0))


@pytest.mark.parametrize(
    ("line", "name"),
    [
        ("FIRMWARE_NAME:Prusa-Firmware 3.14.1 based on Marlin FIRMWARE_URL:https://github.com/"
         "prusa3d/Prusa-Firmware PROTOCOL_VERSION:1.0 MACHINE_TYPE:Prusa i3 MK3S EXTRUDER_COUNT:1",
         "Prusa-Firmware 3.14.1 based on Marlin"),
        ("FIRMWARE_NAME:Prusa-Firmware-Buddy 6.1.3+8542 (Github) SOURCE_CODE_URL:https://"
         "github.com/prusa3d/Prusa-Firmware-Buddy PROTOCOL_VERSION:1.0 MACHINE_TYPE:Prusa-MK4",
         "Prusa-Firmware-Buddy 6.1.3+8542 (Github)"),
        ("ok FIRMWARE_NAME:Klipper FIRMWARE_VERSION:v0.12.0-114-ga77d0790", "Klipper"),
        ("FIRMWARE_NAME: RepRapFirmware for Duet 2 WiFi/Ethernet FIRMWARE_VERSION: 3.4.5 "
         "ELECTRONICS: Duet WiFi 1.02 or later FIRMWARE_DATE: 2022-11-30 19:36:12",
         "RepRapFirmware for Duet 2 WiFi/Ethernet"),
    ],
)
def test_m115_other_firmwares(line, name):
    assert replies.parse_firmware_fields(line)["FIRMWARE_NAME"] == name


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("  Min:  X0.00 Y0.00 Z0.00   Max:  X250.00 Y210.00 Z220.00",
         ((0.0, 0.0, 0.0), (250.0, 210.0, 220.0))),
        ("echo:Soft endstops: On   Min:  X0.00 Y-6.00 Z0.00   Max:  X430.00 Y430.00 Z500.00",
         ((0.0, -6.0, 0.0), (430.0, 430.0, 500.0))),
        ("echo:  M211 S1 ; ON", None),
    ],
)
def test_m211(line, expected):
    assert replies.parse_soft_endstops(line) == expected


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("Axis limits (mm) X0.0:230.0, Y0.0:210.0, Z0.0:200.0",
         ((0.0, 0.0, 0.0), (230.0, 210.0, 200.0))),
        ("Axis limits X-4.0:235.0, Y0.0:230.0, Z-0.2:250.0",
         ((-4.0, 0.0, -0.2), (235.0, 230.0, 250.0))),
        ("ok", None),
    ],
)
def test_m208(line, expected):
    assert replies.parse_axis_limits(line) == expected


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("echo:  M200 S0 D1.75", 1.75),
        ("echo:  M200 D2.85", 2.85),
        ("echo:  M200 T0 D1.75", 1.75),
        ("echo:; Filament settings (Disabled):", None),
        ("echo:  M200 D0", None),
    ],
)
def test_m200(line, expected):
    assert replies.parse_filament_diameter(line) == expected


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("0.40", 0.4),  # Prusa MK3 M862.1 Q
        ("0.60", 0.6),
        ("echo:  M862.1 T0 P0.40 A0 F0", 0.4),  # Prusa Buddy
        ("echo:  M862.1 T0 P0.60 A1 F1", 0.6),
        ("// nozzle_diameter: 0.400", 0.4),  # a Klipper macro
        ("// 0.25", 0.25),
        ('echo:Unknown command: "M862.1 Q"', None),
        ('// Unknown command:"M862.1"', None),
        ("ok", None),
        ("25", None),  # not a plausible nozzle diameter
    ],
)
def test_nozzle_replies(line, expected):
    assert replies.parse_nozzle_reply(line) == expected


@pytest.mark.parametrize(
    ("line", "command"),
    [
        ('echo:Unknown command: "M862.1 Q"', "M862.1 Q"),
        ('// Unknown command:"M862.1"', "M862.1"),
        ("Error: M862.1: Command is not supported", "M862.1"),
        ("ok", None),
    ],
)
def test_unknown_command(line, command):
    assert replies.unknown_command_of(line) == command


@pytest.mark.parametrize(("line", "kind"), [
    ("Resend: " + "9" * 4301, "resend"),
    ("Error:Line Number is not Last Line Number+1, Last Line: " + "9" * 4301, "line_error"),
    ("ok N" + "9" * 5000 + " P15 B3", "ok"),
])
def test_huge_numbers_in_replies_saturate(line, kind):
    """Fuzz regression: int() of more than 4300 digits raised ValueError in parse_reply."""
    reply = replies.parse_reply(line)
    assert reply.kind == kind
    assert reply.number == 2**31 - 1


# (line, keep-alive form) -- what each firmware prints while M109/M190/G28/G29 run, and
# lines that look alike but are not keep-alives (auto-reports, M105 replies, echoes)
KEEPALIVE_TABLE = [
    ("echo:busy: processing", "busy"),  # Marlin HOST_KEEPALIVE during G28/G29/M400
    ("busy: processing", "busy"),
    ("echo:busy: paused for user", "busy"),  # M600 / M0
    (" T:180.52 /210.00 B:60.01 /60.00 @:127 B@:0 W:?", "wait"),  # Marlin M109
    (" T:209.31 /210.00 B:60.00 /60.00 @:64 B@:0 W:8", "wait"),  # Marlin, residency count
    ("T:25.3 /210.0 B:41.2 /60.0 @:127 B@:127 W:?", "wait"),  # Marlin M190
    ("T:205.3 E:0 W:3", "prusa_wait"),  # Prusa MK3 M109
    ("T:201.2 E:0 W:?", "prusa_wait"),
    ("T:25.0 E:0 B:40.5", "prusa_wait"),  # Prusa MK3 M190
    ("B:41.0 /60.0 T0:120.3 /210.0", "bare"),  # Klipper M190 / M109, once a second
    ("T0:120.3 /210.0 B:41.0 /60.0", "bare"),
    (" T:210.00 /210.00 B:60.00 /60.00 @:127 B@:0", None),  # Marlin M155 auto-report
    ("T:20.2 /0.0 B:19.6 /0.0 T0:20.2 /0.0 @:0 B@:0 P:0.0 A:26.4", None),  # Prusa M155
    ("ok T:210.00 /210.00 B:60.00 /60.00 @:127 B@:0", None),  # M105 reply
    ("ok B:60.0 /60.0 T0:210.0 /210.0", None),  # Klipper M105 reply
    ("T:25.0 B:24.0", None),  # targets unknown: could be anything
    ("echo:Marlin 2.1.2.1", None),
    ("ok", None),
    ("X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0", None),  # M114
]


@pytest.mark.parametrize(("line", "form"), KEEPALIVE_TABLE)
def test_keepalive_forms(line, form):
    assert replies.keepalive_form(replies.parse_reply(line)) == form


@pytest.mark.parametrize(
    ("temps", "expected"),
    [
        ({"T": (25.0, 210.0), "B": (40.0, 60.0), "P": (30.0, None), "A": (26.4, None)},
         {"T": (25.0, 210.0), "B": (40.0, 60.0)}),  # Prusa probe and ambient dropped
        ({"B": (41.0, 60.0), "T0": (120.3, 210.0)}, {"B": (41.0, 60.0), "T": (120.3, 210.0)}),
        ({"T0": (1.0, 2.0), "T1": (3.0, 4.0)}, {"T": (1.0, 2.0), "T1": (3.0, 4.0)}),
        ({"T": (1.0, 2.0), "T0": (1.0, 2.0)}, {"T": (1.0, 2.0), "T0": (1.0, 2.0)}),
        ({"C": (30.0, 45.0)}, {"C": (30.0, 45.0)}),
    ],
)
def test_heater_readings(temps, expected):
    assert replies.heater_readings(temps) == expected
