"""Farm faults with real processes: a printing node killed with SIGKILL, the compute
node killed mid-repair, the broker stopped for 20 s mid-batch."""

from __future__ import annotations

import time

import pytest
from daemon_helpers import DaemonProc, box, drop, tiny_gcode, write_binary_stl
from farm_checks import all_ended, check_farm
from farm_helpers import farm_config

from daemon.farm.queue import FarmQueue
from daemon.worker import FAULT_ENV


def _boxes(tmp, spool, count: int, prefix: str = "m") -> list[str]:
    src = tmp / "models"
    src.mkdir(exist_ok=True)
    names = []
    for i in range(count):
        path = src / f"{prefix}{i:02d}.stl"
        write_binary_stl(path, *box((3.0 + 0.5 * i, 3.0, 2.0)))
        drop(spool, path.name, path.read_bytes())
        names.append(path.name)
    return names


def _printing(node) -> list:
    return [j for j in node.jobs() if str(j.state) == "printing"]


def test_killed_printing_node_interrupts_its_print_and_others_print_the_rest(
        tmp_path, redis_server):
    art = tmp_path / "artefacts"
    # node a prints slowly (a heat-up takes seconds), so it is caught mid-print; it
    # computes nothing, so its 0.6 printer holds a claim it cannot start (no compute
    # node runs before b)
    a = DaemonProc(farm_config(tmp_path / "a", node="a", broker=redis_server.url,
                               artefacts=art, printers=[{"name": "a04", "nozzle": 0.4},
                                                        {"name": "a06", "nozzle": 0.6}],
                               compute=False, claim_timeout=4, speedup=15))
    b = DaemonProc(farm_config(tmp_path / "b", node="b", broker=redis_server.url,
                               artefacts=art, printers=[{"name": "b04", "nozzle": 0.4},
                                                        {"name": "b06", "nozzle": 0.6}],
                               compute=True, claim_timeout=4))
    queue = FarmQueue(redis_server.url, "test")
    nodes = [a, b]
    try:
        a.start()
        drop(a.cfg.spool.path, "m00.toml", b"nozzle = 0.6\n")
        names = _boxes(tmp_path, a.cfg.spool.path, 1)
        a.wait_for(lambda: queue.all_jobs(), what="the mesh job published")
        names += [f"g{i:02d}.gcode" for i in range(7)]
        for i, name in enumerate(names[1:]):  # each waits for its bed to heat: seconds
            drop(a.cfg.spool.path, name, tiny_gcode([f"M117 job {i}", "M190 S60", "M140 S0"],
                                                    moves=5).encode())
        a.wait_for(lambda: _printing(a), what="a print on node a")
        a.wait_for(lambda: a.journal.jobs() and len(queue.all_jobs()) == len(names),
                   what="every job published")
        a.kill9()
        killed_mid_print = {j for j, job in queue.all_jobs().items()
                            if job["state"] == "printing"}
        claimed = {j for j, job in queue.all_jobs().items() if job["state"] == "claimed"}
        assert len(killed_mid_print) == 1 and len(claimed) == 1
        b.start()  # the rest of the farm: only now can anyone else print
        b.wait_for(lambda: sum(j["state"] == "done" for j in queue.all_jobs().values())
                   == len(names) - 1, what="node b printed the other jobs", timeout=300)
        assert queue.all_jobs()[next(iter(killed_mid_print))]["state"] == "printing"
        a.start()  # its journal: the print was interrupted; the farm hears it
        a.wait_for(lambda: all_ended(queue, len(names)), what="every job ended")
        jobs = check_farm(queue, nodes, len(names), partial_prints=1)
        for fid, entry in jobs.items():
            if fid in killed_mid_print:
                assert entry["job"]["state"] == "interrupted" and entry["node"] is a
                assert "interrupted" in (entry["local"].reason or "")
            else:
                assert entry["job"]["state"] == "done" and entry["node"] is b
        (back,) = claimed  # claimed by a, never started: back on the queue, printed on b
        assert jobs[back]["job"]["requeues"] == "1" and jobs[back]["printer"] == "b06"
        # re-sent only by an explicit requeue, on the printer it was on
        fid = next(iter(killed_mid_print))
        local = jobs[fid]["local"]
        answer = a.cli("jobs", "requeue", str(local.id))
        assert answer.returncode == 0, answer.stderr
        a.wait_for(lambda: queue.job(fid)["state"] == "done", what="the requeued print")
        assert queue.job(fid)["prints"] == "2" and queue.job(fid)["node"] == "a"
    finally:
        for node in nodes:
            node.stop()


