"""Allegro driver faults on loopback socketcand: no server, a server that accepts and never
answers, a link that stops reading (each ends the driver's wait instead of holding it), a server
that closes the link, a hand that goes silent."""
import logging
import socket
import threading
import time

import numpy as np
import pytest
from devices_support import EVENT_TIMEOUT, Relay, wait_until

from tacforce_ros.devices import socketcand_link
from tacforce_ros.devices.allegro import AllegroConfig, AllegroV4Driver
from tacforce_ros.devices.allegro_codec import AllegroError
from tacforce_ros.devices.polling import LinkLost
from tacforce_ros.sim.emulators.allegro import AllegroEmulator

POSE = np.linspace(-0.2, 1.0, 16)


def config(port, host='127.0.0.1', **overrides):
    return AllegroConfig(interface='socketcand', channel='can0',
                         bus_kwargs={'host': host, 'port': port, 'tcp_tune': True},
                         rtr_requests=False, **overrides)


def unused_port() -> int:
    with socket.socket() as probe:
        probe.bind(('127.0.0.1', 0))
        return probe.getsockname()[1]


def test_no_server_is_refused_at_once_without_python_cans_retries(caplog):
    """python-can's client retries a refused connection for 10 s without a pause, so a driver
    asked to stop meanwhile stayed: the server is asked first, and no retry loop runs."""
    port = unused_port()
    with caplog.at_level(logging.WARNING, logger=socketcand_link.SOCKETCAND_LOGGER):
        with pytest.raises(AllegroError, match=f'no socketcand server at 127.0.0.1:{port}'):
            AllegroV4Driver(config(port))
    assert not [r for r in caplog.records if 'Failed to connect' in r.getMessage()]


def test_a_server_that_accepts_and_never_answers_is_refused_not_waited_for():
    """A socketcand server that hangs: python-can waits for its greeting without a timeout."""
    with socket.create_server(('127.0.0.1', 0)) as mute:
        outcome = []

        def open_it():
            try:
                AllegroV4Driver(config(mute.getsockname()[1]))
            except AllegroError as error:
                outcome.append(error)

        opener = threading.Thread(target=open_it, daemon=True)
        opener.start()
        opener.join(EVENT_TIMEOUT)
        assert not opener.is_alive(), 'still waiting for the greeting'
        assert 'did not answer within' in str(outcome[0])


def test_a_link_that_stops_reading_is_lost_once_and_the_driver_closes():
    """The hand's end stops reading (a hung relay): the send that cannot go through is a lost
    link after the socket timeout, every later send fails at once, and close() ends."""
    with AllegroEmulator(lambda: POSE, lambda tau: None) as hand, \
            Relay(hand.address, buffer=4096) as relay:
        driver = AllegroV4Driver(config(relay.address[1], silent_timeout=60.0))
        try:
            socketcand_link.socketcand_socket(driver.bus).setsockopt(socket.SOL_SOCKET,
                                                              socket.SO_SNDBUF, 4096)
            relay.freeze()
            with pytest.raises(LinkLost, match='sending to the hand failed'):
                for _ in range(100_000):          # kilobytes of buffers fill long before
                    driver.set_torques(np.zeros(16))
            started = time.monotonic()
            with pytest.raises(LinkLost):
                driver.set_torques(np.zeros(16))
            assert time.monotonic() - started < socketcand_link.SOCKETCAND_TIMEOUT_S, 'waited again'
        finally:
            closer = threading.Thread(target=driver.close, daemon=True)
            closer.start()
            closer.join(EVENT_TIMEOUT)
            assert not closer.is_alive(), 'close() waits on the hung link'


def test_a_closed_link_stops_the_driver_at_once():
    hand = AllegroEmulator(lambda: POSE, lambda tau: None)
    driver = AllegroV4Driver(config(hand.address[1], silent_timeout=30.0))
    try:
        driver.start()
        assert driver.wait_for_samples(10, timeout=EVENT_TIMEOUT)
        hand.close()
        assert wait_until(lambda: driver.fatal_error is not None, EVENT_TIMEOUT)
        assert isinstance(driver.fatal_error, LinkLost)
        assert 'closed the connection' in str(driver.fatal_error)
        assert wait_until(lambda: not driver._thread.is_alive(), EVENT_TIMEOUT), \
            'polling thread spins on'
    finally:
        driver.close()


def test_a_silent_hand_is_made_safe_and_torques_are_refused():
    with AllegroEmulator(lambda: POSE, lambda tau: None) as hand, \
            AllegroV4Driver(config(hand.address[1], silent_warn_after=0.1,
                                   silent_timeout=0.5)) as driver:
        events = []
        driver.add_event_callback(lambda level, text: events.append((level, text)))
        driver.start()
        assert driver.wait_for_samples(10, timeout=EVENT_TIMEOUT)
        driver.set_torques(np.full(16, 0.1))
        hand.pause_stream()
        started = time.monotonic()
        # Bounds for a host that stalls: silence counts only while the driver runs.
        assert wait_until(lambda: driver.safe_stop, 30.0)
        assert time.monotonic() - started >= 0.5
        assert wait_until(lambda: not hand.servo_on, EVENT_TIMEOUT) and np.all(hand.torques == 0)
        with pytest.raises(AllegroError, match='torque refused: the hand sent no joint data'):
            driver.set_torques(np.zeros(16))
        levels = [level for level, _ in events]
        assert levels[levels.index(logging.WARNING):][:2] == [logging.WARNING, logging.ERROR]


def test_time_the_driver_was_not_run_is_not_the_hands_silence():
    """Nobody polls for 1 s (a host that does not run the driver, and stalls an emulated hand
    with it): the first poll after it finds nothing queued, and that is not yet a silent hand;
    a hand that stays silent is judged once the driver has run a while again."""
    with AllegroEmulator(lambda: POSE, lambda tau: None) as hand, \
            AllegroV4Driver(config(hand.address[1], silent_warn_after=0.1,
                                   silent_timeout=0.5)) as driver:
        events = []
        driver.add_event_callback(lambda level, text: events.append((level, text)))
        assert wait_until(lambda: driver.poll(0.01) and driver.latest() is not None, EVENT_TIMEOUT)
        hand.pause_stream()
        assert wait_until(lambda: not driver.poll(0.01), EVENT_TIMEOUT)    # queue drained
        before = driver.diagnostics.late_polls
        time.sleep(1.0)
        assert driver.poll(0.0) == []
        assert driver.diagnostics.late_polls > before
        assert not driver.safe_stop and not events
        hand.pause_stream(False)
        assert wait_until(lambda: driver.poll(0.01), EVENT_TIMEOUT)
        driver.set_torques(np.full(16, 0.1))
        hand.pause_stream()
        assert wait_until(lambda: driver.poll(0.01) is not None and driver.safe_stop,
                          EVENT_TIMEOUT)
