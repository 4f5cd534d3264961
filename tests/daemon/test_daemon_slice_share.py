"""With several jobs at once ([daemon] workers), each slice's `workers = auto` gets its
share of this machine's CPUs; one job at a time keeps auto; an explicit count is kept."""

from __future__ import annotations

from daemon.config import parse_config
from daemon.pipeline import slice_overrides
from slicer.parallel import available_cpus
from slicer.profile import Profile


def _overrides(daemon_workers: int, profile: dict | None = None) -> dict:
    return slice_overrides(parse_config({"daemon": {"workers": daemon_workers},
                                         "profile": profile or {}}))


def test_one_job_at_a_time_keeps_auto():
    assert "workers" not in _overrides(1)


def test_as_many_jobs_as_cpus_slice_on_one_process_each():
    cpus = available_cpus()
    over = _overrides(max(2, cpus))
    assert over["workers"] == "1"
    assert Profile.for_printer().with_overrides(over).workers == "1"


def test_fewer_jobs_than_cpus_share_them():
    cpus = available_cpus()
    assert _overrides(2)["workers"] == str(max(1, cpus // 2))


def test_an_explicit_count_is_kept():
    assert _overrides(4, {"workers": "3"})["workers"] == "3"
