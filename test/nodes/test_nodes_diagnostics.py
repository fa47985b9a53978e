"""Each driver's link health on /diagnostics, as rqt_robot_monitor reads it: a real driver
process against its emulator on loopback goes OK while the device streams, ERROR when the
device is gone (the XELA server and the Net F/T box stop, the hand falls silent), and OK again
when it returns; the counters carry on across the outage."""
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

from tacforce_ros.hand.description import load_hand
from tacforce_ros.nodes.qos import subscriber_qos
from tacforce_ros.bringup.session_plan import params_file
from tacforce_ros.sim.emulators.allegro import AllegroEmulator
from tacforce_ros.sim.emulators.netft import NetFtEmulator
from tacforce_ros.sim.emulators.xela_server import XelaServerEmulator
from tacforce_ros.topics import TOPIC_DIAGNOSTICS

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import (OutputLines, executable, rclpy_node, spin_until, start,  # noqa: E402
                           unique_domain_id)

pytestmark = pytest.mark.ros
PERIOD_S = 0.2
LEVEL = {DiagnosticStatus.OK: 'OK', DiagnosticStatus.WARN: 'WARN',
         DiagnosticStatus.ERROR: 'ERROR', DiagnosticStatus.STALE: 'STALE'}


class XelaDevice:
    node = 'xela_driver'

    def __enter__(self):
        hand = load_hand()
        counts = np.full((hand.n_taxels, 3), 30000, np.uint16)
        temperatures = np.full(hand.n_taxels, 300.0)
        self.server = XelaServerEmulator(lambda: (counts, temperatures, time.time()))
        return self

    def params(self):
        return [f'url:=ws://127.0.0.1:{self.server.address[1]}', 'reconnect_max:=0.2']

    def go(self):
        self.server.stop()

    def come_back(self):
        self.server.start()

    def __exit__(self, *exc_info):
        self.server.close()


class NetFtDevice:
    node = 'ft_bridge'

    def __enter__(self):
        self.box = NetFtEmulator(lambda: (np.zeros(6, np.int32), 0))
        self.port = self.box.address[1]
        return self

    def params(self):
        return ['host:=127.0.0.1', f'port:={self.port}', 'restart_after:=0.3']

    def go(self):
        self.box.close()

    def come_back(self):       # the box back on its address (it reboots and streams when asked)
        self.box = NetFtEmulator(lambda: (np.zeros(6, np.int32), 0), port=self.port)

    def __exit__(self, *exc_info):
        self.box.close()


class AllegroDevice:
    node = 'allegro_driver'

    def __enter__(self):
        self.hand = AllegroEmulator(lambda: np.linspace(0.0, 0.6, 16), lambda tau: None)
        return self

    def params(self):
        host, port = self.hand.address
        return ['interface:=socketcand', 'channel:=can0', f'host:={host}', f'port:={port}',
                'rtr_requests:=false', 'control:=off', 'silent_warn_after:=0.2',
                'silent_timeout:=1.0']

    def go(self):
        self.hand.pause_stream()

    def come_back(self):
        self.hand.pause_stream(False)

    def __exit__(self, *exc_info):
        self.hand.close()


@pytest.mark.parametrize('device', [XelaDevice, NetFtDevice, AllegroDevice],
                         ids=lambda d: d.node)
def test_a_driver_s_link_goes_ok_error_ok_on_diagnostics(device):
    domain = unique_domain_id(offset=41 + [XelaDevice, NetFtDevice, AllegroDevice].index(device))
    seen: list[tuple[float, DiagnosticStatus]] = []
    with device() as dev, rclpy_node('diagnostics_test', domain) as node:
        name = f'/{dev.node}: device link'
        node.create_subscription(
            DiagnosticArray, TOPIC_DIAGNOSTICS,
            lambda msg: seen.extend((time.monotonic(), s) for s in msg.status if s.name == name),
            subscriber_qos(TOPIC_DIAGNOSTICS))
        params = [*dev.params(), f'diagnostics_period:={PERIOD_S}']
        out = OutputLines(start([executable(dev.node), '--ros-args', '--params-file',
                                 params_file(dev.node), *[a for p in params for a in ('-p', p)]],
                                domain))

        def level_since(level, since):
            return spin_until(node, lambda: any(t >= since and s.level == level
                                                for t, s in seen), 30.0)
        try:
            assert level_since(DiagnosticStatus.OK, 0.0), (seen[-3:], out.text()[-2000:])
            gone = time.monotonic()
            dev.go()
            assert level_since(DiagnosticStatus.ERROR, gone), (seen[-3:], out.text()[-2000:])
            back = time.monotonic()
            dev.come_back()
            assert level_since(DiagnosticStatus.OK, back), (seen[-3:], out.text()[-2000:])
        finally:
            text = out.stop()
    received = [int(next(v.value for v in s.values if v.key == 'received')) for _, s in seen]
    levels = [LEVEL[s.level] for _, s in seen]
    print(f'{dev.node}: levels {levels}')
    assert received == sorted(received), 'a counter went back'
    error = next(s for _, s in seen if s.level == DiagnosticStatus.ERROR)
    assert error.hardware_id and error.message, error
    assert 'link ERROR' in text and 'link OK' in text, text[-2000:]
