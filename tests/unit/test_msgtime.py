"""The gateway's clock on message time (pfdoa.gateway.msgtime): which message times are
plausible, and that an implausible one moves nothing; a host clock injected."""

import pytest

from pfdoa.gateway.msgtime import AHEAD, BEHIND, MAX_LAG_S, MAX_LEAD_S, RESYNC, MessageClock

pytestmark = pytest.mark.unit


def clock():
    host = [100.0]
    return MessageClock(monotonic=lambda: host[0]), host


def test_plausible_times_move_the_clock_and_implausible_ones_move_nothing():
    c, _host = clock()
    assert c.admit(10.0) is None and c.now == 10.0  # the first reading sets it
    assert c.admit(10.1) is None and c.admit(10.05) is None and c.now == 10.1  # a little late: admitted
    assert c.admit(9e10) == AHEAD and c.now == 10.1  # one stamp in the far future
    assert c.admit(10.1 + MAX_LEAD_S + 0.01) == AHEAD and c.now == 10.1
    assert c.admit(10.1 - MAX_LAG_S - 0.01) == BEHIND and c.admit(0.0) == BEHIND and c.now == 10.1
    assert c.admit(10.2) is None and c.now == 10.2 and c.resets == 0
    # Right at the tolerances: admitted.
    assert c.admit(10.2 + MAX_LEAD_S) is None and c.admit(10.2 + MAX_LEAD_S - MAX_LAG_S) is None


def test_after_a_silence_the_host_time_that_passed_is_allowed():
    """A fleet silent for an hour (nobody in range) resumes an hour later on its own clock."""
    c, host = clock()
    c.admit(1000.0)
    assert c.admit(1000.0 + 3600.0) == AHEAD  # no host time passed: implausible
    host[0] += 3600.0
    assert c.admit(1000.0 + 3600.0) is None and c.now == 4600.0
    assert c.admit(4600.0 + 3600.0) == AHEAD  # the allowance counts from when the clock last moved


def test_a_wrong_first_clock_gives_way_to_a_run_of_readings_that_agree():
    """The first reading came from a node with a broken clock: the fleet's readings are all
    refused until RESYNC of them in a row, agreeing with each other, move the clock back to
    them (counted, moved_back said for the tracker to rebase); one plausible reading in
    between starts the run again."""
    c, _host = clock()
    assert c.admit(1e6) is None  # nothing to compare with yet
    for k in range(RESYNC - 1):
        assert c.admit(50.0 + 0.01 * k) == BEHIND, k
    assert c.admit(1e6) is None  # the broken node again: plausible to the (wrong) clock, the run restarts
    for k in range(RESYNC - 1):
        assert c.admit(51.0 + 0.01 * k) == BEHIND, k
    assert c.now == 1e6 and c.resets == 0
    t = 51.0 + 0.01 * (RESYNC - 1)
    assert c.admit(t) is None and c.now == t and c.resets == 1 and c.moved_back
    assert c.admit(t + 0.1) is None and not c.moved_back and c.now == t + 0.1
    assert c.admit(1e6) == AHEAD  # from now on the broken node is the one refused


def test_a_lone_wrong_clock_among_working_ones_never_moves_it_and_a_fleet_that_jumps_does():
    c, _host = clock()
    c.admit(50.0)
    for k in range(10 * RESYNC):  # one node far ahead, interleaved with the fleet's readings
        assert c.admit(9e10 + k) == AHEAD and c.admit(50.0 + 0.001 * k) is None
    assert c.resets == 0 and c.now < 51.0
    for k in range(RESYNC):  # the whole fleet's clock jumped (its publisher restarted on another base)
        assert c.admit(5000.0 + 0.01 * k) == (None if k == RESYNC - 1 else AHEAD)
    assert c.resets == 1 and not c.moved_back and c.now == 5000.0 + 0.01 * (RESYNC - 1)


def test_a_run_that_does_not_agree_with_itself_moves_nothing():
    c, _host = clock()
    c.admit(50.0)
    for k in range(3 * RESYNC):  # far future, but scattered over years: never a clock
        assert c.admit(1e6 + 1e5 * k) == AHEAD
    assert c.now == 50.0 and c.resets == 0
