"""SegGrasp: zero-shot task-oriented grasping via semantic and geometric guided segmentation.

The method lives here (meshes, rendering, detectors, voting, decomposition, fusion, grasps, metrics) together with
the robot-cell interface that the simulated (`sim`) and real (`hardware`) backends implement. This package never
imports PyBullet or hardware drivers.
"""

__version__ = "0.1.0"
