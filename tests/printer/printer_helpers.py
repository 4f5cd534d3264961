"""Shared helpers for the printer tests: a test G-code program and exactly-once checks."""

from __future__ import annotations

import time

from printer.gcode import clean_lines

FAST = {"speedup": 1e6, "baud": 1_000_000, "keepalive": 0.05}
HOST = {"timeout": 0.25, "resend_settle": 0.002, "handshake_timeout": 3.0}


def program(moves: int = 300) -> list[str]:
    """A small but realistic print: heat, home, prime, moves with extrusion, cool."""
    lines = [
        "; generated for the printer tests",
        "M140 S60",
        "M104 S200",
        "G28 ; home all",
        "M190 S60",
        "M109 S200",
        "M105",
        "G90",
        "M82",
        "G92 E0",
        "G1 Z0.2 F3000",
    ]
    e = 0.0
    for i in range(moves):
        e += 0.0123
        x = 20 + (i * 37) % 180
        y = 20 + (i * 53) % 160
        lines.append(f"G1 X{x}.{i % 10} Y{y}.{(i * 3) % 10} E{e:.4f} F{1800 + (i % 5) * 600}")
        if i % 97 == 0:
            lines.append("")
            lines.append(f"; layer {i // 97}")
    lines += ["M104 S0", "M140 S0", "M107", "M84"]
    return lines


def streamed(vp) -> list[tuple[int, str]]:
    """(line number, command) of every numbered stream line the printer executed."""
    return [(n, c) for n, c in list(vp.executed_numbered) if n is not None and n >= 1]


def wait_executed(vp, count: int, patience: float = 20.0) -> None:
    """Wait until the printer has executed ``count`` stream lines (or patience runs out);
    the caller's assertions then say what is wrong."""
    end = time.monotonic() + patience
    while len(streamed(vp)) < count and time.monotonic() < end:
        time.sleep(0.01)
    time.sleep(0.05)


def assert_exactly_once(vp, raw_lines: list[str]) -> None:
    """The printer ran every command once, in order. A line that noise changed without
    breaking the XOR checksum (the printer flags those) may differ in text only."""
    commands = clean_lines(raw_lines)
    wait_executed(vp, len(commands))
    done = streamed(vp)
    assert [n for n, _ in done] == list(range(1, len(commands) + 1))
    changed = [n for (n, got), want in zip(done, commands, strict=True) if got != want]
    assert set(changed) <= set(vp.undetected_corruptions)


def assert_prefix_once(vp, raw_lines: list[str]) -> int:
    """Whatever ran is a prefix of the program, each line once; return its length."""
    commands = clean_lines(raw_lines)
    time.sleep(0.1)
    done = streamed(vp)
    assert [n for n, _ in done] == list(range(1, len(done) + 1))
    assert [c for _, c in done] == commands[: len(done)]
    return len(done)
