"""End to end: the real daemon (``preflight run``) on a real spool folder, the
virtual printer on a real pty, the real repair and slicer in child processes."""

from __future__ import annotations

import os
import socket
import time
from pathlib import Path

import pytest
from daemon_helpers import (
    DaemonProc,
    box,
    broken_stl,
    drop,
    gcode_commands,
    tiny_gcode,
    write_3mf,
    write_config,
)

from daemon.worker import FAULT_ENV

QUERY_WORDS = ("M110", "M115", "M105", "M211", "M200", "M862.1", "M208", "M155", "M114",
               "M503", "NOZZLE_DIAMETER")


def read_log(path: Path) -> list[str]:
    return path.read_text().splitlines() if path.exists() else []


def find_once(log: list[str], seq: list[str]) -> int:
    """Index where ``seq`` occurs contiguously in ``log``; asserts it occurs exactly once."""
    n = len(seq)
    hits = [i for i in range(len(log) - n + 1) if log[i] == seq[0] and log[i:i + n] == seq]
    assert len(hits) == 1, f"sequence of {n} lines found {len(hits)} times"
    return hits[0]


def settled(job) -> bool:
    """Final state reached and the outcome archived (reports written)."""
    return str(job.state) in ("done", "failed", "cancelled", "interrupted") and bool(
        (job.outputs or {}).get("report_txt"))


def is_query(line: str) -> bool:
    return line.split()[0].upper() in QUERY_WORDS if line.split() else True


@pytest.fixture
def daemon_factory(tmp_path):
    made: list[DaemonProc] = []

    def make(cfg: Path, env: dict | None = None) -> DaemonProc:
        d = DaemonProc(cfg, env)
        made.append(d)
        return d

    yield make
    for d in made:
        d.stop()


@pytest.mark.slow
def test_three_files_two_prints_one_failure(tmp_path, daemon_factory):
    vlog = tmp_path / "printer.log"
    d = daemon_factory(write_config(tmp_path, virtual_log=vlog)).start()
    spool = d.cfg.spool.path
    v, f = box((6, 5, 4))
    broken = broken_stl(tmp_path / "broken.stl")
    drop(spool, "broken.stl", broken.read_bytes())
    d.wait_for(lambda: d.jobs(), what="first job")
    write_3mf(tmp_path / "good.3mf", v, f)
    drop(spool, "good.3mf", (tmp_path / "good.3mf").read_bytes())
    drop(spool, "garbage.stl", os.urandom(3000))
    d.wait_for(lambda: len(d.jobs()) == 3 and all(settled(j) for j in d.jobs()),
               what="three outcomes")
    st = d.states()
    assert st == {"broken.stl": "done", "good.3mf": "done", "garbage.stl": "failed"}, st
    jobs = {j.source_name: j for j in d.jobs()}

    # the garbage file: in failed/ with a clear one-line reason
    bad = jobs["garbage.stl"]
    assert bad.reason.startswith("repair failed: ") and "\n" not in bad.reason
    assert (d.cfg.failed_dir / "garbage.stl").read_bytes()
    txt = (d.cfg.failed_dir / "garbage.report.txt").read_text()
    assert "FAILED" in txt and bad.reason in txt

    # the broken model: repaired with the printer's nozzle as epsilon, reports in done/
    b = jobs["broken.stl"]
    assert b.epsilon == pytest.approx(0.4) and "nozzle" in b.epsilon_source
    assert b.repair_report["printable"]["ok"] is True
    assert b.repair_report["before"]["triangles"] == 22
    assert (d.cfg.done_dir / "broken.stl").exists()
    rep = (d.cfg.done_dir / "broken.report.txt").read_text()
    assert "PRINTED" in rep and "Repair:" in rep and "Slicing:" in rep and "Epsilon: 0.4" in rep

    # every streamed line reached the printer exactly once, in order
    log = read_log(vlog)
    spans = []
    for name in ("broken.stl", "good.3mf"):
        g = Path(jobs[name].outputs["gcode"])
        cmds = gcode_commands(g)
        assert len(cmds) > 50
        i = find_once(log, cmds)
        spans.append((i, i + len(cmds)))
        assert jobs[name].print_result["acked_lines"] == len(cmds)
    assert spans[0][1] <= spans[1][0]  # printed in drop order, one after the other
    rest = log[:spans[0][0]] + log[spans[0][1]:spans[1][0]] + log[spans[1][1]:]
    assert all(is_query(x) for x in rest), [x for x in rest if not is_query(x)][:5]
    # nothing left behind in the spool or the work area
    assert sorted(p.name for p in spool.iterdir()) == [".preflight", "done", "failed"]
    assert list(d.cfg.work_dir.iterdir()) == []
    assert d.stop() == 0


