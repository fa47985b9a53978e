"""ATI Net F/T RDT: byte-level codec and the client against the emulator over UDP on loopback."""
import logging
import threading

import numpy as np
import pytest
from devices_support import EVENT_TIMEOUT, wait_until
from hypothesis import given
from hypothesis import strategies as st

from tacforce_ros.devices.diagnostics import sequence_delta
from tacforce_ros.devices.netft import (CMD_START_REALTIME, CMD_STOP, STATUS_MONITOR_WARNING,
                                        NetFtClient, NetFtConfig, RdtError, decode_records,
                                        SILENT_RETRY_S, decode_request, encode_records,
                                        encode_request)
from tacforce_ros.sim.emulators.netft import NetFtEmulator


class CountingSource:
    """Wrench source whose Fx counts the calls, so every record is identifiable."""

    def __init__(self, status: int = 0):
        self.calls = 0
        self.status = status
        self.lock = threading.Lock()

    def __call__(self):
        with self.lock:
            self.calls += 1
            return np.array([self.calls, 0, 2_000_000, 0, 0, -500_000], np.int32), self.status


def client_for(emulator, **config):
    host, port = emulator.address
    client = NetFtClient(NetFtConfig(host=host, port=port, **config))
    client.start()
    return client


def test_request_bytes_match_the_protocol():
    assert encode_request(CMD_START_REALTIME).hex(' ') == '12 34 00 02 00 00 00 00'
    assert encode_request(CMD_STOP).hex(' ') == '12 34 00 00 00 00 00 00'
    assert encode_request(0x0042, 10).hex(' ') == '12 34 00 42 00 00 00 0a'
    assert decode_request(bytes.fromhex('1234000200000005')) == (2, 5)
    with pytest.raises(RdtError, match='header'):
        decode_request(bytes.fromhex('4321000200000000'))


def test_hand_built_record_decodes_to_its_values():
    record = bytes.fromhex(
        '00000007' '00000009' '80010000'      # rdt seq 7, ft seq 9, monitor warning
        '000f4240' 'fff0bdc0' '001e8480'      # Fx 1e6, Fy -1e6, Fz 2e6
        '00000001' 'ffffffff' '7fffffff')     # Tx 1, Ty -1, Tz int32 max
    decoded = decode_records(record)
    assert len(decoded) == 1
    assert int(decoded['rdt_sequence'][0]) == 7 and int(decoded['ft_sequence'][0]) == 9
    assert int(decoded['status'][0]) == STATUS_MONITOR_WARNING
    np.testing.assert_array_equal(decoded['counts'][0],
                                  [1_000_000, -1_000_000, 2_000_000, 1, -1, 2**31 - 1])
    assert encode_records(7, 9, STATUS_MONITOR_WARNING, decoded['counts'][0]) == record


@pytest.mark.parametrize('length', [0, 35, 37, 71])
def test_lengths_not_a_multiple_of_36_are_refused(length):
    with pytest.raises(RdtError, match='multiple of 36'):
        decode_records(bytes(length))


def test_default_scaling_is_one_newton_per_million_counts_and_units_convert_to_si():
    np.testing.assert_allclose(NetFtConfig().si_per_count() * 1_000_000, [1] * 6)
    imperial = NetFtConfig(force_unit='lbf', torque_unit='lbf-in', counts_per_force=1.0,
                           counts_per_torque=1.0).si_per_count()
    np.testing.assert_allclose(imperial, [4.4482216152605] * 3 + [0.1129848290276167] * 3)
    with pytest.raises(ValueError, match='force_unit'):
        NetFtConfig(force_unit='furlong')


@given(st.integers(0, 2**32 - 1), st.integers(-2**31 + 1, 2**31 - 1))
def test_sequence_delta_inverts_wrapping_addition(last, step):
    assert sequence_delta((last + step) % 2**32, last) == step


