"""Start-up recovery and requests, on a real journal and real files (no printer needed)."""

import threading
from pathlib import Path

import pytest

from daemon.config import parse_config
from daemon.pipeline import Processor, Spool
from daemon.printlink import PrinterLink
from daemon.service import AlreadyRunning, Daemon
from daemon.states import JobState

S = JobState


def make_cfg(tmp_path: Path, **daemon):
    return parse_config({"spool": {"path": str(tmp_path / "spool")},
                         "daemon": {"state_dir": str(tmp_path / "state"), **daemon},
                         "printer": {"port": "/dev/nonexistent"}})


def take(spool: Spool, name: str, data: bytes = b"G28\nG1 X1\n") -> int:
    p = spool.root / name
    p.write_bytes(data)
    return spool.intake(p)


def test_recover_redoes_processing_and_interrupts_prints(tmp_path):
    cfg = make_cfg(tmp_path)
    d = Daemon(cfg)
    j, sp = d.journal, d.spool
    a = take(sp, "a.stl", b"solid a\nendsolid a\n")
    b = take(sp, "b.gcode")
    j.transition(a, S.REPAIRING)
    j.transition(b, S.READY)
    j.transition(b, S.PRINTING, progress=0.4)
    d.recover()
    ja, jb = j.get(a), j.get(b)
    assert ja.state == S.QUEUED and "redoing" in j.history(a)[-1]["note"]
    assert jb.state == S.INTERRUPTED
    assert "half-printed part" in jb.reason and "40%" in jb.reason
    assert Path(jb.input_path).exists()  # kept for a requeue
    assert "INTERRUPTED" in (cfg.failed_dir / "b.report.txt").read_text()
    ok, msg = d._handle("requeue", b)
    assert ok and j.get(b).state == S.READY and j.get(b).print_requested
    assert not (cfg.failed_dir / "b.report.txt").exists()


def test_orphaned_work_folder_goes_back_to_the_spool(tmp_path):
    cfg = make_cfg(tmp_path)
    sp = Daemon(cfg).spool
    orphan = cfg.work_dir / "deadbeef"
    orphan.mkdir(parents=True)
    (orphan / "lost.stl").write_bytes(b"x")
    (orphan / "repair.log").write_bytes(b"log")
    assert sp.recover_orphans() == ["lost.stl"]
    assert (cfg.spool.path / "lost.stl").read_bytes() == b"x"
    assert not orphan.exists()


def test_requeue_of_a_failed_job_restores_its_input(tmp_path):
    cfg = make_cfg(tmp_path)
    d = Daemon(cfg)
    jid = take(d.spool, "c.gcode")
    d.journal.transition(jid, S.FAILED, reason="boom")
    d.spool.archive(jid)
    assert (cfg.failed_dir / "c.gcode").exists()
    ok, msg = d._handle("requeue", jid)
    assert ok, msg
    job = d.journal.get(jid)
    assert job.state == S.QUEUED and Path(job.input_path).read_bytes() == b"G28\nG1 X1\n"
    assert not (cfg.failed_dir / "c.gcode").exists()
    assert not (cfg.failed_dir / "c.report.txt").exists()


def test_requests_that_make_no_sense_are_refused(tmp_path):
    d = Daemon(make_cfg(tmp_path))
    jid = take(d.spool, "d.gcode")
    assert d._handle("requeue", jid)[0] is False       # queued: nothing to requeue
    assert d._handle("print", 999)[0] is False
    assert d._handle("explode", jid)[0] is False
    ok, _ = d._handle("cancel", jid)
    assert ok and d.journal.get(jid).state == S.CANCELLED
    assert (d.cfg.failed_dir / "d.gcode").exists()


def test_a_refused_entry_cannot_be_requeued(tmp_path):
    d = Daemon(make_cfg(tmp_path))
    jid = take(d.spool, "notes.txt")
    assert d.journal.get(jid).state == S.FAILED
    rid = d.journal.add_request(jid, "requeue")  # the way the CLI asks
    d.handle_requests()
    r = d.journal.request(rid)
    assert r["ok"] == 0 and "drop it into the spool again" in r["message"]


def test_second_daemon_on_the_same_state_dir_is_refused(tmp_path):
    cfg = make_cfg(tmp_path)
    first = Daemon(cfg)
    with pytest.raises(AlreadyRunning, match="another preflight daemon"):
        Daemon(cfg)
    assert first.journal is not None


def test_a_job_that_keeps_killing_the_daemon_fails(tmp_path):
    cfg = make_cfg(tmp_path)
    d = Daemon(cfg)
    jid = take(d.spool, "e.stl", b"solid e\nendsolid e\n")
    d.journal.update(jid, attempts=cfg.limits.max_attempts)
    proc = Processor(cfg, d.journal, d.spool, lambda: {"nozzle_diameter": 0.4},
                     stop=threading.Event(), claim_lock=threading.Lock(), active={})
    job, ev = proc.next_job(True)
    proc.process(job, {"nozzle_diameter": 0.4}, ev)
    job = d.journal.get(jid)
    assert job.state == S.FAILED and "interrupted 3 times" in job.reason


