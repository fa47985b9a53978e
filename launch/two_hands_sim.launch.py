"""ros2 launch tacforce_ros two_hands_sim.launch.py

Two simulated hands in one ROS graph, each a closed-loop session of closed_loop.launch.py in its
own namespace with its own simulator, device ports and /clock: the left hand (its description
and models) in /left, the right in /right; /left/tactile/<array>/wrench and
/right/tactile/<array>/wrench side by side, every frame id prefixed left/ or right/ (TF from each
hand's robot_state_publisher too). test/integration/test_integration_namespaces.py runs the same
two plans without launch."""
from pathlib import Path

from launch import LaunchDescription
from launch.actions import GroupAction, IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource

# Device ports of each simulated hand (the right hand on the hardware defaults).
HANDS = {'/right': ('5000', '49152', '29536'), '/left': ('5010', '49162', '29546')}
# Namespace /<side>: that hand's description, frame prefix <side>/.


def generate_launch_description():
    closed_loop = str(Path(__file__).resolve().parent / 'closed_loop.launch.py')
    # Scoped: each hand's launch arguments stay its own.
    return LaunchDescription([
        GroupAction(scoped=True, actions=[IncludeLaunchDescription(
            PythonLaunchDescriptionSource(closed_loop),
            launch_arguments={'namespace': ns, 'hand_side': ns.strip('/'),
                              'frame_prefix': f'{ns.strip("/")}/', 'xela_port': xela,
                              'netft_port': netft, 'can_port': can,
                              'out': f'bags{ns}'}.items())])
        for ns, (xela, netft, can) in HANDS.items()])
