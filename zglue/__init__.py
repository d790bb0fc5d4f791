"""The Zenoh glue every vsfleet process shares (installed as ``vsfleet.zglue``).

- ``zconf``: zenoh's flags layered into a Config, QoS, sessions that say what went wrong;
- ``lifecycle``: stop on SIGTERM/SIGINT, counted rejections, pacing on a clock;
- ``peers``: the mission a running fleet holds, asked of the operator and the agents;
- ``scenario_file``: scenario TOML files from disk;
- ``program``: the start-up every program shares (flags, logging, exit codes).
- ``forks``: a fork server that starts many processes of one program, imported once.

Programs (agent, simfleet, tracker) and operator tools (fleetctl) import this package;
it imports only the pure core ``vsfleet`` (and zenoh), never a program or a tool.
"""