def test_a_job_sliced_for_another_nozzle_is_redone(tmp_path):
    cfg = make_cfg(tmp_path)
    d = Daemon(cfg)
    jid = take(d.spool, "f.stl", b"solid f\nendsolid f\n")
    d.journal.transition(jid, S.REPAIRING, epsilon=0.4, printer_info={"nozzle_diameter": 0.4})
    d.journal.transition(jid, S.SLICING)
    d.journal.transition(jid, S.READY)
    link = PrinterLink(cfg, d.journal, d.spool, threading.Event())
    assert link._stale(d.journal.get(jid), {"nozzle_diameter": 0.6}) is True
    assert d.journal.get(jid).state == S.QUEUED
    assert "0.6 mm nozzle" in d.journal.history(jid)[-1]["note"]


def test_a_name_that_is_not_utf8_is_refused_not_stuck(tmp_path):
    import os

    d = Daemon(make_cfg(tmp_path))
    raw = os.fsencode(str(d.spool.root)) + b"/bad\xff.gcode"
    with open(raw, "wb") as fh:
        fh.write(b"G28\n")
    name = os.fsdecode(b"bad\xff.gcode")
    jid = d.spool.intake(d.spool.root / name)
    job = d.journal.get(jid)
    assert job.state == S.FAILED and "not valid UTF-8" in job.reason
    assert job.source_name == "bad\ufffd.gcode"
    assert sorted(os.listdir(d.spool.root)) == [".preflight", "done", "failed"]
    assert (d.cfg.failed_dir / job.name).exists()


def test_start_up_recovery_does_not_load_every_job(tmp_path):
    # Found by the soak: the daemon's memory after each start grew with the journal
    # (every job and its reports were decoded to learn which work folders are owned).
    import tracemalloc

    cfg = make_cfg(tmp_path)
    d = Daemon(cfg)
    report = {"log": "x" * 20_000}
    for i in range(300):
        jid = d.journal.add_job(name=f"p{i}.stl", source_name=f"p{i}.stl", kind="mesh",
                                work_dir=str(cfg.work_dir / f"owned{i}"), input_path="")
        d.journal.update(jid, repair_report=report)
    (cfg.work_dir / "owned7").mkdir(parents=True)
    (cfg.work_dir / "owned7" / "p7.stl").write_bytes(b"kept")
    orphan = cfg.work_dir / "orphan"
    orphan.mkdir()
    (orphan / "lost.stl").write_bytes(b"x")
    tracemalloc.start()
    try:
        given_back = d.spool.recover_orphans()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert given_back == ["lost.stl"]
    assert (cfg.work_dir / "owned7" / "p7.stl").read_bytes() == b"kept"
    assert peak < 1_000_000, f"recovery allocated {peak / 1e6:.1f} MB for 300 jobs"


def test_a_job_killed_while_being_archived_is_archived_at_start_up(tmp_path):
    # Found by the soak: a kill -9 between a print's `done` and the writing of its
    # reports left a done job without reports (and, earlier still, its files in work/).
    cfg = make_cfg(tmp_path)
    d = Daemon(cfg)
    j = d.journal
    printed = take(d.spool, "printed.gcode")
    broken = take(d.spool, "broken.gcode")
    for state in (S.READY, S.PRINTING, S.DONE):
        j.transition(printed, state)
    j.transition(broken, S.FAILED, reason="the G-code file has no commands")
    work = Path(j.get(printed).work_dir)
    assert j.unreported(set(S)) == [printed, broken]
    d.recover()
    assert j.unreported(set(S)) == []
    assert (cfg.done_dir / "printed.gcode").read_bytes() == b"G28\nG1 X1\n"
    assert not work.exists()
    assert "PRINTED" in (cfg.done_dir / "printed.report.txt").read_text()
    text = (cfg.failed_dir / "broken.report.txt").read_text()
    assert "FAILED - the G-code file has no commands" in text
    assert (cfg.failed_dir / "broken.gcode").exists()


def test_a_paused_print_is_interrupted_at_start_up_and_never_resumed(tmp_path):
    """The printer may have reset or cooled down while the daemon was away: the paused
    print cannot go on from its pause point."""
    d = Daemon(make_cfg(tmp_path))
    j = d.journal
    jid = take(d.spool, "p.gcode")
    j.transition(jid, S.READY)
    j.transition(jid, S.PRINTING, progress=0.25)
    j.transition(jid, S.PAUSED, note="paused by the user")
    d.recover()
    job = j.get(jid)
    assert job.state == S.INTERRUPTED
    assert "while the print was paused" in job.reason and "25%" in job.reason
    assert "cannot be resumed" in job.reason
    for action in ("resume", "pause", "stop"):
        ok, msg = d._handle(action, jid)
        assert not ok and "interrupted" in msg
    ok, _ = d._handle("requeue", jid)
    assert ok and j.get(jid).state == S.READY


def test_pause_requests_need_a_print(tmp_path):
    d = Daemon(make_cfg(tmp_path))
    jid = take(d.spool, "q.gcode")
    for action in ("pause", "resume", "stop"):
        ok, msg = d._handle(action, jid)
        assert not ok and "queued" in msg
