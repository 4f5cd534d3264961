"""The journal: the state machine is enforced, timestamps recorded, WAL on disk."""

import sqlite3

import pytest

from daemon.journal import Journal
from daemon.states import ALLOWED, JobState, TransitionError

S = JobState


def new_job(j: Journal, name="a.stl") -> int:
    return j.add_job(name=name, source_name=name, kind="mesh", work_dir="/w", input_path="/w/a")


def test_happy_path_records_every_transition(tmp_path):
    j = Journal(tmp_path / "j.sqlite")
    jid = new_job(j)
    for st in (S.REPAIRING, S.SLICING, S.READY, S.PRINTING, S.DONE):
        j.transition(jid, st)
    hist = j.history(jid)
    assert [h["to_state"] for h in hist] == ["queued", "repairing", "slicing", "ready",
                                             "printing", "done"]
    ats = [h["at"] for h in hist]
    assert ats == sorted(ats) and all(a > 0 for a in ats)
    assert j.get(jid).state == S.DONE


@pytest.mark.parametrize("path", [
    (S.PRINTING,),                       # queued cannot print
    (S.REPAIRING, S.DONE),               # repairing cannot be done
    (S.READY, S.PRINTING, S.DONE, S.QUEUED),  # done is final
    (S.READY, S.PRINTING, S.INTERRUPTED, S.PRINTING),  # interrupted is not re-sent by itself
])
def test_forbidden_transitions_raise(tmp_path, path):
    j = Journal(tmp_path / "j.sqlite")
    jid = new_job(j)
    for st in path[:-1]:
        j.transition(jid, st)
    with pytest.raises(TransitionError):
        j.transition(jid, path[-1])
    assert j.get(jid).state == (path[-2] if len(path) > 1 else S.QUEUED)


def test_every_state_has_a_rule_and_done_is_final():
    assert set(ALLOWED) == set(JobState)
    assert ALLOWED[S.DONE] == frozenset()
    assert S.PRINTING not in ALLOWED[S.INTERRUPTED]


def test_expect_guards_races(tmp_path):
    j = Journal(tmp_path / "j.sqlite")
    jid = new_job(j)
    with pytest.raises(TransitionError):
        j.transition(jid, S.CANCELLED, expect=S.READY)
    assert j.get(jid).state == S.QUEUED


def test_fields_json_and_requests_and_meta(tmp_path):
    j = Journal(tmp_path / "j.sqlite")
    jid = new_job(j)
    j.transition(jid, S.REPAIRING, epsilon=0.4, epsilon_source="M862.1",
                 printer_info={"nozzle_diameter": 0.4, "build_volume": [250, 210, 220]})
    job = j.get(jid)
    assert job.epsilon == 0.4 and job.printer_info["build_volume"] == [250, 210, 220]
    rid = j.add_request(jid, "cancel")
    assert [r["id"] for r in j.pending_requests()] == [rid]
    j.finish_request(rid, True, "ok")
    assert j.pending_requests() == [] and j.request(rid)["ok"] == 1
    j.set_meta("status", {"pid": 1})
    assert j.get_meta("status") == {"pid": 1}


def test_wal_mode_and_second_connection_sees_commits(tmp_path):
    path = tmp_path / "j.sqlite"
    j = Journal(path)
    jid = new_job(j)
    mode = sqlite3.connect(path).execute("PRAGMA journal_mode").fetchone()[0]
    assert mode == "wal"
    other = Journal(path, readonly=True)
    assert other.get(jid).state == S.QUEUED
    j.transition(jid, S.FAILED, reason="bad")
    assert other.get(jid).reason == "bad"
    assert [x.id for x in other.jobs({S.FAILED})] == [jid]
    assert other.jobs(limit=1)[0].id == jid