def test_stream_scales_counts_and_stops_on_close():
    source = CountingSource()
    with NetFtEmulator(source, rate_hz=500) as emulator:
        client = client_for(emulator)
        assert client.wait_for_samples(20, timeout=EVENT_TIMEOUT)
        sample = client.latest()
        np.testing.assert_allclose(sample.wrench[2:], [2.0, 0, 0, -0.5])
        assert sample.wrench.dtype == np.float64
        assert sample.stamp.monotonic > 0
        client.close()
        assert wait_until(lambda: not emulator.streaming, EVENT_TIMEOUT)
        diag = client.diagnostics.snapshot()
        assert diag.gaps == diag.dropped == diag.malformed == 0


def test_bad_datagrams_are_counted_and_good_records_around_them_all_arrive():
    source = CountingSource()
    with NetFtEmulator(source, rate_hz=500) as emulator:
        client = client_for(emulator)
        assert client.wait_for_samples(5, timeout=EVENT_TIMEOUT)
        for payload in (bytes(20), bytes(41), bytes(36 * 2 + 1)):    # truncated, oversized
            emulator.send_raw(payload)
        assert client.wait_for_samples(10, timeout=EVENT_TIMEOUT)
        client.close()
    diag = client.diagnostics.snapshot()
    assert diag.malformed == 3 and diag.dropped == 3
    assert 'multiple of 36' in diag.last_error
    assert diag.gaps == 0 and diag.reordered == 0
    assert diag.delivered == diag.received - 3


def test_skipped_and_reordered_records_are_counted():
    source = CountingSource()
    with NetFtEmulator(source, rate_hz=500) as emulator:
        client = client_for(emulator)
        sequences = []
        client.add_callback(lambda s: sequences.append(s.rdt_sequence))
        assert client.wait_for_samples(5, timeout=EVENT_TIMEOUT)
        emulator.skip(3)
        assert client.wait_for_samples(5, timeout=EVENT_TIMEOUT)
        emulator.reorder_next()
        assert client.wait_for_samples(5, timeout=EVENT_TIMEOUT)
        client.close()
    diag = client.diagnostics.snapshot()
    # 3 skipped + 1 held back (a gap when its successor arrives, then reordered on arrival).
    assert diag.gaps == 4
    assert diag.reordered == 1
    assert np.all(np.diff(sequences) > 0)


def test_wrap_around_is_not_a_gap():
    source = CountingSource()
    with NetFtEmulator(source, rate_hz=500, first_sequence=2**32 - 5) as emulator:
        client = client_for(emulator)
        sequences = []
        client.add_callback(lambda s: sequences.append(s.rdt_sequence))
        assert client.wait_for_samples(15, timeout=EVENT_TIMEOUT)
        client.close()
    assert 2**32 - 1 in sequences and 0 in sequences
    assert client.diagnostics.gaps == 0 and client.diagnostics.reordered == 0


def test_monitor_warnings_are_delivered_and_serious_status_records_withheld():
    source = CountingSource(status=STATUS_MONITOR_WARNING)
    with NetFtEmulator(source, rate_hz=500) as emulator:
        client = client_for(emulator)
        events, delivered = [], []
        client.add_event_callback(lambda level, text: events.append((level, text)))
        client.add_callback(lambda s: delivered.append(s.status))
        assert client.wait_for_samples(3, timeout=EVENT_TIMEOUT)
        source.status = 0x80020000          # a serious word: no record may pass
        assert wait_until(lambda: client.diagnostics.status_errors >= 20, EVENT_TIMEOUT)
        source.status = 0
        assert client.wait_for_samples(3, timeout=EVENT_TIMEOUT)
        client.close()
    diag = client.diagnostics.snapshot()
    assert diag.status_warnings >= 3 and diag.dropped >= diag.status_errors >= 20
    assert set(delivered) == {STATUS_MONITOR_WARNING, 0}
    assert diag.last_error.startswith('F/T status 0x80020000')
    assert [level for level, _ in events] == [logging.ERROR, logging.INFO]
    assert 'withholding' in events[0][1] and 'withheld records' in events[1][1]


def test_serious_status_records_stay_out_of_the_host_bias():
    source = CountingSource(status=0x80020000)
    with NetFtEmulator(source, rate_hz=500) as emulator:
        client = client_for(emulator)
        assert wait_until(lambda: client.diagnostics.status_errors >= 10, EVENT_TIMEOUT)
        with pytest.raises(RuntimeError, match='no wrench received'):
            client.set_host_bias()
        client.close()


