"""ament_python package tacforce_ros; executables go to lib/tacforce_ros (setup.cfg) for ros2 run/launch."""
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = 'tacforce_ros'
HERE = Path(__file__).parent

# Installed executables: ROS nodes first, then offline tools (all take --help).
NODES = ['xela_driver', 'ft_bridge', 'allegro_driver', 'force_controller', 'estimator',
         'sync_recorder', 'coverage_view', 'command_player', 'sim_world', 'tacforce_container']
TOOLS = {
    'train': 'train',               # bags/datasets -> model files + report
    'bench': 'bench',               # accuracy vs inference time of M1-M5, M3-lambda
    'bench_devices': 'bench_devices',   # driver latency and sustained rates over loopback
    'bench_sim': 'bench_sim',       # simulator speed per scene and per effect
    'bench_ros': 'bench_ros',       # tactile->wrench latency, input rate, controller jitter
    'bench_graph': 'bench_graph',   # node graph vs direct path: agreement, watchdog trips, rates
    'bench_messages': 'bench_messages',  # what the estimator's serialized fast path saves
    'bench_stop': 'bench_stop',     # every node and `session` stopped at random moments
    'bench_train': 'bench_train',   # cross-validation folds trained one at a time vs together
    'skin_sensitivity': 'skin_sensitivity',  # Table I on the magnetic skin, per estimate +/-
    'sim_record': 'sim_record',     # simulated calibration sessions -> rosbag2 (mcap)
    'campaign': 'campaign',         # whole-hand calibration campaign: plan, verdicts, resume
    'bag_repair': 'bag_repair',     # bags cut off by a crash -> whole bags (complete chunks kept)
    'session': 'session',           # start a calibration or closed-loop session without ros2 launch
    'reproduce': 'reproduce',       # the main job: the paper's experiments in simulation + report
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
        + [f'{exe} = {PACKAGE}.tools.{mod}:main' for exe, mod in TOOLS.items()],
    },
)
