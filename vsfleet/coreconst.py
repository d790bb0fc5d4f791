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
