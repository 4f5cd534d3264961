"""Several printers per daemon: a real daemon driving two virtual printers (nozzles 0.4
and 0.6, different build volumes) over real ptys; routing, pinning, exactly-once
printing, parallel prints; and the ``[[printers]]`` config."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pytest
import tomli_w
from daemon_helpers import FAST_PROFILE, DaemonProc, box, drop, gcode_commands, write_binary_stl
from web_helpers import request

from daemon.config import ConfigError, parse_config
from daemon.journal import Journal
from daemon.web.auth import read_key

BIG, SMALL = "big04", "small06"
SMALL_VOLUME = [80.0, 80.0, 80.0]


def printers_config(tmp: Path, **daemon) -> Path:
    def printer(name: str, nozzle: float, volume: list[float]) -> dict:
        return {"name": name, "port": "virtual", "baud": 250000, "virtual_speedup": 2000.0,
                "nozzle_diameter": nozzle, "virtual_build_volume": volume,
                "virtual_log": str(tmp / f"{name}.gcode"),
                "reconnect_min_seconds": 0.2, "reconnect_max_seconds": 1.0}

    config = {
        "spool": {"path": str(tmp / "spool"), "settle_seconds": 1.0, "close_grace_seconds": 0.2},
        "printers": [printer(BIG, 0.4, [250.0, 210.0, 220.0]),
                     printer(SMALL, 0.6, SMALL_VOLUME)],
        "daemon": {"state_dir": str(tmp / "state"), "log_level": "DEBUG", **daemon},
        "limits": {"repair_timeout": 120, "slice_timeout": 120},
        "web": {"listen": "127.0.0.1:0"},
        "profile": FAST_PROFILE,
    }
    path = tmp / "preflight.toml"
    path.write_text(tomli_w.dumps(config))
    return path


def stl_bytes(tmp: Path, size: tuple[float, float, float]) -> bytes:
    path = tmp / "model.stl"
    write_binary_stl(path, *box(size))
    return path.read_bytes()


def settled(job) -> bool:
    return str(job.state) in ("done", "failed", "cancelled", "interrupted") and bool(
        (job.outputs or {}).get("report_txt"))


def print_span(d: DaemonProc, job_id: int) -> tuple[float, float]:
    """When the job started printing and when it ended, from the journal's history."""
    history = d.journal.history(job_id)
    start = next(h["at"] for h in history if h["to_state"] == "printing")
    end = next(h["at"] for h in history if h["from_state"] == "printing")
    return start, end


def occurrences(log: list[str], seq: list[str]) -> int:
    n = len(seq)
    return sum(1 for i in range(len(log) - n + 1) if log[i] == seq[0] and log[i:i + n] == seq)


@pytest.fixture
def daemon(tmp_path):
    made: list[DaemonProc] = []

    def make(cfg: Path) -> DaemonProc:
        d = DaemonProc(cfg)
        made.append(d)
        return d

    yield make
    for d in made:
        d.stop()