def test_compute_node_killed_mid_repair_is_redone_elsewhere(tmp_path, redis_server):
    art = tmp_path / "artefacts"
    common = {"broker": redis_server.url, "artefacts": art, "task_timeout": 6}
    a = DaemonProc(farm_config(tmp_path / "a", node="a", printers=[{"name": "a04",
                                                                     "nozzle": 0.4}],
                               compute=False, **common))
    # c's repair of this model hangs (the documented test hook), so it is mid-repair
    c = DaemonProc(farm_config(tmp_path / "c", node="c", printers=None, **common),
                   env={FAULT_ENV: "repair:hang:slowpoke"})
    d = DaemonProc(farm_config(tmp_path / "d", node="d", printers=None, **common))
    queue = FarmQueue(redis_server.url, "test")
    nodes = [a, c, d]
    try:
        a.start()
        c.start()
        _boxes(tmp_path, a.cfg.spool.path, 1, prefix="slowpoke")
        c_log = c.cfg.daemon.state_dir / "farm-compute.log"
        c.wait_for(lambda: c_log.exists() and "prepare slowpoke" in c_log.read_text(),
                   what="node c repairing", timeout=300)
        d.start()
        time.sleep(1.0)
        assert queue.all_jobs() and all(j["state"] == "claimed"
                                        for j in queue.all_jobs().values())
        c.kill9()
        a.wait_for(lambda: all_ended(queue, 1), what="the job, repaired elsewhere",
                   timeout=300)
        jobs = check_farm(queue, [a, d], 1)
        (entry,) = jobs.values()
        assert entry["job"]["state"] == "done"
        assert entry["local"].repair_report and entry["local"].epsilon == pytest.approx(0.4)
        d_log = (d.cfg.daemon.state_dir / "farm-compute.log").read_text()
        assert "prepare slowpoke" in d_log and "succeeded" in d_log
    finally:
        for node in nodes:
            node.stop()


@pytest.mark.slow
def test_broker_outage_loses_and_duplicates_nothing(tmp_path, redis_server):
    art = tmp_path / "artefacts"
    common = {"broker": redis_server.url, "artefacts": art, "task_timeout": 10}
    a = DaemonProc(farm_config(tmp_path / "a", node="a", printers=[
        {"name": "a04", "nozzle": 0.4}, {"name": "a06", "nozzle": 0.6}], speedup=200,
        **common))
    b = DaemonProc(farm_config(tmp_path / "b", node="b", printers=[
        {"name": "b04", "nozzle": 0.4}], speedup=200, **common))
    c = DaemonProc(farm_config(tmp_path / "c", node="c", printers=None, **common))
    queue = FarmQueue(redis_server.url, "test")
    nodes = [a, b, c]
    try:
        for node in nodes:
            node.start()
        _boxes(tmp_path, a.cfg.spool.path, 8, prefix="before")
        for i in range(6):
            drop(b.cfg.spool.path, f"g{i}.gcode", tiny_gcode([f"M117 b {i}"]).encode())
        a.wait_for(lambda: sum(j["state"] == "done" for j in queue.all_jobs().values()) >= 3
                   and any(_printing(n) for n in nodes), what="the batch under way, printing")
        redis_server.stop()
        stopped = time.time()
        printing = [(n, j.id) for n in nodes for j in _printing(n)]
        _boxes(tmp_path, a.cfg.spool.path, 3, prefix="during")  # into the outbox
        drop(c.cfg.spool.path, "during.gcode", tiny_gcode(["M117 during"]).encode())
        time.sleep(20)
        for node in nodes:
            assert node.alive()
        # prints under way went on to the end; none started without the broker
        for node, job_id in printing:
            assert str(node.journal.get(job_id).state) == "done"
        for node in nodes:
            for job in node.jobs():
                starts = [t["at"] for t in node.journal.history(job.id)
                          if t["to_state"] == "printing"]
                assert not any(stopped + 1.0 < at for at in starts), job.name
        redis_server.start()
        a.wait_for(lambda: all_ended(queue, 18), what="every job ended", timeout=600)
        jobs = check_farm(queue, nodes, 18)
        assert all(e["job"]["state"] == "done" for e in jobs.values()), \
            [(e["job"]["name"], e["job"].get("reason")) for e in jobs.values()]
    finally:
        for node in nodes:
            node.stop()
