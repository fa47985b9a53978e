"""Frames split across TCP reads reach the Allegro driver whole: python-can's socketcand client
buffers the partial frame ("Got incomplete message => waiting for more data", logged at
WARNING), so the driver silences exactly that message. Shown with a relay on 127.0.0.1 that
passes the emulated hand's bytes on in odd-sized pieces, and poses that number their cycle."""
import itertools

import numpy as np
from devices_support import Relay, wait_until

from tacforce_ros.devices import socketcand_link
from tacforce_ros.devices.allegro import AllegroConfig, AllegroV4Driver
from tacforce_ros.devices.allegro_codec import RAD_PER_COUNT
from tacforce_ros.sim.emulators.allegro import AllegroEmulator

PIECE = 29          # bytes; a socketcand frame line is ~40, so most reads end mid-frame
PAUSE_S = 0.0003    # between pieces: each one leaves as its own TCP segment


def test_frames_split_across_reads_are_delivered_complete_and_in_order():
    cycle = itertools.count()
    # Each FINGER_POSE cycle reports all 16 joints at `cycle` encoder counts.
    with AllegroEmulator(lambda: np.full(16, next(cycle) * RAD_PER_COUNT),
                         lambda tau: None) as hand:
        relay = Relay(hand.address, piece=PIECE, pause=PAUSE_S)
        suppressed_before = socketcand_link.SOCKETCAND_LOG.suppressed
        try:
            host, port = relay.address
            config = AllegroConfig(interface='socketcand', channel='can0', rtr_requests=False,
                                   bus_kwargs={'host': host, 'port': port, 'tcp_tune': True})
            with AllegroV4Driver(config) as driver:
                samples = []
                driver.add_callback(samples.append)
                driver.start()
                assert driver.wait_for_samples(300, timeout=20.0)
                hand.pause_stream()
                # Drained once no new cycle arrives for a while.
                counts = [-1]
                assert wait_until(lambda: counts.append(len(samples)) or counts[-1] == counts[-2],
                                  timeout=10.0, period=0.2)
                diagnostics = driver.diagnostics.snapshot()
        finally:
            relay.close()
    cycles = np.array([s.counts for s in samples], dtype=np.int64)
    assert np.all(cycles == cycles[:, :1]), 'a cycle mixed frames of different cycles'
    numbers = cycles[:, 0]
    assert np.array_equal(numbers, np.arange(numbers[0], numbers[0] + len(numbers))), \
        'a cycle was lost or reordered'
    assert diagnostics.gaps == diagnostics.malformed == 0
    # The relay did split frames across reads: python-can said so, and the filter hid it.
    assert socketcand_link.SOCKETCAND_LOG.suppressed > suppressed_before