def test_two_printers_route_pin_and_print_each_job_once_in_parallel(tmp_path, daemon):
    d = daemon(printers_config(tmp_path, auto_print=False, workers=2))
    spool = d.cfg.spool.path
    (spool / "nozzle-0.6").mkdir()
    d.start()
    d.wait_for(lambda: all(p.get("state") == "connected"
                           for p in d.status().get("printers", [])), what="both printers")

    def jobs() -> dict:
        return {j.source_name: j for j in d.jobs()}

    # distinct sizes, so that every job's G-code is its own. Unpinned ones first (pinned
    # jobs count as queued work for the 0.6 class from the moment they are taken)
    free = [f"free{i}.stl" for i in range(4)]
    for i, name in enumerate(free):
        drop(spool, name, stl_bytes(tmp_path, (6 + i, 5, 3)))
    d.wait_for(lambda: len(jobs()) == 4 and all(j.nozzle for j in jobs().values()),
               what="unpinned jobs routed")
    by_sidecar = ["side0.stl", "side1.stl"]
    for i, name in enumerate(by_sidecar):
        drop(spool, Path(name).stem + ".toml", b"nozzle = 0.6\n")
        drop(spool, name, stl_bytes(tmp_path, (5, 6 + i, 3)))
    by_folder = ["fold0.stl", "fold1.stl"]
    for i, name in enumerate(by_folder):
        drop(spool / "nozzle-0.6", name, stl_bytes(tmp_path, (5, 5, 3.5 + i)))
    drop(spool, "long.stl", stl_bytes(tmp_path, (120, 20, 3)))     # fits only big04
    drop(spool, "longpin.toml", b"nozzle = 0.6\n")
    drop(spool, "longpin.stl", stl_bytes(tmp_path, (121, 20, 3)))  # pinned: fits no 0.6
    drop(spool, "badpin.stl.toml", b"nozzle = 'wide'\n")
    drop(spool, "badpin.stl", stl_bytes(tmp_path, (5, 5, 5)))
    printable = free + by_sidecar + by_folder + ["long.stl"]
    names = printable + ["longpin.stl", "badpin.stl"]

    d.wait_for(lambda: set(jobs()) == set(names) and all(
        str(j.state) in ("ready", "failed") for j in jobs().values()), what="all processed")
    assert not any(j.source_name.endswith(".toml") for j in d.jobs())  # sidecars: no jobs
    requests = Journal(d.cfg.journal_path)  # as `preflight jobs print ID` asks, all at once
    for job in jobs().values():
        if job.source_name in printable:
            requests.add_request(job.id, "print")
    requests.close()
    d.wait_for(lambda: all(settled(j) for j in jobs().values()), what="all printed")

    done = jobs()
    assert {n: str(j.state) for n, j in done.items()} == {
        **{n: "done" for n in printable}, "longpin.stl": "failed", "badpin.stl": "failed"}
    # a model too long for the 80 mm printer went to the other one
    assert done["long.stl"].printer == BIG
    reason = done["longpin.stl"].reason
    assert "121.0 x 20.0 x 3.0 mm" in reason and "0.6 mm nozzle" in reason and "80 x 80" in reason
    assert "badpin.stl.toml" in done["badpin.stl"].reason and "nozzle" in done["badpin.stl"].reason
    assert (d.cfg.failed_dir / "badpin.stl.toml").exists()
    # pinned jobs: only on the 0.6 printer, repaired with epsilon = 0.6
    for name in by_sidecar + by_folder:
        job = done[name]
        assert job.printer == SMALL and job.pinned and job.epsilon == pytest.approx(0.6)
        report = json.loads(Path(job.outputs["report_json"]).read_text())
        assert report["epsilon"] == pytest.approx(0.6) and report["printer"] == SMALL
        assert "Epsilon: 0.6 mm" in Path(job.outputs["report_txt"]).read_text()
    assert (d.cfg.done_dir / "side0.toml").exists()  # the sidecar went along
    # unpinned jobs: processed for the class of the printer that printed them
    for name in free + ["long.stl"]:
        job = done[name]
        assert job.epsilon == pytest.approx(0.4 if job.printer == BIG else 0.6)
    assert {done[n].printer for n in free} == {BIG, SMALL}  # both printers got free work

    # every printed file executed exactly once, on its own printer, and nowhere else
    logs = {name: (tmp_path / f"{name}.gcode").read_text().splitlines() for name in (BIG, SMALL)}
    for name in printable:
        job = done[name]
        commands = gcode_commands(Path(job.outputs["gcode"]))
        assert occurrences(logs[job.printer], commands) == 1, name
        other = SMALL if job.printer == BIG else BIG
        assert occurrences(logs[other], commands) == 0, name

    # the two printers printed at the same time
    spans = {p: [print_span(d, j.id) for j in done.values() if j.printer == p]
             for p in (BIG, SMALL)}
    assert any(a0 < b1 and b0 < a1 for a0, a1 in spans[BIG] for b0, b1 in spans[SMALL])

    # `preflight status` lists both printers (once the heartbeat shows them idle)
    d.wait_for(lambda: all(p.get("state") == "connected" and not p.get("job")
                           for p in d.status()["printers"]), what="both printers idle")
    out = d.cli("status").stdout
    for name, nozzle, volume in ((BIG, "0.4", "250 x 210 x 220"), (SMALL, "0.6", "80 x 80 x 80")):
        line = next(x for x in out.splitlines() if x.startswith(f"printer {name}"))
        assert f"nozzle {nozzle} mm" in line and volume in line and "Marlin" in line
        assert "virtual" in line and "connected" in line

    listing = d.cli("jobs", "list").stdout
    assert "fold0.stl on small06 (pinned to a 0.6 mm nozzle)" in listing
    assert "long.stl on big04" in listing

    # the web API's state lists both; its single-printer fields describe the first
    port = d.status()["web"]["port"]
    key = read_key(d.cfg.daemon.state_dir)
    state = request(port, "GET", "/api/preflight/state", headers={"X-Api-Key": key}).json()
    assert [(p["name"], p["nozzle"], p["build_volume"]) for p in state["printers"]] == [
        (BIG, 0.4, [250.0, 210.0, 220.0]), (SMALL, 0.6, SMALL_VOLUME)]
    assert state["printer"]["name"] == BIG
    rows = {row["source_name"]: row for row in state["history"]}
    assert rows["fold0.stl"]["printer"] == SMALL and rows["fold0.stl"]["pinned"] is True
    assert d.stop() == 0


