"""The virtual printer's firmware: line protocol, command queue, execution and faults.

It receives complete lines from the link (:mod:`printer.virtual.link`) and answers
through it. The line protocol follows each profile's ``checks``: Marlin's queue
(a line starting with ``N`` must carry the next line number and a matching XOR
checksum, else ``Error:`` + ``Resend:``), RepRapFirmware's (a bad line is dropped
without a word) or Klipper's (N and checksum ignored, never a resend).
"""

from __future__ import annotations

import random
from collections import deque
from dataclasses import dataclass
from typing import Protocol

from printer.gcode import checksum, command_word, lex
from printer.virtual.commands import begin
from printer.virtual.faults import Faults
from printer.virtual.physics import Heaters, Motion
from printer.virtual.profiles import FirmwareProfile


class Wire(Protocol):
    """What the firmware needs of the serial link it sits behind."""

    def send(self, text: str) -> None: ...

    def clear_receive_buffer(self) -> None: ...

    def hang_up(self) -> None: ...

    def reset_wire(self) -> None: ...


@dataclass(frozen=True)
class MachineSettings:
    """What does not change while the printer runs. nozzle: mm. speedup: simulated time
    runs this many times faster. queue_size: commands the firmware buffers (BUFSIZE).
    advanced_ok: ``ok N P B``. build_volume: (x, y, z) mm. keepalive: real seconds
    between busy / heating keepalives. nozzle_macro: Klipper macro naming the nozzle."""

    nozzle: float
    speedup: float
    queue_size: int
    advanced_ok: bool
    build_volume: tuple[float, float, float]
    keepalive: float
    nozzle_macro: str


