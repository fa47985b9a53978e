"""The paper's experiments end to end on the simulated hand (the `reproduce` tool) and the
magnetic skin's sensitivity study (`skin_sensitivity`). The runtime never imports this package.

Stages (calibration_stages.py, estimation_stages.py, loop_stages.py; settings.py says what a run
computes, workers.py runs its units in a pool), each cached by a hash of its inputs (cache.py):
calibration sessions (calibration_data.py) -> leave-one-plate-out benchmark and final models ->
online test on the held-out spherical plate -> closed-loop runs (closed_loop.py) -> the same
session and run through the ROS node graph (node_path.py) -> report (report.py, plots.py) with
the paper's numbers (paper_reference.py) side by side.
"""