def test_printers_tables_are_checked():
    one = {"name": "a", "port": "virtual"}
    cfg = parse_config({"printers": [one, {"name": "b", "port": "auto",
                                           "nozzle_diameter": 0.6}]})
    assert [p.name for p in cfg.all_printers] == ["a", "b"]
    assert cfg.printer.name == "a" and cfg.all_printers[1].nozzle_diameter == 0.6
    single = parse_config({"printer": {"port": "virtual"}})
    assert [p.name for p in single.all_printers] == ["printer"]
    cases = [
        ({"printer": {"port": "auto"}, "printers": [one]}, "[printer] and [[printers]]"),
        ({"printers": [one, {"name": "a"}]}, "the name 'a' is used by another printer"),
        ({"printers": [{"port": "auto"}]}, "[[printers]] table 1: name is required"),
        ({"printers": [{"name": "a", "baud": "fast"}]}, "[printers a] baud: expected a number"),
        ({"printers": [{"name": "a", "colour": 1}]}, "[printers a] colour: unknown key"),
        ({"printers": []}, "expected one or more [[printers]] tables"),
        ({"printers": [{"name": "a", "port": "/dev/ttyACM0"}, {"name": "b", "port":
                                                                "/dev/ttyACM0"}]},
         "port '/dev/ttyACM0' is given to another printer too"),
        ({"printers": [{"name": "a", "virtual_build_volume": [1, 2]}]},
         "virtual_build_volume: expected three sizes"),
    ]
    for data, message in cases:
        with pytest.raises(ConfigError) as err:
            parse_config(data)
        assert message in str(err.value) and "\n" not in str(err.value)


