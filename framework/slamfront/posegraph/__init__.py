"""Pose-graph optimisation: file I/O, the GTSAM solver, reports and the outlier study.

The pure pieces (graph arrays, text formats, alignment) live in :mod:`slamfront.core`;
this package adds files, GTSAM and plots around them, for the ``gtsam_pose_graph``
back end and the ``slamfront optimize`` / ``slamfront outliers`` commands.
"""
