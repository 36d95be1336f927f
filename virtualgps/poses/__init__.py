"""Poses: where the antenna is. Pose records and tracks (:mod:`.pose`), pose logs (:mod:`.logs`),
ROS bags (:mod:`.rosbag`) and live pose sources (:mod:`.posesource`). Imports
:mod:`virtualgps.device` (NMEA logs as pose logs) and the base modules only.
"""
