"""XELA: message codec and the client against the xela_server emulator over real WebSockets."""
import json
import time

import numpy as np
import pytest
from devices_support import EVENT_TIMEOUT, wait_until
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from tacforce_ros.devices.xela import (XelaClient, XelaConfig, XelaFormatError, parse_message,
                                       routine_message, welcome_message)
from tacforce_ros.hand.description import load_hand
from tacforce_ros.sim.emulators.xela_server import XelaServerEmulator

HAND = load_hand()


class RampSource:
    """Taxel i reads (i, 2i, 3i) + call number, so every frame and taxel is identifiable."""

    def __init__(self):
        self.calls = 0

    def __call__(self):
        self.calls += 1
        base = np.arange(368, dtype=np.int64)[:, None] * np.array([1, 2, 3])
        counts = ((base + self.calls) % 65536).astype(np.uint16)
        return counts, np.full(368, 300.0), time.time()


def test_welcome_is_skipped_and_hand_built_frames_decode():
    assert parse_message(welcome_message()) is None
    assert parse_message('{"message": "Welcome"}') is None
    frame = {'message': 7, 'time': 1.5, 'type': 'routine',
             '1': {'taxels': 2, 'data': '8000,7FFF,0001,FFFF,0000,ABCD', 'temp': [300.5, 301]}}
    message = parse_message(json.dumps(frame), n_taxels=2)
    assert (message.sequence, message.server_time) == (7, 1.5)
    assert message.counts.dtype == np.uint16
    assert message.counts.tolist() == [[0x8000, 0x7FFF, 1], [0xFFFF, 0, 0xABCD]]
    assert message.temperatures.tolist() == [300.5, 301.0]
    frame['1']['data'] = [32768, 32767, 1, 65535, 0, 43981]
    del frame['1']['temp']
    as_list = parse_message(json.dumps(frame), n_taxels=2)
    np.testing.assert_array_equal(as_list.counts, message.counts)
    assert np.isnan(as_list.temperatures).all()


@pytest.mark.parametrize('text, reason', [
    ('{"message": 1, "type": "rout', 'not JSON'),
    ('[1, 2]', 'expected an object'),
    ('{"type": "routine", "message": 1, "time": 0, "1": {"taxels": 3, "data": ""}}',
     'reports 3 taxels'),
    ('{"type": "routine", "message": 1, "time": 0, "1": {"taxels": 2, "data": "1,2,3"}}',
     'data has 3 values'),
    ('{"type": "routine", "message": 1, "time": 0, "1": {"taxels": 2, "data": "0001,0002,'
     '0003,0004,0005,00GG"}}', 'not hex'),
    ('{"type": "routine", "message": 1, "time": 0, "1": {"taxels": 2, "data": [1,2,3,4,5,70000]}}',
     'not uint16'),
    ('{"type": "routine", "time": 0, "1": {"taxels": 2, "data": [1,2,3,4,5,6]}}', 'counter'),
])
def test_malformed_frames_say_what_is_wrong(text, reason):
    with pytest.raises(XelaFormatError, match=reason):
        parse_message(text, n_taxels=2)


@given(hnp.arrays(np.uint16, (368, 3)), st.integers(1, 2**40))
def test_emulator_encoding_round_trips_through_the_parser(counts, sequence):
    temps = np.linspace(290.0, 310.0, 368)
    message = parse_message(routine_message(sequence, counts, temps, 12.25))
    np.testing.assert_array_equal(message.counts, counts)
    np.testing.assert_allclose(message.temperatures, temps, atol=0.005)
    assert message.sequence == sequence and message.server_time == 12.25


def test_frames_are_stamped_split_per_array_and_complete():
    source = RampSource()
    with XelaServerEmulator(source, rate_hz=200) as server:
        client = XelaClient(XelaConfig(url=server.url), HAND)
        client.start()
        assert client.wait_for_samples(20, timeout=EVENT_TIMEOUT)
        client.close()
    frame = client.latest()
    assert frame.counts.shape == (368, 3) and frame.counts.dtype == np.uint16
    assert frame.stamp.monotonic > 0 and frame.stamp.wall > frame.server_time - 1
    np.testing.assert_array_equal(frame.counts[:, 0], (np.arange(368) + frame.sequence) % 65536)
    tip = HAND.array('index_tip')
    np.testing.assert_array_equal(frame.arrays['index_tip'], frame.counts[tip.flat_indices])
    assert len(frame.arrays) == 18
    diag = client.diagnostics.snapshot()
    assert diag.gaps == diag.malformed == diag.dropped == 0
    assert diag.received == diag.delivered + 1       # + the welcome frame


def test_bad_frames_are_counted_and_the_good_ones_around_them_all_arrive():
    with XelaServerEmulator(RampSource(), rate_hz=200) as server:
        client = XelaClient(XelaConfig(url=server.url))
        sequences = []
        client.add_callback(lambda f: sequences.append(f.sequence))
        client.start()
        assert client.wait_for_samples(5, timeout=EVENT_TIMEOUT)
        server.inject_text('{"message": 1, "type": "routine", ')
        assert wait_until(lambda: client.diagnostics.malformed == 1, EVENT_TIMEOUT)
        short = routine_message(10**6, np.zeros((300, 3), np.uint16), np.zeros(300), 0.0)
        server.inject_text(short)
        assert wait_until(lambda: client.diagnostics.malformed == 2, EVENT_TIMEOUT)
        assert 'reports 300 taxels, expected 368' in client.diagnostics.last_error
        assert client.wait_for_samples(5, timeout=EVENT_TIMEOUT)
        client.close()
    assert sequences == list(range(sequences[0], sequences[-1] + 1))
    assert client.diagnostics.gaps == 0


def test_server_that_disappears_and_comes_back_is_reconnected():
    with XelaServerEmulator(RampSource(), rate_hz=200) as server:
        client = XelaClient(XelaConfig(url=server.url, reconnect_initial=0.02,
                                       reconnect_max=0.1, stale_after=0.05))
        client.start()
        assert client.wait_for_samples(5, timeout=EVENT_TIMEOUT)
        server.stop()
        assert wait_until(lambda: not client.connected and client.is_stale(), EVENT_TIMEOUT)
        assert 'failed' in client.diagnostics.last_error or 'closed' in \
            client.diagnostics.last_error
        server.start()
        assert client.wait_for_samples(5, timeout=EVENT_TIMEOUT)
        client.close()
    diag = client.diagnostics.snapshot()
    assert diag.reconnects == 1 and diag.malformed == 0


def test_client_gives_up_after_the_configured_attempts():
    with XelaServerEmulator(RampSource()) as server:
        url = server.url
    client = XelaClient(XelaConfig(url=url, reconnect_initial=0.01, max_attempts=3))
    client.start()
    assert wait_until(lambda: client.fatal_error is not None, EVENT_TIMEOUT)
    assert 'gave up after 3 attempts' in str(client.fatal_error)
    client.close()


def test_hand_and_config_taxel_counts_must_agree():
    with pytest.raises(ValueError, match='368 taxels'):
        XelaClient(XelaConfig(n_taxels=30), HAND)
