"""Operator tools (installed as ``vsfleet.fleetctl``): the ``vsfleet`` command, the router, the
localhost fleet launcher, recording, replay, plots, monitor, Foxglove, fuzzing, deploy configs
and the ROS 2 bridges.

Tools import the pure core ``vsfleet`` and the Zenoh glue ``vsfleet.zglue``; a program
(agent, simfleet, tracker) is started as a child process through ``vsfleet``, never imported.
"""
