"""The compiled core's interface constants, read from vsfleet._core: the one place Python gets them.

The core defines them once, in its headers (vsfleet/_core/*.h), and exports them (module.c). Every
other Python module, the numpy reference and the tests import them from here and never write the
numbers again (tests/test_coreconst.py checks both).
"""

from __future__ import annotations

from . import _core

# advance goal kinds (vs_advance.h VS_GOAL_*)
GOAL_POSE: int = _core.GOAL_POSE
GOAL_PATH: int = _core.GOAL_PATH
GOAL_TWIST: int = _core.GOAL_TWIST
GOAL_PLAN: int = _core.GOAL_PLAN

#: the advance's alignment throttle (vs_advance.h VS_ALIGN_*): per robot max(ALIGN_FLOOR, |cos d|**power), the
#: power ALIGN_POWER_PLAN following a room's plan (GOAL_PLAN), ALIGN_POWER on every other goal
ALIGN_FLOOR: float = _core.ALIGN_FLOOR
ALIGN_POWER: int = _core.ALIGN_POWER
ALIGN_POWER_PLAN: int = _core.ALIGN_POWER_PLAN

#: vsfleet.advance.StructureLimits' fields in vs_limits' order (vs_advance.h): the core takes them so
LIMIT_FIELDS: tuple[str, ...] = _core.LIMIT_FIELDS

#: the fit's metrics by code (vs_fit.h VS_METRIC_*): METRICS[code] is its name
METRICS: tuple[str, ...] = _core.METRICS
METRIC_CODES: dict[str, int] = {name: code for code, name in enumerate(METRICS)}

#: the failure rule's modes (a mission's on_failure) by code (vs_failure.h VS_FAILURE_HOLD / _DROP / _REJOIN)
FAILURE_MODES: tuple[str, ...] = _core.FAILURE_MODES
#: the failure rule's decisions by code (vs_failure.h VS_DECISION_*): vsfleet.wire's EVENT_KINDS begin with them
DECISION_KINDS: tuple[str, ...] = _core.DECISION_KINDS
#: the motion window's integer nanometres per metre (vs_failure.h VS_FAILURE_NM_PER_M)
FAILURE_NM_PER_M: float = _core.FAILURE_NM_PER_M
#: the progress test judges once the window's oldest item is this share of fail_after_s old
FAILURE_SETTLED_RATIO: float = _core.FAILURE_SETTLED_RATIO

#: commands Precision keeps besides the last one sent (vs_control.h VS_PRECISION_HISTORY)
PRECISION_HISTORY: int = _core.PRECISION_HISTORY
#: vsfleet.control.Precision's and Tracking's gains in vs_precision_gains' / vs_tracking_gains' order
PRECISION_GAIN_FIELDS: tuple[str, ...] = _core.PRECISION_GAIN_FIELDS
TRACKING_GAIN_FIELDS: tuple[str, ...] = _core.TRACKING_GAIN_FIELDS

# the room's navigation function (vs_field.h VS_FIELD_*): a state's cost word, the comfort band [m], the cell's
# growth, the edge weights and the search for a free state around a pose
FIELD_WALL: int = _core.FIELD_WALL
FIELD_BLOCKED_BIT: int = _core.FIELD_BLOCKED_BIT
FIELD_TIGHT_BIT: int = _core.FIELD_TIGHT_BIT
FIELD_COST_MASK: int = _core.FIELD_COST_MASK
#: a deferred build's blocked state whose component is not resolved yet (its cost bits; vs_field_build_deferred)
FIELD_UNRESOLVED: int = _core.FIELD_UNRESOLVED
FIELD_COMFORT_M: float = _core.FIELD_COMFORT_M
FIELD_GROW: float = _core.FIELD_GROW
FIELD_W_AXIS: int = _core.FIELD_W_AXIS
FIELD_W_DIAG: int = _core.FIELD_W_DIAG
FIELD_SEARCH_CELLS: int = _core.FIELD_SEARCH_CELLS
#: the field's descent handed to the advance each frame [m], and its waypoints at most (vs_step.h)
STEP_PATH_M: float = _core.STEP_PATH_M
STEP_PATH_CAP: int = _core.STEP_PATH_CAP
#: following a field, the carrot runs at least this times the shape's reach ahead (vs_step.h)
STEP_LOOKAHEAD_PER_REACH: float = _core.STEP_LOOKAHEAD_PER_REACH
STEP_HELD_BACK: float = _core.STEP_HELD_BACK   # vs_step.h: the barrier keeps less of the move: the short carrot
#: the structure's clearance barrier in a room (vs_clear.h): the clearance its points keep [m], the band [m] in
#: which a point gets a row, the barrier's rate [1/s], the rows kept at most
CLEAR_M: float = _core.CLEAR_M
CLEAR_BAND_M: float = _core.CLEAR_BAND_M
CLEAR_GAMMA_PER_S: float = _core.CLEAR_GAMMA_PER_S
CLEAR_ROWS: int = _core.CLEAR_ROWS
#: the assembly tie-break (vs_assembly.h): a seen robot farther than ASSEMBLING_M [m] from its point is on its way
#: to it; a detour's waypoint lies DETOUR_CLEAR_M [m] beyond touching + margin beside the blocker, as far short of it
ASSEMBLING_M: float = _core.ASSEMBLING_M
DETOUR_CLEAR_M: float = _core.DETOUR_CLEAR_M
#: a boxed-in robot heads ESCAPE_M [m] back from its blocker, or out of the crowd, or off back; a placed robot that bars
#: a boxed-in robot's way round its blocker steps ESCAPE_M aside (vs_assembly.h)
ESCAPE_M: float = _core.ESCAPE_M
#: which of two robots comes first is drawn afresh every PRIORITY_S [s] of the mission (vs_assembly.h)
PRIORITY_S: float = _core.PRIORITY_S
#: ... when pressed against its blocker: its centre's distance from the blocker's less than PRESSED_M [m] beyond
#: touching + margin
PRESSED_M: float = _core.PRESSED_M

