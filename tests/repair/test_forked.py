"""repair.forked: a call run in a forked child comes back by value; a child that dies
has the call run again in the caller; a cancelled child is gone."""

from __future__ import annotations

import os
import signal

import numpy as np

from repair.forked import Forked


def _in_child_of(parent: int) -> bool:
    return os.getpid() != parent


def test_the_value_comes_back_from_a_child():
    parent = os.getpid()
    job = Forked(lambda: (os.getpid(), np.arange(5) * 2))
    pid, arr = job.result()
    assert pid != parent and np.array_equal(arr, [0, 2, 4, 6, 8])


def test_a_child_that_dies_has_the_call_run_here():
    parent = os.getpid()

    def dies_in_child() -> str:
        if _in_child_of(parent):
            os.kill(os.getpid(), signal.SIGKILL)
        return "computed here"

    assert Forked(dies_in_child).result() == "computed here"


def test_a_cancelled_child_is_killed():
    r, w = os.pipe()
    parent = os.getpid()

    def sleeps() -> None:
        if _in_child_of(parent):
            os.write(w, b"x")
            signal.pause()

    job = Forked(sleeps)
    os.close(w)  # now only the child holds the pipe's write end
    assert os.read(r, 1) == b"x"  # the child runs
    job.cancel()
    assert os.read(r, 1) == b""  # end of file: the child is gone
    os.close(r)
