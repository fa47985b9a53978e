"""The level of a link over one report period, from its counters (devices/diagnostics.py)."""
import dataclasses

from tacforce_ros.devices.diagnostics import ERROR, OK, STALE, WARN, LinkDiagnostics, link_health


def counters(**values):
    return dataclasses.replace(LinkDiagnostics(), **values)


def test_a_link_is_stale_until_data_arrives_then_ok_while_it_flows():
    assert link_health(counters(), None) == (STALE, 'no data from the device yet')
    first = counters(received=10, delivered=10, last_seen=100.0)
    assert link_health(first, None)[0] == OK
    assert link_health(counters(received=20, delivered=20, last_seen=101.0), first) == (
        OK, 'streaming')


def test_a_period_without_data_is_an_error_and_lost_or_bad_data_a_warning():
    before = counters(received=10, delivered=10, last_seen=100.0)
    level, message = link_health(dataclasses.replace(before), before)
    assert level == ERROR and message.startswith('no data for')
    worse = counters(received=20, delivered=17, malformed=2, gaps=1, dropped=2, last_seen=101.0,
                     last_error='bad JSON')
    level, message = link_health(worse, before)
    assert level == WARN
    assert '2 malformed, 1 gaps' in message and 'bad JSON' in message
    # The next period with no new trouble is OK again: the counts stay, the level does not.
    later = dataclasses.replace(worse, received=30, delivered=27, last_seen=102.0)
    assert link_health(later, worse) == (OK, 'streaming')


def test_a_failure_the_driver_knows_of_is_an_error_whatever_the_counters():
    flowing = counters(received=10, delivered=10, last_seen=100.0)
    assert link_health(flowing, None, 'link lost: closed') == (ERROR, 'link lost: closed')
