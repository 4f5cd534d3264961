"""Firmware that says ``wait`` while idle (Repetier, OctoPrint's virtual printer): a
lost ``ok`` must still be recovered. Those lines used to count as signs of life, so the
lost-ok timeout never ran out and the stream hung for good."""

from __future__ import annotations

import os
import select
import threading
import time
import tty

from printer.gcode import lex
from printer.host import PrinterHost


class WaitingFirmware(threading.Thread):
    """A Marlin-like line protocol on a pty (line numbers checked, ``Resend:`` + ``ok``
    on a wrong one) that loses the ``ok`` of line ``drop_ok_at`` once and prints
    ``wait`` after each ``idle`` seconds without input (a test double of such firmware)."""

    def __init__(self, link, drop_ok_at: int, idle: float = 0.3) -> None:
        super().__init__(daemon=True)
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.symlink(os.ttyname(self.slave), link)
        self.drop_ok_at = drop_ok_at
        self.idle = idle
        self.accepted: list[tuple[int, str]] = []
        self.waits = 0
        self.stop = threading.Event()

    def send(self, text: str) -> None:
        os.write(self.master, (text + "\n").encode())

    def run(self) -> None:
        pending = b""
        last_n = 0
        quiet_since = time.monotonic()
        while not self.stop.is_set():
            ready, _, _ = select.select([self.master], [], [], 0.02)
            if not ready:
                if time.monotonic() - quiet_since >= self.idle:
                    self.send("wait")
                    self.waits += 1
                    quiet_since = time.monotonic()
                continue
            pending += os.read(self.master, 4096)
            quiet_since = time.monotonic()
            while b"\n" in pending:
                raw, pending = pending.split(b"\n", 1)
                last_n = self.line(raw.decode().strip(), last_n)

    def line(self, text: str, last_n: int) -> int:
        if not text:
            return last_n
        lexed = lex(text)
        if lexed.number is None:
            if lexed.word == "M115":
                self.send("FIRMWARE_NAME:Marlin 2.1 (waiting double)")
            self.send("ok T:20.0 /0.0 B:20.0 /0.0" if lexed.word == "M105" else "ok")
            return last_n
        if lexed.word == "M110":
            self.send("ok")
            return lexed.number
        if lexed.number != last_n + 1:
            self.send(f"Error:Line Number is not Last Line Number+1, Last Line: {last_n}")
            self.send(f"Resend: {last_n + 1}")
            self.send("ok")
            return last_n
        self.accepted.append((lexed.number, lexed.command))
        if lexed.number == self.drop_ok_at:
            self.drop_ok_at = -1  # this ok is lost on the wire
        else:
            self.send("ok")
        return lexed.number

    def close(self) -> None:
        self.stop.set()
        self.join(timeout=5)
        os.close(self.master)
        os.close(self.slave)


def test_a_lost_ok_is_recovered_although_the_firmware_says_wait(tmp_path):
    commands = [f"G1 X{i % 50} Y{(i * 7) % 50} F3000" for i in range(1, 41)]
    firmware = WaitingFirmware(tmp_path / "ttyWAIT", drop_ok_at=7)
    firmware.start()
    hung = threading.Event()
    # a long timeout: only the "wait" can start the recovery; the guard only stops a
    # hung stream (it asserts nothing about speed)
    guard = threading.Timer(600, hung.set)
    guard.start()
    try:
        with PrinterHost(str(tmp_path / "ttyWAIT"), 115200, timeout=120.0,
                         mode="ping-pong") as host:
            result = host.stream(commands, cancel=hung)
    finally:
        guard.cancel()
        firmware.close()
    assert not hung.is_set()
    assert result.lines == 40 and result.timeouts == 1  # one recovery, started by "wait"
    assert firmware.accepted == [(n, c) for n, c in enumerate(commands, start=1)]
    assert firmware.waits >= 1
