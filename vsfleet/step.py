"""The agent's decision at one frame, as one pure function: ``agent_step``; the one name every caller uses.

``agent_step(state, mission, frame, now_s, config) -> (state, StepOutput)`` is
everything an agent decides per frame: the frame's age (a stale frame is not
run), gaps and resynchronisation, the fit and the advance, its own command and
every robot's predicted command, and the failure rule. The agent process
(agent/main.py), the offline fleet (simfleet.offline), the benches and the
tests drive this same function.

Its parts live in three modules, re-exported here:
- vsfleet.agentstate: the mission packed for the compiled core, the agent's state, the step's configuration and
  outputs (no numpy);
- vsfleet.agentcore: the step as the agent process runs it, one call into the core per frame, over plain buffers
  (no numpy: the agent process never loads it, issue 29);
- vsfleet.glue: the same step in numpy glue around the kernels a StepConfig selects (vsfleet.impl: the core's one
  by one, or the numpy reference), for the reference, a controller the core lacks and offline runs that share
  structures; bit for bit the core's (tests/test_core_agent_step.py).
"""

from __future__ import annotations

from .agentcore import (  # noqa: F401 (re-exported)
    Kernel, PayloadStep, adopt_health, agent_kernel, agent_payload_step, agent_step, command_ttl_s, enter_mission,
    frame_buffers, precision_initial, stop_command)
from .agentstate import (  # noqa: F401 (re-exported)
    FAILURE_FIELDS, PRECISION_STATE_FIELDS, SCALE_COUNT, SCALE_STEP, STALL_MOVE_M, STALL_S, STALL_TURN_RAD,
    AgentState, Controller, CoreMission, Note, StepConfig, StepOutput, SyncPhase, blocked_note, core_mission_of,
    failure_initial, failure_with_health, health_of, mission_controller, mission_goal, mission_policy, mission_scales,
    mission_shape_points, pack_mission, safety_params, shape_name, used_ids)
from .assembly import assembly_targets, assembly_targets_reference  # noqa: F401 (re-exported: the step's names)
from .glue import (  # noqa: F401 (re-exported)
    MissionArrays, core_mission, core_outputs, decide_in_numpy, expected_steps_m, frame_arrays, mission_arrays,
    mission_envelope_arrays, mission_envelopes, mission_shapes, mission_template, numpy_state, planned_way,
    stall_state, structure_step)
from .structure import MISSION_ARGS, PLAN_MARGIN_M, Structure, make_structure, room_field  # noqa: F401 (re-exported)
