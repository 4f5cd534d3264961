"""Streaming benchmark: lines/s and the fraction of the serial link's physical limit.

For ping-pong, buffered and auto (buffered, one line in flight while noisy) modes,
at 115200 and 250000 baud, on a clean line and with 1% of host->printer bytes
corrupted, it streams the same G-code to the virtual printer
(moves sped up so that the link, not the motion, is the bottleneck) and prints:

    lines/s, payload bytes/s, link use = bytes sent / (baud / 10)

"bytes sent" counts everything written, resends included, so under corruption the
useful fraction is lines/s relative to the clean run, printed as "vs clean".
Run: .venv/bin/python bench/bench_stream.py [--lines N]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from printer.gcode import clean_lines  # noqa: E402
from printer.host import PrinterHost  # noqa: E402
from printer.virtual import Faults, VirtualPrinter  # noqa: E402


def make_gcode(n: int) -> list[str]:
    out = ["G28", "G92 E0"]
    e = 0.0
    for i in range(n):
        e += 0.0171
        out.append(f"G1 X{20 + (i * 37) % 180}.{i % 10} Y{20 + (i * 53) % 160}.{i % 7} E{e:.4f}")
    return out


def run(mode: str, baud: int, corrupt: float, lines: list[str]) -> dict:
    with VirtualPrinter("marlin", baud=baud, speedup=1e6, keepalive=0.5) as vp:
        with PrinterHost(vp.port, baud, mode=mode, timeout=0.5) as host:
            vp.faults = Faults(corrupt=corrupt, seed=42)  # noise on the stream, not the hello
            start = time.monotonic()
            result = host.stream(lines)
            seconds = time.monotonic() - start
        executed = [c for n, c in vp.executed_numbered if n is not None and n >= 1]
    commands = clean_lines(lines)
    ok = [n for n, _ in vp.executed_numbered if n is not None and n >= 1] == list(
        range(1, len(commands) + 1)
    )
    return {
        "lines_per_s": len(commands) / seconds,
        "bytes_per_s": result.bytes_sent / seconds,
        "link_use": result.bytes_sent / seconds / (baud / 10.0),
        "resends": result.resends,
        "exact": ok and len(executed) == len(commands),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lines", type=int, default=3000)
    args = parser.parse_args()
    lines = make_gcode(args.lines)
    payload = sum(len(c) + 1 for c in clean_lines(lines))
    print(f"{len(clean_lines(lines))} commands, {payload} payload bytes (before N/checksum)")
    print(f"{'mode':10} {'baud':>7} {'noise':>6} {'lines/s':>9} {'bytes/s':>9} "
          f"{'link use':>9} {'vs clean':>9} {'resends':>8} exactly-once")
    for baud in (115200, 250000):
        for mode in ("ping-pong", "buffered", "auto"):
            clean_rate = None
            for corrupt in (0.0, 0.01):
                r = run(mode, baud, corrupt, lines)
                if clean_rate is None:
                    clean_rate = r["lines_per_s"]
                print(
                    f"{mode:10} {baud:>7} {corrupt:>6.0%} {r['lines_per_s']:>9.0f} "
                    f"{r['bytes_per_s']:>9.0f} {r['link_use']:>9.1%} "
                    f"{r['lines_per_s'] / clean_rate:>9.1%} {r['resends']:>8} "
                    f"{'yes' if r['exact'] else 'NO'}",
                    flush=True,
                )
    return 0


if __name__ == "__main__":
    sys.exit(main())
