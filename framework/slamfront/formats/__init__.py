"""Readers and writers of the file formats slamfront meets (trajectories, RGB-D lists).

Every reader raises :class:`~slamfront.errors.DataError` naming the file and line.
"""
