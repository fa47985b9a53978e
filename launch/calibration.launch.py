"""ros2 launch tacforce_ros calibration.launch.py [sim:=true|false] [hand_side:=right|left]
[array:=index_tip] [plate:=spherical] [scene:=...] [out:=bags] [real_time_factor:=1.0]
[lockstep:=true] [sim_duration:=0.0] [seed:=-1] [compose:=false] [namespace:=] [frame_prefix:=]
[autostart:=true] [xela_port:=5000] [netft_port:=49152] [can_port:=29536] [campaign:=FOLDER]

campaign:=FOLDER records the next session the campaign has due (its array and plate, into FOLDER).

The node graph is tacforce_ros.bringup.session_plan's, shared with `session calibration`."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from session_launch import session_launch_description  # noqa: E402


def generate_launch_description():
    return session_launch_description('calibration')