def test_device_bias_and_host_bias_zero_the_reading():
    source = CountingSource()
    with NetFtEmulator(source, rate_hz=500) as emulator:
        client = client_for(emulator)
        assert client.wait_for_samples(5, timeout=EVENT_TIMEOUT)
        bias = client.set_host_bias()
        assert bias[2] == pytest.approx(2.0)
        assert client.wait_for_samples(2, timeout=EVENT_TIMEOUT)
        assert client.latest().wrench[2] == pytest.approx(0.0)
        client.clear_host_bias()
        client.bias_device()
        assert wait_until(lambda: client.latest().counts[2] == 0, EVENT_TIMEOUT)
        client.close()


def test_wrong_request_header_is_ignored_by_the_box():
    import socket
    with NetFtEmulator(CountingSource(), rate_hz=500) as emulator:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.sendto(bytes.fromhex('4321000200000000'), emulator.address)
            assert wait_until(lambda: emulator.diagnostics.malformed == 1, EVENT_TIMEOUT)
        assert not emulator.streaming


def test_stale_when_the_box_stops_sending():
    with NetFtEmulator(CountingSource(), rate_hz=500) as emulator:
        client = client_for(emulator, stale_after=0.25)
        assert client.wait_for_samples(3, timeout=EVENT_TIMEOUT)
        assert not client.is_stale()
        emulator.skip(10**9)
        assert wait_until(client.is_stale, EVENT_TIMEOUT)
        client.close()


def test_a_box_that_comes_up_after_the_request_streams_without_a_restart():
    """The start request went to a port nobody listened on: the client asks again, whether the
    kernel reported the refusal (ICMP port unreachable, 'refused' in the diagnostics) or withheld
    it, so a box that comes up later streams (launch starts the simulator and the bridge
    together)."""
    with NetFtEmulator(CountingSource(), rate_hz=500) as gone:
        host, port = gone.address
    client = NetFtClient(NetFtConfig(host=host, port=port))
    client.start()
    try:
        assert wait_until(lambda: client.start_requests >= 3, EVENT_TIMEOUT)
        with NetFtEmulator(CountingSource(), port=port, rate_hz=500):
            assert client.wait_for_samples(5, timeout=EVENT_TIMEOUT)
    finally:
        client.close()


def test_poll_from_the_callers_own_thread_without_a_background_thread():
    with NetFtEmulator(CountingSource(), rate_hz=500) as emulator:
        host, port = emulator.address
        with NetFtClient(NetFtConfig(host=host, port=port)) as client:
            samples = []
            for _ in range(200):
                samples += client.poll(timeout=0.01)
                if len(samples) >= 10:
                    break
    assert len(samples) >= 10
    assert client.latest() is samples[-1]
    assert [s.rdt_sequence for s in samples] == list(range(samples[0].rdt_sequence,
                                                         samples[0].rdt_sequence + len(samples)))


def test_a_start_request_nothing_answers_is_sent_again():
    """UDP may lose the request, and a kernel may withhold the refusal: a box that missed the
    first request gets another SILENT_RETRY_S later, and none once it streams."""
    import socket
    import time
    box = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    box.bind(('127.0.0.1', 0))
    box.settimeout(EVENT_TIMEOUT)
    client = NetFtClient(NetFtConfig(host='127.0.0.1', port=box.getsockname()[1]))
    client.start()
    try:
        first, peer = box.recvfrom(64)
        asked = time.monotonic()
        second, _ = box.recvfrom(64)          # the first went unanswered
        assert time.monotonic() - asked >= 0.8 * SILENT_RETRY_S
        assert decode_request(first) == decode_request(second) == (CMD_START_REALTIME, 0)
        box.sendto(bytes(36), peer)           # one record (all zero) answers the request
        assert wait_until(lambda: client.diagnostics.received >= 1, EVENT_TIMEOUT)
        sent = client.start_requests
        time.sleep(3 * SILENT_RETRY_S)
        assert client.start_requests == sent
    finally:
        client.close()
        box.close()
