"""The node graph's topic names and the QoS kind each is published with: the one place they are
spelled. ROS-free: the bag layout (bagio), the nodes and the tools all read them here.

Names are written as they resolve in the root namespace (and as a bag names its topics); nodes
create their publishers and subscriptions with `relative(name)`, so a graph started in a
namespace (`session --namespace /left`) publishes /left/tactile/raw and two hands share one
graph. /diagnostics stays absolute: every device's health in one place, as diagnostic_updater
publishes it."""
from __future__ import annotations

TOPIC_TACTILE = '/tactile/raw'
TOPIC_WRENCH = '/ft_sensor/wrench'
TOPIC_JOINTS = '/joint_states'
TOPIC_SAMPLE = '/calibration/sample'
TOPIC_SESSION = '/session/metadata'
TOPIC_SIM_CONTACT = '/sim/contact_force'
TOPIC_ESTIMATES = '/tactile/estimates'
TOPIC_MARKERS = '/tactile/markers'
# Closed-loop sessions also carry the command and the controller's ticks.
TOPIC_DESIRED = '/force_controller/desired'
TOPIC_CONTROLLER_STATE = '/force_controller/state'
# Grasp sessions: the grasp controller's ticks (one ControllerState per fingertip, base frame)
# and the simulated object's pose.
TOPIC_GRASP_STATE = '/grasp_controller/state'
TOPIC_SIM_OBJECT = '/sim/object_pose'
# Joint torques for the hand driver (sensor_msgs/JointState: name and effort), from any controller.
TOPIC_TORQUE_COMMAND = '/allegro_driver/torque_command'
# Health of the device links (diagnostic_msgs/DiagnosticArray), where ROS tools look for it.
TOPIC_DIAGNOSTICS = '/diagnostics'

# Sensor streams are published reliable and subscribed best-effort (sensor-data QoS); commands
# and controller states are reliable both ways; the recorder's calibration samples are reliable
# and kept for late joiners (nodes/qos.py builds the profiles).
SENSOR, RELIABLE, KEPT = 'sensor', 'reliable', 'kept'
TOPIC_QOS = {
    TOPIC_TACTILE: SENSOR,
    TOPIC_WRENCH: SENSOR,
    TOPIC_JOINTS: SENSOR,
    TOPIC_ESTIMATES: SENSOR,
    TOPIC_SIM_CONTACT: SENSOR,
    TOPIC_SAMPLE: KEPT,
    TOPIC_DESIRED: RELIABLE,
    TOPIC_CONTROLLER_STATE: RELIABLE,
    TOPIC_GRASP_STATE: RELIABLE,
    TOPIC_SIM_OBJECT: SENSOR,
    TOPIC_TORQUE_COMMAND: RELIABLE,
    TOPIC_DIAGNOSTICS: RELIABLE,
}


# What the graph's publishers offer: keep-last, this deep, reliable, volatile (nodes/qos.py
# builds the rclpy profiles; bagio writes them into a bag's metadata as each recorded topic's
# offered QoS, as `ros2 bag record` does); KEPT topics are transient-local, KEPT_DEPTH deep.
PUBLISHER_DEPTH = 10
# 10 s of samples at the 100 Hz tactile rate: the operator's coverage view starts with the
# session but may match the recorder after its first samples, and must still judge the session
# from its first sample (volatile, a CI host's view judged 1305 of the bag's 1486 samples).
KEPT_DEPTH = 1000


def relative(topic: str) -> str:
    """The name a node uses for `topic`: relative (it resolves in the node's namespace), but for
    the topics that are absolute by convention."""
    return topic if topic in ABSOLUTE else topic.lstrip('/')


ABSOLUTE = frozenset({TOPIC_DIAGNOSTICS})


def array_wrench_topic(array: str) -> str:
    """The estimated wrench of one array (geometry_msgs/WrenchStamped)."""
    return f'/tactile/{array}/wrench'


def qos_kind(topic: str) -> str:
    """SENSOR, RELIABLE or KEPT; a topic nobody decided for is refused, naming this module."""
    if topic.startswith('/tactile/') and topic.endswith('/wrench'):
        return SENSOR       # the per-array wrenches are sensor streams too
    try:
        return TOPIC_QOS[topic]
    except KeyError:
        raise KeyError(f'no QoS decided for {topic}; add it to TOPIC_QOS in '
                       'tacforce_ros/topics.py') from None