def test_an_older_journal_gains_the_printer_columns(tmp_path):
    import sqlite3

    from daemon.journal import MIGRATIONS, SCHEMA

    path = tmp_path / "journal.sqlite"
    db = sqlite3.connect(path)
    db.executescript(SCHEMA)  # then back to the journal of a preflight before [[printers]]
    for column, _ in MIGRATIONS:
        db.execute(f"ALTER TABLE jobs DROP COLUMN {column}")
    db.execute("INSERT INTO jobs (name, source_name, kind, state, created, updated) "
               "VALUES ('a.stl', 'a.stl', 'mesh', 'ready', 1, 1)")
    db.commit()
    assert "printer" not in {r[1] for r in db.execute("PRAGMA table_info(jobs)")}
    db.close()
    journal = Journal(path)
    job = journal.get(1)
    assert (job.nozzle, job.pinned, job.printer) == (None, False, None)
    assert journal.claim_for_printer(1, "left") is True
    assert journal.claim_for_printer(1, "right") is False  # exactly one printer gets it
    assert journal.get(1).printer == "left"
    assert journal.release_unstarted_claims() == 1  # the daemon died before it started
    assert journal.claim_for_printer(1, "right") is True
    journal.close()


def test_two_auto_printers_never_take_the_same_port(tmp_path, daemon):
    from test_daemon_discovery import plug_in

    by_id = tmp_path / "by-id"
    by_id.mkdir()
    links = [by_id / "usb-Virtual_A-if00", by_id / "usb-Virtual_B-if00"]
    procs = [plug_in(link, tmp_path / f"{link.name}.log", 250000) for link in links]
    try:
        auto = {"port": "auto", "scan": [str(by_id / "*")], "probe_seconds": 2.0,
                "reconnect_min_seconds": 0.2, "reconnect_max_seconds": 1.0}
        config = {"spool": {"path": str(tmp_path / "spool")},
                  "printers": [{"name": "a", **auto}, {"name": "b", **auto}],
                  "daemon": {"state_dir": str(tmp_path / "state")}, "web": {"listen": ""}}
        (tmp_path / "preflight.toml").write_text(tomli_w.dumps(config))
        d = daemon(tmp_path / "preflight.toml").start()
        printers = d.wait_for(lambda: (ps := d.status().get("printers")) and all(
            p.get("state") == "connected" for p in ps) and ps, what="both printers found")
        assert sorted(p["port"] for p in printers) == sorted(map(str, links))
        lines = [line for p in printers for line in p.get("discovery") or []]
        assert any("used by printer" in line and "of this daemon" in line for line in lines)
        # each remembers its own choice
        for p in printers:
            remembered = d.cfg.daemon.state_dir / "printers" / p["name"] / "printer_port.json"
            assert json.loads(remembered.read_text())["port"] == p["port"]
        assert d.stop() == 0
    finally:
        for proc in procs:
            proc.terminate()
            proc.wait()


