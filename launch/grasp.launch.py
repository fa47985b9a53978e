"""ros2 launch tacforce_ros grasp.launch.py [sim:=true|false] [object:=golf_ball] [grip:=1.0]
[hold_time:=0.0] [model:=...] [hand_side:=right] [scene:=...] [out:=bags]
[real_time_factor:=1.0] [lockstep:=true] [sim_duration:=0.0] [seed:=-1] [compose:=false]
[namespace:=] [frame_prefix:=] [autostart:=true] [xela_port:=5000] [netft_port:=49152]
[can_port:=29536]

The thumb and the index fingertip hold an object at a grip force (grasp_controller's Grasp
action). In simulation grasp_client sends the scene's goal once the estimator has tared; on the
hardware, send your own goals to /grasp_controller/grasp. The node graph is
tacforce_ros.bringup.session_plan's, shared with `session grasp`."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from session_launch import session_launch_description  # noqa: E402


def generate_launch_description():
    return session_launch_description('grasp')
