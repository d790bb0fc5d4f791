"""Trackers (installed as ``vsfleet.tracker``): each publishes every robot it sees in a frame as one
message on ``vs/<fleet>/frame/<src>`` (the agents' input), and each robot's pose on
``pose/<robot>`` for tools. ``sim``: the simulated tracker (VGPS: simfleet's truth with noise,
latency and drops); ``camera``: ArUco markers from an overhead camera (or ``render``, its synthetic
camera); ``calibrate``: the floor calibration; ``render``: synthetic camera frames of the fleet."""
