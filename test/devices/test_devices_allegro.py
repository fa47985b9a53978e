"""Allegro V4 over CAN: frame codec, and the driver through python-can's socketcand interface to
the emulated hand (in-process and in a subprocess)."""
import json
import subprocess
import sys
import time

import can
import numpy as np
import pytest
from devices_support import EVENT_TIMEOUT, wait_until
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from tacforce_ros.devices.allegro import AllegroConfig, AllegroV4Driver
from tacforce_ros.devices.allegro_codec import (CMD_FINGER_POSE, CMD_HAND_INFO, CMD_SERIAL,
                                                CMD_SET_PERIOD, CMD_SET_TORQUE, CMD_SYSTEM_OFF,
                                                CMD_SYSTEM_ON, PWM_PER_NM_8V, RAD_PER_COUNT,
                                                AllegroError, HandInfo, decode_int16x4,
                                                encode_period, encode_torque, torque_to_pwm,
                                                wire_id)
from tacforce_ros.rig import TORQUE_LIMITS
from tacforce_ros.sim.emulators.allegro import AllegroEmulator

POSE = np.linspace(-0.4, 1.5, 16)


def socketcand_config(address, **overrides):
    host, port = address
    return AllegroConfig(interface='socketcand', channel='can0',
                         bus_kwargs={'host': host, 'port': port, 'tcp_tune': True},
                         rtr_requests=False, **overrides)


@pytest.fixture
def hand():
    torques = []
    with AllegroEmulator(lambda: POSE, torques.append) as emulator:
        emulator.torque_log = torques
        yield emulator


@given(hnp.arrays(np.float64, 16, elements=st.floats(-2.5, 2.5)))
def test_pose_counts_round_trip_within_half_a_count(q):
    counts = np.rint(q / RAD_PER_COUNT).astype(np.int16)
    decoded = decode_int16x4(encode_torque(counts[:4])).astype(np.float64) * RAD_PER_COUNT
    np.testing.assert_allclose(decoded, q[:4], atol=RAD_PER_COUNT / 2 + 1e-12)


@given(hnp.arrays(np.float64, 16, elements=st.floats(-50, 50)))
def test_pwm_is_the_nearest_int16_of_tau_times_1200(tau):
    pwm = torque_to_pwm(tau).astype(np.int64)
    exact = np.clip(tau * 1200, -32768, 32767)
    assert np.all(np.abs(pwm - exact) <= 0.5 + 1e-9)


def test_wire_ids_follow_command_shift_device():
    assert wire_id(CMD_SYSTEM_ON) == 0x100 and wire_id(CMD_SYSTEM_OFF) == 0x104
    assert wire_id(CMD_HAND_INFO) == 0x200 and wire_id(CMD_SERIAL) == 0x220
    assert wire_id(CMD_SET_PERIOD) == 0x204
    assert [wire_id(CMD_SET_TORQUE + f) for f in range(4)] == [0x180, 0x184, 0x188, 0x18C]
    assert [wire_id(CMD_FINGER_POSE + f) for f in range(4)] == [0x080, 0x084, 0x088, 0x08C]


def test_torque_and_period_payloads_are_little_endian():
    assert torque_to_pwm(0.35) == 420
    assert torque_to_pwm(0.35, PWM_PER_NM_8V) == 280
    assert torque_to_pwm([100.0, -100.0]).tolist() == [32767, -32768]
    assert encode_torque(torque_to_pwm([0.35, -0.35, 0.0, 1.0])).hex(' ') == \
        'a4 01 5c fe 00 00 b0 04'
    assert encode_period(3).hex(' ') == '03 00 00 00 00 00'


def test_pose_and_hand_info_decode_hand_built_bytes():
    counts = decode_int16x4(bytes.fromhex('e803 18fc 0000 ff7f'))
    assert counts.tolist() == [1000, -1000, 0, 32767]
    assert counts[0] * RAD_PER_COUNT == pytest.approx(np.deg2rad(1000 * 333.3 / 65536))
    info = HandInfo.decode(bytes.fromhex('0004 1001 01 1e 05'))
    assert info == HandInfo(0x0400, 0x0110, 'left', 30, True, False, True)
    assert info.is_v4 and HandInfo.decode(info.encode()) == info


