"""ament_python package tacforce_ros; executables go to lib/tacforce_ros (setup.cfg), where
ros2 run and ros2 launch look for them."""
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = 'tacforce_ros'
HERE = Path(__file__).parent

# Installed executables: ROS nodes first, then offline tools (all take --help).
NODES = ['xela_driver', 'ft_bridge', 'allegro_driver', 'force_controller', 'estimator',
         'sync_recorder', 'coverage_view', 'command_player', 'sim_world', 'tacforce_container',
         'grasp_controller', 'grasp_client']
# Offline tools of the runtime (tacforce_ros/tools/): executable -> module.
TOOLS = {
    'train': 'tools.train',                 # bags/datasets -> model files + report
    'sim_record': 'tools.sim_record',       # simulated calibration sessions -> rosbag2 (mcap)
    'campaign': 'tools.campaign',           # whole-hand campaign: plan, verdicts, resume
    'bag_repair': 'tools.bag_repair',       # bags cut off by a crash -> whole bags
    'session': 'tools.session',             # a session's processes without ros2 launch
    'learning_curve': 'tools.learning_curve',   # held-out error against labelled seconds
    # The main job and its study (tacforce_ros/experiments/): the runtime never imports them.
    'reproduce': 'experiments.reproduce',   # the paper's experiments in simulation + report
    'skin_sensitivity': 'experiments.skin_sensitivity',  # Table I per skin estimate +/-
    'compare_reports': 'experiments.compare_reports',    # two main-job reports, figure by figure
    # Benchmarks (tacforce_ros/benchmarks/): the runtime never imports them.
    'bench': 'benchmarks.bench',            # accuracy vs inference time of M1-M5, M3-lambda
    'bench_devices': 'benchmarks.bench_devices',    # driver latency and rates over loopback
    'bench_sim': 'benchmarks.bench_sim',    # simulator speed per scene and per effect
    'bench_ros': 'benchmarks.bench_ros',    # tactile->wrench latency, rates, jitter
    'bench_graph': 'benchmarks.bench_graph',    # node graph vs direct path, fault runs
    'bench_messages': 'benchmarks.bench_messages',  # the serialized fast path's saving
    'bench_stop': 'benchmarks.bench_stop',  # every node and `session` stopped at random moments
    'bench_train': 'benchmarks.bench_train',    # CV folds one at a time vs together
}


def data_files():
    files = [
        ('share/ament_index/resource_index/packages', [f'resource/{PACKAGE}']),
        (f'share/{PACKAGE}', ['package.xml']),
    ]
    for folder in ('launch', 'config'):
        for path in sorted((HERE / folder).rglob('*')):
            if path.is_file():
                rel = path.relative_to(HERE)
                files.append((f'share/{PACKAGE}/{rel.parent}', [str(rel)]))
    return files


setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=data_files(),
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='tacforce_ros maintainers',
    maintainer_email='maintainers@tacforce.dev',
    description='Tactile force estimation and fingertip force control for XELA uSkin on Allegro.',
    license='Apache-2.0',
    entry_points={
        # Nodes start through nodes/entry.py: a prompt stop while loading, a prompt end after.
        'console_scripts': [f'{n} = {PACKAGE}.nodes.entry:{n}' for n in NODES]
        + [f'{exe} = {PACKAGE}.{mod}:main' for exe, mod in TOOLS.items()],
    },
)