class FirmwareModel:
    """One printer's firmware state; every method runs under the link's lock."""

    def __init__(self, profile: FirmwareProfile, wire: Wire, rng: random.Random, stats: dict,
                 settings: MachineSettings, faults: Faults, filament_diameter: float) -> None:
        self.profile = profile
        self.firmware = profile.name
        self.wire = wire
        self.rng = rng
        self.stats = stats
        self.settings = settings
        self.faults = faults
        self.filament_diameter = filament_diameter
        self.executed_numbered: list[tuple[int | None, str]] = []
        #: Line numbers of lines accepted although noise changed their command (an XOR
        #: checksum collision): a limit of the firmware protocol, reported, never hidden.
        self.undetected_corruptions: list[int] = []
        self.log = None
        self.reset(0.0)

    def reset(self, now: float) -> None:
        """Power-on state: empty queue, cold heaters, position zero."""
        self.queue: deque[tuple[int | None, str]] = deque()
        self.current: dict | None = None
        self.last_n = 0
        self.halted = False
        self.motion = Motion()
        self.heaters = Heaters(now)
        self.autoreport = 0.0
        self.next_report = 0.0
        self.numbered_done = 0
        self.paused_until = 0.0  # a runout: the firmware waits for the user until then
        self.next_paused_note = 0.0

    # ----------------------------------------------------------------- replies
    def send(self, text: str) -> None:
        self.wire.send(text)

    def ok(self, extra: str = "", *, executed: bool = True, number: int | None = None) -> None:
        faults = self.faults
        if executed and ((faults.drop_ok and self.rng.random() < faults.drop_ok)
                         or (number is not None and number in faults.drop_ok_at)):
            self.stats["oks_dropped"] += 1
            return
        if self.firmware == "klipper":
            self.send(f"ok {extra}".rstrip())
            return
        text = "ok"
        if self.settings.advanced_ok and not extra:
            queue_free = self.settings.queue_size - len(self.queue)
            text = f"ok N{self.last_n} P{self.motion.free_blocks()} B{queue_free}"
        self.send(f"{text} {extra}".rstrip())

    def temperatures(self) -> str:
        return self.heaters.report(self.firmware)

    def has_room(self) -> bool:
        """True while the command queue can take another line."""
        return len(self.queue) < self.settings.queue_size

    def tick(self, now: float) -> None:
        """Heaters, the auto-report and executing what is due."""
        self.heaters.tick(now, self.settings.speedup)
        if self.halted:
            return
        self.execute(now)
        if self.autoreport and now >= self.next_report:
            self.next_report = now + self.autoreport
            self.send(self.temperatures())

    def break_heat_wait(self) -> None:
        """M108 through the emergency parser (Marlin, Prusa, Buddy, RepRapFirmware): a
        running M109/M190/M116 stops waiting and its ``ok`` follows; otherwise nothing.
        Klipper has no such command: its waits run to the end."""
        if self.firmware == "klipper" or self.current is None or "heat" not in self.current:
            return
        self.record(None, "M108")
        self.current["heat_broken"] = True

    def halt(self, why: str) -> None:
        """M112 or a fatal error: stop, clear everything, switch the heaters off."""
        self.record(None, "M112")
        self.halted = True
        self.queue.clear()
        self.wire.clear_receive_buffer()
        self.current = None
        self.heaters.switch_off()
        if self.firmware == "klipper":
            self.send(f"!! Shutdown due to {why} command")
        else:
            self.send("Error:Printer halted. kill() called!")

    # ----------------------------------------------------------------- receiving
    def line_error(self, reason: str) -> None:
        self.stats["line_errors"] += 1
        self.send(f"Error:{reason}, Last Line: {self.last_n}")
        self.wire.clear_receive_buffer()  # Marlin drains its RX buffer after a line error
        self.send(f"Resend: {self.last_n + 1}")
        if self.profile.resend_ok:
            self.ok(executed=False)

    def receive_line(self, raw: str, changed: bool) -> None:
        """One line as received (noise included); ``changed``: noise altered its command."""
        lexed = lex(raw)
        checks = self.profile.checks
        number: int | None = None
        if raw.startswith("N") and (checks != "none" or lexed.number is not None):
            # Marlin's queue reads any line starting with N as numbered (strtol: N? is 0)
            number = lexed.number if lexed.number is not None else 0
            if checks == "marlin" and not self.numbered_line_ok(lexed, number):
                return
            if checks == "rrf" and not self.rrf_line_ok(lexed, number):
                return
            if checks != "none":
                self.last_n = self.renumbered(lexed, number)
        elif lexed.checksum is not None:
            # A checksum without a line number: noise ate the "N".
            if checks == "marlin":
                self.line_error("No Line Number with checksum")
                return
            if checks == "rrf" and not self.checksum_matches(lexed):
                self.stats["silent_drops"] += 1
                return
        command = lexed.command
        if not command:
            return
        if changed and checks != "none" and number is not None:
            self.undetected_corruptions.append(number)
        self.queue.append((number, command))

    @staticmethod
    def checksum_matches(lexed) -> bool:
        return lexed.checksum is not None and lexed.checksum == checksum(lexed.body, "latin-1")

    @staticmethod
    def renumbered(lexed, number: int) -> int:
        """M110 N<n> sets the line number; any other line keeps its own."""
        if lexed.word == "M110" and lexed.value("N") is not None:
            return int(lexed.value("N"))
        return number

    def numbered_line_ok(self, lexed, number: int) -> bool:
        """Marlin: the next line number and a matching checksum, else a resend request."""
        if lexed.word != "M110" and number != self.last_n + 1:
            self.line_error("Line Number is not Last Line Number+1")
            return False
        if lexed.checksum is None:
            self.line_error("No Checksum with line number")
            return False
        if not self.checksum_matches(lexed):
            self.line_error("checksum mismatch")
            return False
        return True

    def rrf_line_ok(self, lexed, number: int) -> bool:
        """RepRapFirmware: a bad or out-of-order line is dropped silently."""
        if not self.checksum_matches(lexed):
            self.stats["silent_drops"] += 1
            return False
        if lexed.word == "M110":
            return True
        if number <= self.last_n:
            self.ok(executed=False)  # a line it already has: acknowledged, not re-run
            return False
        if number != self.last_n + 1:
            self.stats["silent_drops"] += 1
            return False
        return True

    # ----------------------------------------------------------------- executing
    def record(self, number: int | None, command: str) -> None:
        self.executed_numbered.append((number, command))
        if self.log is not None:
            self.log.write(command + "\n")

    def execute(self, now: float) -> None:
        if self.paused_until and self.user_wait(now):
            return
        while self.queue:
            if self.current is None:
                self.current = begin(self, self.queue[0][1], now)
            if not self.progress(self.current, now):
                self.busy_keepalive(self.current, now)
                return
            number, command = self.queue.popleft()
            current = self.current
            self.current = None
            self.record(number, command)
            for line in current.get("replies", ()):
                self.send(line)
            if current.get("ok", True):
                self.ok(current.get("ok_extra", ""), number=number)
            if number is not None and command_word(command) != "M110":
                self.numbered_done += 1
                if self.fault_after_line(now) or self.event_after_line(now):
                    return

    def fault_after_line(self, now: float) -> bool:
        faults = self.faults
        if faults.reset_after is not None and self.numbered_done == faults.reset_after:
            self.stats["resets"] += 1
            if self.firmware == "klipper":
                # The MCU went away: Klipper shuts down and refuses further commands.
                self.numbered_done = -10**9
                self.halted = True
                self.queue.clear()
                self.send("!! Lost communication with MCU 'mcu'")
            else:
                self.wire.reset_wire()
                self.reset(now)
                self.numbered_done = -10**9  # one reset per printer
                for line in self.profile.banner or ("start",):
                    self.send(line)
            return True
        if faults.disconnect_after is not None and self.numbered_done == faults.disconnect_after:
            self.stats["disconnects"] += 1
            self.numbered_done = -10**9
            self.wire.hang_up()
            return True
        return False

    def event_after_line(self, now: float) -> bool:
        """The ``Faults.events`` due after this line; True when execution must stop."""
        for after, what in self.faults.events:
            if after != self.numbered_done:
                continue
            if what.startswith("//"):
                self.send(what)
            elif what == "kill":
                self.kill("Error:Printer halted. kill() called!")
                return True
            elif what == "thermal_runaway":
                self.kill("Error:Thermal Runaway, system stopped! Heater_ID: 0",
                          "Error:Printer halted. kill() called!")
                return True
            elif what.startswith("runout:"):
                self.send("//action:paused filament_runout")
                self.paused_until = now + float(what.split(":", 1)[1])
                return True
        return False

    def user_wait(self, now: float) -> bool:
        """A runout pause: busy keep-alives until the user is done. True while waiting."""
        if now < self.paused_until:
            if now >= self.next_paused_note:
                self.next_paused_note = now + self.settings.keepalive
                self.send("echo:busy: paused for user")
            return True
        self.paused_until = 0.0
        self.send("//action:resumed")
        return False

    def kill(self, *lines: str) -> None:
        """A firmware halt (kill()): heaters off, nothing more runs until a reset."""
        self.halted = True
        self.queue.clear()
        self.current = None
        self.wire.clear_receive_buffer()
        self.heaters.switch_off()
        for line in lines:
            self.send(line)

    def heating_keepalive(self, heaters: tuple[str, ...]) -> str | None:
        """The line this firmware prints about once a second while it waits for heaters:
        Marlin's report with ``W:``, Prusa MK3's ``T:205.3 E:0 W:?`` (hotend) or
        ``T:25.0 E:0 B:40.5`` (bed), Klipper's bare report; RepRapFirmware stays silent."""
        current = self.heaters.current
        if self.firmware == "rrf":
            return None
        if self.firmware == "klipper":
            return self.temperatures()
        if self.firmware == "prusa":
            if heaters == ("B",):
                return f"T:{current['T']:.1f} E:0 B:{current['B']:.1f}"
            return f"T:{current['T']:.1f} E:0 W:?"
        return self.heaters.report("marlin") + " W:?"

    def progress(self, state: dict, now: float) -> bool:
        """Advance the head command; True once it has finished."""
        motion = self.motion
        motion.retire(now)
        if "move" in state:
            if not motion.plan(state["move"], now):
                return False
            del state["move"]
            return True
        if state.get("drain") and motion.planner:
            return False
        if "busy_for" in state:
            state["until"] = now + state.pop("busy_for")
        if "heat" in state:
            if state.get("heat_broken"):
                return True
            cooling_too = state.get("cooling_too", False)
            if all(self.heaters.settled(h, cooling_too) for h in state["heat"]):
                return True
            if now >= state.get("next_keepalive", 0.0):
                state["next_keepalive"] = now + min(self.settings.keepalive, 1.0)
                line = self.heating_keepalive(state["heat"])
                if line:
                    self.send(line)
            return False
        until = state.get("until")
        return until is None or now >= until

    def busy_keepalive(self, state: dict, now: float) -> None:
        """Marlin's HOST_KEEPALIVE_FEATURE: ``echo:busy: processing`` every ``keepalive``
        seconds while the head command is blocked (homing, a dwell, M400, a full planner);
        a heat-up prints its temperature lines instead. Klipper and RRF say nothing."""
        if "heat" in state or self.firmware not in ("marlin", "prusa", "buddy"):
            return
        due = state.setdefault("next_busy", now + self.settings.keepalive)
        if now >= due:
            state["next_busy"] = now + self.settings.keepalive
            self.send("echo:busy: processing")