def test_start_up_and_torque_frames_on_the_wire(hand):
    host, port = hand.address
    sniffer = can.Bus(interface='socketcand', channel='can0', host=host, port=port)
    try:
        time.sleep(0.6)     # the sniffer joins the bus after the server's grace time
        with AllegroV4Driver(socketcand_config(hand.address)) as driver:
            assert driver.serial == 'SAH040X1' and driver.hand_info.is_v4
            pwm = driver.set_torques(np.full(16, 0.35))
        frames = []
        while (message := sniffer.recv(0.2)) is not None:
            frames.append(message)
    finally:
        sniffer.shutdown()
    wire = [(m.arbitration_id, bytes(m.data).hex()) for m in frames
            if m.arbitration_id & ~0x3 not in (0x080, 0x084, 0x088, 0x08C)]
    replies = [(0x200, hand.hand_info.encode().hex()), (0x220, b'SAH040X1'.hex())]
    assert [f for f in wire if f in replies] == replies
    host_frames = [f for f in wire if f not in replies]
    torque_frames = [f for f in host_frames if 0x180 <= f[0] <= 0x18C]
    assert host_frames[:5] == [(0x104, ''), (0x200, ''), (0x220, ''), (0x204, '030000000000'),
                               (0x100, '')]
    # 0.35 Nm is above the firmware clamp of joints 0 and 3: the host clamps them first.
    assert torque_frames[0] == (0x180, encode_torque([375, 420, 420, 285]).hex())
    assert pwm[:4].tolist() == [375, 420, 420, 285]
    zero_torques = [(0x180 + 4 * f, '0000000000000000') for f in range(4)]
    assert torque_frames[4:] == zero_torques
    assert host_frames[-6:] == [(0x204, '000000000000')] + zero_torques + [(0x104, '')]


def test_pose_stream_torques_and_safe_close(hand):
    with AllegroV4Driver(socketcand_config(hand.address)) as driver:
        driver.start()
        assert driver.wait_for_samples(50, timeout=EVENT_TIMEOUT)
        np.testing.assert_allclose(driver.latest().positions, POSE, atol=RAD_PER_COUNT / 2)
        assert hand.servo_on and hand.period_ms == 3
        driver.set_torques(np.full(16, 10.0))
        assert wait_until(lambda: np.allclose(hand.torques, TORQUE_LIMITS), EVENT_TIMEOUT)
        diag = driver.diagnostics.snapshot()
        assert diag.gaps == diag.malformed == 0
    assert wait_until(lambda: not hand.servo_on and hand.period_ms == 0, EVENT_TIMEOUT)
    assert np.all(hand.torque_log[-1] == 0)


def test_close_makes_the_hand_safe_while_it_still_reads_the_link(hand):
    """Its reader stopped first, the hand's pose stream filled the unread socket, and the
    emulator's server cut the driver off before its servo-off went out (once in a fresh clone's
    suite; 2.5 s of unread stream did it by hand)."""
    seen = []
    forward = hand.server.on_frame
    with AllegroV4Driver(socketcand_config(hand.address)) as driver:
        driver.start()
        assert driver.wait_for_samples(5, timeout=EVENT_TIMEOUT)

        def spy(message):
            seen.append((message.arbitration_id, driver._thread.is_alive()))
            forward(message)
        hand.server.on_frame = spy
    assert wait_until(lambda: not hand.servo_on and hand.period_ms == 0, EVENT_TIMEOUT)
    assert (wire_id(CMD_SYSTEM_OFF), True) in seen