def test_routing_by_size_pin_and_queued_work(tmp_path):
    """The pool's choices from what each printer reported at its last connection (the
    journal remembers it), before any printer is connected again."""
    import threading

    from daemon.pipeline import Spool
    from daemon.printers import NoPrinterFits, PrinterPool

    cfg = parse_config({"spool": {"path": str(tmp_path / "spool")},
                        "daemon": {"state_dir": str(tmp_path / "state")},
                        "printers": [{"name": "a", "port": "virtual"},
                                     {"name": "b", "port": "virtual"},
                                     {"name": "c", "port": "virtual", "nozzle_diameter": 0.8}]})
    journal = Journal(cfg.journal_path)
    pool = PrinterPool(cfg, journal, Spool(cfg, journal), threading.Event())
    journal.set_meta("printer_info:a", {"nozzle_diameter": 0.4, "build_volume": [200, 200, 200]})
    journal.set_meta("printer_info:b", {"nozzle_diameter": 0.6, "build_volume": [100, 100, 100]})
    classes = pool.classes()
    assert [(c.nozzle, c.build_volume, c.printers, c.known) for c in classes] == [
        (0.4, (200, 200, 200), ("a",), True), (0.6, (100, 100, 100), ("b",), True),
        (0.8, None, ("c",), False)]  # c never connected: its config's nozzle, any size

    def add(name: str, nozzle: float | None = None):
        job_id = journal.add_job(name=name, source_name=name, kind="mesh", work_dir="",
                                 input_path="", nozzle=nozzle)
        return journal.get(job_id)

    # no printer is idle (none connected): the least queued work per printer
    first = add("1.stl")
    assert pool.route(first, (10, 10, 10))["nozzle_diameter"] == 0.4
    assert journal.get(first.id).nozzle == 0.4  # recorded: it counts as a's queued work
    assert pool.route(add("2.stl"), (10, 10, 10))["nozzle_diameter"] == 0.6
    assert pool.route(add("3.stl"), (150, 10, 10))["nozzle_diameter"] == 0.4  # too big for b
    # unknown classes are used only when no known one fits: c's bed is not known
    assert pool.route(add("4.stl"), (300, 10, 10))["nozzle_source"] == "config"
    assert pool.route(add("5.stl", nozzle=0.6), (10, 10, 10))["nozzle_diameter"] == 0.6
    with pytest.raises(NoPrinterFits, match=r"150.0 x 10.0 x 10.0 mm; it fits no printer "
                                            r"with a 0.6 mm nozzle \(b: 0.6 mm nozzle, 100 x"):
        pool.route(add("6.stl", nozzle=0.6), (150, 10, 10))
    with pytest.raises(NoPrinterFits, match="pinned to a 1 mm nozzle, but no printer has one"):
        pool.route(add("7.stl", nozzle=1.0), (10, 10, 10))
    # a ready job sliced for b's class: only b may print it; G-code unpinned: anyone
    sliced = journal.get(add("8.stl", nozzle=0.6).id)
    journal.update(sliced.id, printer_info={"nozzle_diameter": 0.6,
                                            "build_volume": [100, 100, 100]})
    sliced = journal.get(sliced.id)
    assert [pool.may_print(link, sliced) for link in pool.links] == [False, True, False]
    journal.close()


def test_pause_resume_and_cancel_reach_the_printer_that_prints(tmp_path, daemon):
    """Requests go to whichever printer holds the job: here the second one, which a
    pinned G-code file goes to while the first printer takes an unpinned one."""
    from daemon_helpers import tiny_gcode

    cfg_path = printers_config(tmp_path)
    config = tomllib.loads(cfg_path.read_text())
    config["printers"][1]["virtual_speedup"] = 10.0  # slow enough to pause and cancel
    cfg_path.write_text(tomli_w.dumps(config))
    d = daemon(cfg_path)
    (d.cfg.spool.path / "nozzle-0.6").mkdir()
    d.start()
    d.wait_for(lambda: all(p.get("state") == "connected"
                           for p in d.status().get("printers", [])), what="both printers")
    drop(d.cfg.spool.path / "nozzle-0.6", "long.gcode", tiny_gcode(moves=800).encode())
    job = d.wait_for(lambda: next((j for j in d.jobs() if j.state == "printing"), None),
                     what="printing")
    assert job.printer == SMALL
    assert d.cli("jobs", "pause", str(job.id)).returncode == 0
    d.wait_for(lambda: str(d.journal.get(job.id).state) == "paused", what="paused")
    drop(d.cfg.spool.path, "other.gcode", tiny_gcode(moves=30).encode())  # the first prints
    other = d.wait_for(lambda: next((j for j in d.jobs() if j.source_name == "other.gcode"
                                     and settled(j)), None), what="other printed")
    assert (str(other.state), other.printer) == ("done", BIG)
    assert d.cli("jobs", "resume", str(job.id)).returncode == 0
    d.wait_for(lambda: str(d.journal.get(job.id).state) == "printing", what="resumed")
    assert d.cli("jobs", "cancel", str(job.id)).returncode == 0
    d.wait_for(lambda: settled(d.journal.get(job.id)), what="cancelled")
    assert str(d.journal.get(job.id).state) == "cancelled"
    executed = (tmp_path / f"{SMALL}.gcode").read_text().splitlines()
    assert "M84" in executed[-10:]  # the cancel's cool-down and motors off, on that printer
    assert d.stop() == 0
