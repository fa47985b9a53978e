"""ros2 launch tacforce_ros two_hands_sim.launch.py

Two simulated hands in one ROS graph, each a closed-loop session of closed_loop.launch.py in its
own namespace, /left and /right, with its own simulator, device ports and /clock
(/left/clock, /right/clock): /left/tactile/<array>/wrench and /right/tactile/<array>/wrench side
by side. Both hands use the right-hand description (config/hand has no left hand yet).
test/integration/test_integration_namespaces.py runs the same two plans without launch."""
from pathlib import Path

from launch import LaunchDescription
from launch.actions import GroupAction, IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource

# Device ports of each simulated hand (the right hand on the hardware defaults).
HANDS = {'/right': ('5000', '49152', '29536'), '/left': ('5010', '49162', '29546')}


def generate_launch_description():
    closed_loop = str(Path(__file__).resolve().parent / 'closed_loop.launch.py')
    # Scoped: each hand's launch arguments stay its own.
    return LaunchDescription([
        GroupAction(scoped=True, actions=[IncludeLaunchDescription(
            PythonLaunchDescriptionSource(closed_loop),
            launch_arguments={'namespace': ns, 'xela_port': xela, 'netft_port': netft,
                              'can_port': can, 'out': f'bags{ns}'}.items())])
        for ns, (xela, netft, can) in HANDS.items()])
