"""Real ROS 2 between processes: the whole-hand tactile message crosses DDS intact."""
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from rclpy.qos import qos_profile_sensor_data

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import PYTHON, start, stop, unique_domain_id  # noqa: E402

N_ARRAYS = 18
TAXELS = [30] * 4 + [16] * 11 + [24] * 3

PUBLISHER = textwrap.dedent('''
    import sys, time
    import rclpy
    from rclpy.qos import qos_profile_sensor_data
    from tacforce_msgs.msg import TactileArray, TactileHand
    taxels = [int(n) for n in sys.argv[1].split(',')]
    rclpy.init()
    node = rclpy.create_node('smoke_publisher')
    pub = node.create_publisher(TactileHand, '/tactile/raw', qos_profile_sensor_data)
    for seq in range(400):                        # bounded: at most 4 s at 100 Hz
        msg = TactileHand()
        msg.header.stamp = node.get_clock().now().to_msg()
        msg.header.frame_id = 'hand_root'
        msg.server_sequence = seq
        msg.server_time = 1700000000.0 + seq / 100.0
        for i, n in enumerate(taxels):
            arr = TactileArray(name=f'array_{i}')
            arr.header.frame_id = f'uskin_array_{i}'
            arr.x = [(32768 + i * 100 + k) % 65536 for k in range(n)]
            arr.y = [32768] * n
            arr.z = [65535 - k for k in range(n)]
            arr.temperature = [300.0 + i] * n
            msg.arrays.append(arr)
        pub.publish(msg)
        time.sleep(0.01)
    node.destroy_node()
    rclpy.shutdown()
''')


@pytest.mark.ros
def test_whole_hand_message_crosses_processes(tmp_path):
    domain = unique_domain_id()
    script = tmp_path / 'publisher.py'
    script.write_text(PUBLISHER)
    rclpy.init(domain_id=domain)
    node = rclpy.create_node('smoke_subscriber')
    from tacforce_msgs.msg import TactileHand
    received = []
    node.create_subscription(TactileHand, '/tactile/raw', received.append, qos_profile_sensor_data)
    proc = start([PYTHON, script, ','.join(map(str, TAXELS))], domain)
    try:
        deadline = time.monotonic() + 60.0
        while len(received) < 20 and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
    finally:
        output = stop(proc)
        node.destroy_node()
        rclpy.shutdown()
    assert len(received) >= 20, f'only {len(received)} frames arrived; publisher said:\n{output}'
    msg = received[-1]
    assert len(msg.arrays) == N_ARRAYS
    assert [len(a.x) for a in msg.arrays] == TAXELS
    assert sum(len(a.z) for a in msg.arrays) == 368
    last = msg.arrays[17]
    assert last.name == 'array_17' and last.header.frame_id == 'uskin_array_17'
    np.testing.assert_array_equal(np.asarray(last.x), (32768 + 1700 + np.arange(24)) % 65536)
    np.testing.assert_array_equal(np.asarray(last.z), 65535 - np.arange(24))
    assert list(last.temperature) == [317.0] * 24
    seqs = [m.server_sequence for m in received]
    assert seqs == sorted(seqs)
