"""ros2 launch tacforce_ros two_hands_sim.launch.py [out:=bags] [array:=index_tip]
[plate:=spherical] [sequence:=] [real_time_factor:=1.0] [lockstep:=true] [sim_duration:=0.0]
[seed:=-1] [compose:=false] [autostart:=true]

Two simulated hands in one ROS graph, each a closed-loop session as closed_loop.launch.py starts
it, in its own namespace with its own simulator, device ports and /clock: the left hand (its
description and models) in /left, the right in /right; /left/tactile/<array>/wrench and
/right/tactile/<array>/wrench side by side, every frame id prefixed left/ or right/ (TF from each
hand's robot_state_publisher too), bags in <out>/left and <out>/right. What is set per hand
(hand_side, namespace, frame_prefix, the ports, model, scene) is refused as an argument.
tacforce_ros.bringup.session_plan.two_hands makes the two sessions, which
test/integration/test_integration_namespaces.py runs without launch."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from session_launch import session_launch_description  # noqa: E402


def generate_launch_description():
    return session_launch_description('two_hands')