# the fit (vs_fit.h, vs_fit_l1.h, vs_fit_linf.h): the certified gap, the search's rounds, the largest magnitude,
# from which n l1 starts at Newton's rotation, linf's end points per cell
FIT_CERT_TOL: float = _core.FIT_CERT_TOL
FIT_MAX_ROUNDS: int = _core.FIT_MAX_ROUNDS
FIT_MAX_ABS: float = _core.FIT_MAX_ABS
L1_NEWTON_N: int = _core.L1_NEWTON_N
LINF_SPLIT: int = _core.LINF_SPLIT

#: sinc's series below this |x| (vs_kin.h VS_SINC_SERIES_BELOW)
SINC_SERIES_BELOW: float = _core.SINC_SERIES_BELOW
#: the wheel limit's corners whose angles to the command differ by at most this [rad] tie (vs_kin.h VS_CORNER_TIE_RAD)
CORNER_TIE_RAD: float = _core.CORNER_TIE_RAD

# a frame's limits, as the core's decoder checks them (vs_wire.h VS_WIRE_*)
WIRE_MAX_FRAME_BYTES: int = _core.WIRE_MAX_FRAME_BYTES
WIRE_MAX_ROBOTS: int = _core.WIRE_MAX_ROBOTS
#: a frame's src at most this many bytes (vs_wire.h VS_WIRE_MAX_SRC); vsfleet.wire holds every string field to it
WIRE_MAX_SRC: int = _core.WIRE_MAX_SRC
WIRE_MAX_ABS: float = _core.WIRE_MAX_ABS
WIRE_MAX_ABS_T: float = _core.WIRE_MAX_ABS_T
WIRE_PROTOCOL_V: int = _core.WIRE_PROTOCOL_V

# the bindings' argument layouts by name (py_control.c, py_step.c): every controller's ControlInput arguments,
# Precision's state arrays, and structure_step's arguments (the mission's before pose_world and from radius_m
# on, the frame's between)
CONTROL_INPUT_ARGS: tuple[str, ...] = _core.CONTROL_INPUT_ARGS
PRECISION_STATE_ARGS: tuple[str, ...] = _core.PRECISION_STATE_ARGS
STRUCTURE_STEP_ARGS: tuple[str, ...] = _core.STRUCTURE_STEP_ARGS

AGENT_CONTROLLERS: tuple[str, ...] = _core.AGENT_CONTROLLERS
AGENT_STALL_S: float = _core.AGENT_STALL_S
AGENT_STALL_MOVE_M: float = _core.AGENT_STALL_MOVE_M
AGENT_STALL_TURN_RAD: float = _core.AGENT_STALL_TURN_RAD
AGENT_SCRATCH_F64_PER_ROBOT: int = _core.AGENT_SCRATCH_F64_PER_ROBOT
AGENT_SCRATCH_U8_PER_ROBOT: int = _core.AGENT_SCRATCH_U8_PER_ROBOT
#: the agent binding's layouts by name (py_agent.c): agent_config's policy, safety and times tuples, the state's
#: arrays and numbers (scalars) agent_step and agent_frame update in place, and agent_step's answer
AGENT_POLICY: tuple[str, ...] = _core.AGENT_POLICY
AGENT_SAFETY: tuple[str, ...] = _core.AGENT_SAFETY
AGENT_TIMES: tuple[str, ...] = _core.AGENT_TIMES
AGENT_STATE: tuple[str, ...] = _core.AGENT_STATE
AGENT_SCALARS: tuple[str, ...] = _core.AGENT_SCALARS
AGENT_RESULT: tuple[str, ...] = _core.AGENT_RESULT