def test_wrong_dlc_and_unknown_ids_are_counted_and_the_stream_continues(hand):
    with AllegroV4Driver(socketcand_config(hand.address)) as driver:
        driver.start()
        assert driver.wait_for_samples(5, timeout=EVENT_TIMEOUT)
        hand.inject(wire_id(CMD_FINGER_POSE + 1), bytes(6))
        assert wait_until(lambda: driver.diagnostics.malformed == 1, EVENT_TIMEOUT)
        assert 'FINGER_POSE 1 with DLC 6' in driver.diagnostics.last_error
        hand.inject(0x3FC, bytes(2))
        assert wait_until(lambda: 'unexpected CAN id 0x3fc' in driver.diagnostics.last_error,
                          EVENT_TIMEOUT)
        assert driver.wait_for_samples(20, timeout=EVENT_TIMEOUT)
        diag = driver.diagnostics.snapshot()
    assert diag.malformed == 1 and diag.dropped == 2 and diag.gaps == 0


def test_a_hand_that_stops_streaming_goes_stale_and_recovers(hand):
    with AllegroV4Driver(socketcand_config(hand.address, stale_after=0.25)) as driver:
        driver.start()
        assert driver.wait_for_samples(5, timeout=EVENT_TIMEOUT)
        assert not driver.is_stale()
        hand.pause_stream()
        assert wait_until(driver.is_stale, EVENT_TIMEOUT)
        age = driver.diagnostics.age()
        time.sleep(0.05)
        assert driver.diagnostics.age() > age
        hand.pause_stream(False)
        assert driver.wait_for_samples(5, timeout=EVENT_TIMEOUT) and not driver.is_stale()


def test_a_fatal_error_in_the_driver_thread_makes_the_hand_safe(hand):
    with AllegroV4Driver(socketcand_config(hand.address)) as driver:
        driver.set_torques(np.full(16, 0.1))
        assert wait_until(lambda: hand.torques[0] == pytest.approx(0.1), EVENT_TIMEOUT)

        def broken_consumer(sample):
            raise RuntimeError('controller crashed')
        driver.add_callback(broken_consumer)
        driver.start()
        assert wait_until(lambda: driver.fatal_error is not None, EVENT_TIMEOUT)
        assert wait_until(lambda: not hand.servo_on, EVENT_TIMEOUT)
        assert np.all(hand.torques == 0)
        assert 'controller crashed' in driver.diagnostics.last_error


def test_silent_hand_is_refused_and_left_safe_with_rtr_requests():
    with can.Bus(interface='virtual', channel='allegro_silent') as listener:
        config = AllegroConfig(interface='virtual', channel='allegro_silent', bus_kwargs={},
                               rtr_requests=True, reply_timeout=0.1)
        with pytest.raises(AllegroError, match='HAND_INFO and SERIAL within 0.1 s'):
            AllegroV4Driver(config)
        sent = []
        while (message := listener.recv(0.1)) is not None:
            sent.append((message.arbitration_id, message.is_remote_frame, bytes(message.data)))
    assert sent[:3] == [(0x104, False, b''), (0x200, True, b''), (0x220, True, b'')]
    assert sent[3] == (0x204, False, bytes(6))
    assert sent[4:8] == [(0x180 + 4 * f, False, bytes(8)) for f in range(4)]
    assert sent[8:] == [(0x104, False, b'')]


def test_driver_reaches_a_hand_in_another_process():
    pose = np.round(np.linspace(0.1, 1.2, 16), 3)
    process = subprocess.Popen(
        [sys.executable, '-m', 'tacforce_ros.sim.emulators.allegro', '--duration', '20',
         '--pose', *map(str, pose)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        port = json.loads(process.stdout.readline())['port']
        with AllegroV4Driver(socketcand_config(('127.0.0.1', port))) as driver:
            driver.start()
            assert driver.wait_for_samples(100, timeout=EVENT_TIMEOUT)
            np.testing.assert_allclose(driver.latest().positions, pose, atol=RAD_PER_COUNT)
            driver.set_torques(np.full(16, 0.2))
            time.sleep(0.1)
        process.stdin.close()
        summary = json.loads(process.stdout.readline())
    finally:
        process.kill() if process.poll() is None else None
        process.wait(timeout=5)
    assert summary['servo_on'] is False and summary['period_ms'] == 0
    np.testing.assert_allclose(summary['max_torques'], np.minimum(0.2, TORQUE_LIMITS),
                               atol=1 / 1200)
    assert summary['last_torques'] == [0.0] * 16 and summary['malformed'] == 0