@pytest.mark.slow
def test_slow_writer_is_taken_only_when_complete(tmp_path, daemon_factory):
    d = daemon_factory(write_config(tmp_path, auto_print=False)).start()
    data = tiny_gcode(moves=400).encode()
    chunks = [data[i:i + len(data) // 5 + 1] for i in range(0, len(data), len(data) // 5 + 1)]
    path = d.cfg.spool.path / "slow.gcode"
    with open(path, "wb") as fh:
        for c in chunks:
            fh.write(c)
            fh.flush()
            os.fsync(fh.fileno())
            time.sleep(1.5)             # longer than settle_seconds: a mtime-only rule fails
            assert d.jobs() == []
    job = d.wait_for(lambda: d.jobs() and d.jobs()[0], what="the job")
    d.wait_for(lambda: str(d.journal.get(job.id).state) == "ready", what="ready")
    job = d.journal.get(job.id)
    assert Path(job.input_path).read_bytes() == data


@pytest.mark.slow
def test_hundred_files_at_once_are_all_accounted_for(tmp_path, daemon_factory):
    d = daemon_factory(write_config(tmp_path, auto_print=False))
    spool = d.cfg.spool.path
    staging = tmp_path / "staging"
    staging.mkdir()
    (spool / "early.gcode").write_text(tiny_gcode(moves=5))  # waiting before the start
    names = ["early.gcode"]
    mesh = broken_stl(tmp_path / "m.stl").read_bytes()
    for i in range(99):
        if i % 10 == 9:
            name = f"note{i:03d}.txt"
        elif i % 10 == 4:
            name = f"reset{i:03d}.gcode"
        elif i % 25 == 0:
            name = f"mesh{i:03d}.stl"
        else:
            name = f"part{i:03d}.gcode"
        if name.endswith(".stl"):
            (staging / name).write_bytes(mesh)
        else:
            extra = ["M502"] if name.startswith("reset") else []
            (staging / name).write_text(tiny_gcode(extra, moves=5))
        names.append(name)
    d.start()
    for name in names[1:]:  # a burst: 99 renames into the watched spool
        os.rename(staging / name, spool / name)
    d.wait_for(lambda: len(d.jobs()) == 100 and all(
        str(j.state) == "ready" or settled(j) for j in d.jobs()), what="100 outcomes")
    st = d.states()
    assert sorted(st) == sorted(names)
    for name, s in st.items():
        good = name.startswith(("part", "mesh", "early"))
        assert s == ("ready" if good else "failed"), (name, s)
        if s == "failed":
            assert (d.cfg.failed_dir / name).exists()
    reasons = {j.source_name: j.reason for j in d.jobs()}
    assert "firmware-altering" in reasons["reset004.gcode"]
    assert "not a model or G-code file" in reasons["note009.txt"]
    assert sorted(p.name for p in spool.iterdir()) == [".preflight", "done", "failed"]


@pytest.mark.slow
def test_kill9_during_repair_then_during_print(tmp_path, daemon_factory):
    vlog = tmp_path / "printer.log"
    cfg = write_config(tmp_path, virtual_log=vlog, speedup=30)
    # 1. kill -9 while a repair runs (the worker hangs in this first life only)
    d1 = daemon_factory(cfg, {FAULT_ENV: "repair:hang:model"}).start()
    broken = broken_stl(tmp_path / "b.stl")
    drop(d1.cfg.spool.path, "model.stl", broken.read_bytes())
    d1.wait_for(lambda: d1.jobs() and str(d1.jobs()[0].state) == "repairing", what="repairing")
    d1.kill9()
    assert str(d1.jobs()[0].state) == "repairing"
    # 2. restart: the repair is redone; a long G-code starts printing; kill -9 again
    d2 = daemon_factory(cfg).start()
    d2.wait_for(lambda: str(d2.journal.get(1).state) == "done", what="the redone job printed")
    hist = [h["to_state"] for h in d2.journal.history(1)]
    assert hist[:3] == ["queued", "repairing", "queued"] and hist.count("repairing") == 2
    long_g = tiny_gcode(moves=3000)
    drop(d2.cfg.spool.path, "long.gcode", long_g.encode())
    d2.wait_for(lambda: (j := d2.journal.get(2)) and str(j.state) == "printing"
                and (j.progress or 0) > 0.05, what="printing")
    d2.kill9()
    sent_before = read_log(vlog)
    # 3. restart: the print is interrupted, explained, and not re-sent
    d3 = daemon_factory(cfg).start()
    job = d3.wait_for(lambda: (j := d3.journal.get(2)) and str(j.state) == "interrupted"
                      and settled(j) and j, what="interrupted")
    assert "half-printed part" in job.reason and "requeue 2" in job.reason
    d3.wait_for(lambda: (d3.status().get("printer") or {}).get("state") == "connected",
                what="printer connected")
    time.sleep(1.0)
    cmds = gcode_commands(d3.cfg.spool.path / ".preflight" / "work" /
                          Path(job.work_dir).name / "long.gcode")
    after = read_log(vlog)[len(sent_before):]
    assert all(is_query(x) for x in after), "an interrupted print was re-sent by itself"
    printed = [x for x in sent_before if not is_query(x)]
    assert 0 < sum(1 for x in printed if x in cmds) < len(cmds)
    assert (d3.cfg.failed_dir / "long.report.txt").exists()
    # no job lost: both files are accounted for
    assert d3.states() == {"model.stl": "done", "long.gcode": "interrupted"}
    # 4. an explicit requeue re-sends it, whole, once
    out = d3.cli("jobs", "requeue", "2")
    assert out.returncode == 0, out.stderr
    d3.wait_for(lambda: settled(d3.journal.get(2)) and str(d3.journal.get(2).state) == "done",
                what="requeued print done")
    find_once(read_log(vlog)[len(sent_before):], cmds)
    assert not (d3.cfg.failed_dir / "long.report.txt").exists()
    assert (d3.cfg.done_dir / "long.report.txt").exists()


@pytest.mark.slow
def test_crashing_hanging_and_greedy_children_fail_only_their_job(tmp_path, daemon_factory):
    faults = "repair:abort:crashme,slice:hang:hangme,repair:oom:oomme"
    cfg = write_config(tmp_path, limits={"slice_timeout": 2, "repair_memory_mb": 600})
    d = daemon_factory(cfg, {FAULT_ENV: faults}).start()
    b = broken_stl(tmp_path / "b.stl").read_bytes()
    for name in ("crashme.stl", "hangme.stl", "oomme.stl", "fine.stl"):
        drop(d.cfg.spool.path, name, b)
    d.wait_for(lambda: len(d.jobs()) == 4 and all(settled(j) for j in d.jobs()),
               what="outcomes")
    jobs = {j.source_name: j for j in d.jobs()}
    assert str(jobs["fine.stl"].state) == "done"
    assert "repair failed: repair crashed with SIGABRT" in jobs["crashme.stl"].reason
    assert "slicing failed: slice took longer than the limit of 2 s" in jobs["hangme.stl"].reason
    assert "repair ran out of memory" in jobs["oomme.stl"].reason
    assert {str(j.state) for n, j in jobs.items() if n != "fine.stl"} == {"failed"}
    assert d.alive()


@pytest.mark.slow
def test_refused_entries(tmp_path, daemon_factory):
    d = daemon_factory(write_config(tmp_path)).start()
    spool = d.cfg.spool.path
    secret = tmp_path / "secret.gcode"
    secret.write_text(tiny_gcode())
    os.symlink(secret, spool / "link.gcode")
    drop(spool, "..\\..\\evil.gcode", tiny_gcode().encode())
    drop(spool, "reset.gcode", tiny_gcode(["M502"]).encode())
    d.wait_for(lambda: (d.status().get("printer") or {}).get("state") == "connected",
               what="printer info")
    drop(spool, "huge.gcode", tiny_gcode(["G1 X400 Y10 E1"]).encode())
    d.wait_for(lambda: len(d.jobs()) == 4 and all(settled(j) for j in d.jobs()),
               what="four refusals")
    reasons = {j.source_name: j.reason for j in d.jobs()}
    assert "symbolic link" in reasons["link.gcode"]
    assert "leave the spool" in reasons["..\\..\\evil.gcode"]
    assert "M502" in reasons["reset.gcode"] and "firmware-altering" in reasons["reset.gcode"]
    assert "outside the printer's build volume 250 x 210 x 220 mm" in reasons["huge.gcode"]
    assert secret.read_text() == tiny_gcode()  # the link's target is untouched
    assert (d.cfg.failed_dir / "link.gcode").is_symlink()
    names = sorted(p.name for p in d.cfg.failed_dir.iterdir())
    assert all("/" not in n and "\\" not in n and not n.startswith(".") for n in names)
    assert (d.cfg.failed_dir / "reset.report.txt").read_text().count("M502") >= 1


@pytest.mark.slow
def test_cli_print_cancel_status_and_notify(tmp_path, daemon_factory):
    sock_path = str(tmp_path / "notify.sock")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(sock_path)
    sock.settimeout(60)
    d = daemon_factory(write_config(tmp_path, auto_print=False, speedup=20),
                       {"NOTIFY_SOCKET": sock_path, "WATCHDOG_USEC": "1000000"}).start()
    assert b"READY=1" in sock.recv(4096)
    got = b""
    while b"WATCHDOG=1" not in got:  # the main loop pings the watchdog
        got = sock.recv(4096)
    drop(d.cfg.spool.path, "a.gcode", tiny_gcode(moves=10).encode())
    drop(d.cfg.spool.path, "b.gcode", tiny_gcode(moves=5000).encode())
    d.wait_for(lambda: len(d.jobs()) == 2 and all(str(j.state) == "ready" for j in d.jobs()),
               what="ready jobs")
    out = d.cli("jobs", "list")
    assert out.returncode == 0 and "a.gcode" in out.stdout and "ready" in out.stdout
    out = d.cli("jobs", "print", "1")
    assert out.returncode == 0, out.stderr
    d.wait_for(lambda: str(d.journal.get(1).state) == "done", what="print 1")
    out = d.cli("jobs", "print", "2")
    assert out.returncode == 0, out.stderr
    d.wait_for(lambda: str(d.journal.get(2).state) == "printing", what="print 2 starts")
    out = d.wait_for(lambda: (o := d.cli("status")).returncode == 0
                     and "printing job 2" in o.stdout and o, what="status shows the print")
    assert "printer: virtual" in out.stdout
    out = d.cli("jobs", "cancel", "2")
    assert out.returncode == 0, out.stderr
    job = d.wait_for(lambda: (j := d.journal.get(2)) and str(j.state) == "cancelled"
                     and settled(j) and j, what="cancelled")
    assert 0 < job.print_result["acked_lines"] < job.print_result["total_lines"]
    out = d.cli("jobs", "show", "2")
    assert "CANCELLED" in out.stdout
    out = d.cli("jobs", "print", "99")
    assert out.returncode != 0 and out.stderr.startswith("preflight: ")
    assert d.stop() == 0
    out = d.cli("status")
    assert out.returncode == 3 and "not running" in out.stdout


@pytest.mark.slow
def test_unplug_mid_print_interrupts_and_reconnects(tmp_path, daemon_factory):
    from printer.virtual import Faults, VirtualPrinter

    link = tmp_path / "ttyVIRTUAL"
    vp = VirtualPrinter(speedup=200, baud=250000, link=link,
                        faults=Faults(disconnect_after=400, reconnect_after=2.0))
    vp.start()
    try:
        d = daemon_factory(write_config(tmp_path, port=str(link))).start()
        d.wait_for(lambda: (d.status().get("printer") or {}).get("state") == "connected",
                   what="connected")
        drop(d.cfg.spool.path, "long.gcode", tiny_gcode(moves=3000).encode())
        job = d.wait_for(lambda: (j := d.journal.get(1)) and str(j.state) == "interrupted"
                         and settled(j) and j, what="interrupted")
        assert "half-printed part" in job.reason
        assert 0 < job.print_result["acked_lines"] < job.print_result["total_lines"]
        # the daemon lives on and reconnects to the re-plugged printer
        d.wait_for(lambda: (d.status().get("printer") or {}).get("connections", 0) >= 2,
                   what="reconnected")
        assert d.alive()
        executed = len([x for x in vp.executed if not is_query(x)])
        time.sleep(1.0)
        assert len([x for x in vp.executed if not is_query(x)]) == executed  # not re-sent
        # and it still prints: a new file goes through on the new connection
        drop(d.cfg.spool.path, "next.gcode", tiny_gcode(moves=10).encode())
        d.wait_for(lambda: (j := d.journal.get(2)) and str(j.state) == "done", what="next print")
    finally:
        vp.stop()


@pytest.mark.slow
def test_demo_runs_and_exits_0(tmp_path):
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", "daemon", "demo"], capture_output=True,
                         text=True, timeout=900, cwd=tmp_path)
    assert out.returncode == 0, out.stdout + out.stderr
    text = out.stdout
    for needle in ("repaired - ", "intersecting pairs resolved", "sliced - ", "streaming",
                   "Result: PRINTED", "demo finished"):
        assert needle in text, (needle, text)


@pytest.mark.slow
def test_sigterm_mid_print_is_graceful(tmp_path, daemon_factory):
    vlog = tmp_path / "printer.log"
    d = daemon_factory(write_config(tmp_path, virtual_log=vlog, speedup=20)).start()
    drop(d.cfg.spool.path, "long.gcode", tiny_gcode(moves=3000).encode())
    d.wait_for(lambda: (j := d.journal.get(1)) and str(j.state) == "printing"
               and (j.progress or 0) > 0.02, what="printing")
    assert d.stop() == 0
    job = d.journal.get(1)
    assert str(job.state) == "interrupted" and "daemon was stopped" in job.reason
    tail = read_log(vlog)[-6:]
    assert "M104 S0" in tail and "M84" in tail  # cooldown and motors off were sent


@pytest.mark.slow
def test_jobs_wait_for_a_printer_plugged_in_later(tmp_path, daemon_factory):
    from printer.virtual import VirtualPrinter

    link = tmp_path / "ttyLATER"
    d = daemon_factory(write_config(tmp_path, port=str(link))).start()
    drop(d.cfg.spool.path, "box.stl", broken_stl(tmp_path / "b.stl").read_bytes())
    d.wait_for(lambda: (d.status().get("printer") or {}).get("state") == "waiting",
               what="waiting for the printer")
    time.sleep(1.5)
    assert str(d.journal.get(1).state) == "queued"  # no printer, no epsilon: it waits
    assert "no serial port" in (d.status().get("printer") or {}).get("message", "")
    vp = VirtualPrinter(speedup=2000, baud=250000, nozzle=0.6, firmware="prusa", link=link)
    vp.start()
    try:
        job = d.wait_for(lambda: settled(j := d.journal.get(1)) and j, what="printed")
        assert str(job.state) == "done"
        assert job.epsilon == pytest.approx(0.6) and "M862.1" in job.epsilon_source
    finally:
        vp.stop()
