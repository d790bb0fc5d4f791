"""The core's interface constants are defined once, in its C headers, and Python reads them from vsfleet.coreconst.

The values vsfleet._core exports (module.c) are the headers' #defines and struct orders, parsed here from the
headers themselves; and no Python file of vsfleet/ or tests/ writes one of them again where it should import
it (goal kinds, metric codes, decision codes, failure modes, field orders, the failure rule's 0.8 factor, the
motion window's nanometres, Precision's history).
"""

from __future__ import annotations

import ast
import dataclasses
import math
import re
from pathlib import Path

import numpy as np
import pytest

from vsfleet import _core, coreconst
from vsfleet.advance import GoalError, GoalPath, GoalPose, StructureLimits
from vsfleet.control import ControlInput, Precision, PrecisionState, Tracking, _input_args
from vsfleet.envelope import Envelope, Envelopes
from vsfleet.failure import FailurePolicy
from vsfleet.geometry import Pose2
from vsfleet.step import PLAN_MARGIN_M, core_mission
from vsfleet.structure import MISSION_ARGS
from vsfleet.wire import EVENT_KINDS, ON_FAILURE

ROOT = Path(__file__).parent.parent
HEADERS = ROOT / "vsfleet" / "_core"


def defines() -> dict[str, str]:
    """Every ``#define VS_NAME value`` of the core's headers: name -> value text (comments dropped)."""
    out = {}
    for h in sorted(HEADERS.glob("vs*.h")):
        text = re.sub(r"/\*.*?\*/", " ", h.read_text(), flags=re.S)
        out.update(re.findall(r"^[ \t]*#[ \t]*define[ \t]+(VS_\w+)[ \t]+(\S[^\n]*?)[ \t]*$", text, re.M))
    return out


def struct_members(name: str) -> tuple[str, ...]:
    """The member names of ``typedef struct {...} name;`` in the core's headers, in declaration order."""
    for h in sorted(HEADERS.glob("vs*.h")):
        text = re.sub(r"/\*.*?\*/", " ", h.read_text(), flags=re.S)
        m = re.search(r"typedef\s+struct\s*\{([^{}]*)\}\s*" + name + r"\s*;", text)
        if m:
            members = []
            for decl in filter(None, map(str.strip, m.group(1).split(";"))):   # "double a, b" or "int c"
                first, *rest = decl.split(",")
                members += [n.strip().lstrip("*").split("[")[0] for n in (first.split()[-1], *rest)]
            return tuple(members)
    raise AssertionError(f"no struct {name} in {HEADERS}")


DEFINES = defines()


def define_value(name: str):
    """A #define's value as Python reads it: other VS_ names replaced by theirs, C's u suffix dropped."""
    text = re.sub(r"\b(0[xX][0-9A-Fa-f]+|\d+)[uU]\b", r"\1", DEFINES[name])
    text = re.sub(r"\bVS_\w+\b", lambda m: f"({define_value(m.group())!r})", text)
    return eval(text, {"__builtins__": {}})  # noqa: S307 - the core's own headers


NUMBERS = {k: v for k, v in vars(coreconst).items() if k.isupper() and type(v) in (int, float)}


def test_the_codes_python_reads_are_the_headers_defines():
    for kind in ("POSE", "PATH", "TWIST", "PLAN"):
        assert getattr(coreconst, f"GOAL_{kind}") == int(DEFINES[f"VS_GOAL_{kind}"])
    assert {f"VS_METRIC_{m.upper()}": c for m, c in coreconst.METRIC_CODES.items()} == \
        {k: int(v) for k, v in DEFINES.items() if k.startswith("VS_METRIC_")}
    assert {f"VS_DECISION_{k.upper()}": c for c, k in enumerate(coreconst.DECISION_KINDS)} == \
        {k: int(v) for k, v in DEFINES.items() if k.startswith("VS_DECISION_")}
    modes = {f"VS_FAILURE_{m.upper()}": c for c, m in enumerate(coreconst.FAILURE_MODES)}
    assert modes == {k: int(DEFINES[k]) for k in modes} and len(modes) == 3
    assert coreconst.PRECISION_HISTORY == int(DEFINES["VS_PRECISION_HISTORY"])
    assert coreconst.FAILURE_NM_PER_M == float(DEFINES["VS_FAILURE_NM_PER_M"])
    assert coreconst.FAILURE_SETTLED_RATIO == float(DEFINES["VS_FAILURE_SETTLED_RATIO"])


@pytest.mark.parametrize("name", sorted(NUMBERS))
def test_every_number_python_reads_is_its_define(name):
    """coreconst.X is the headers' VS_X, the same type and the same bits."""
    want = define_value(f"VS_{name}")
    assert NUMBERS[name] == want and type(NUMBERS[name]) is type(want), name


def test_the_field_orders_python_reads_are_the_structs_and_name_the_dataclasses_fields():
    for names, struct, cls in ((coreconst.LIMIT_FIELDS, "vs_limits", StructureLimits),
                               (coreconst.PRECISION_GAIN_FIELDS, "vs_precision_gains", Precision),
                               (coreconst.TRACKING_GAIN_FIELDS, "vs_tracking_gains", Tracking)):
        assert names == struct_members(struct), struct
        assert set(names) == {f.name for f in dataclasses.fields(cls)}, cls.__name__


def test_the_python_modules_take_the_cores_constants():
    """The names the modules use are coreconst's own objects (not copies that happen to be equal)."""
    assert coreconst.DECISION_KINDS is _core.DECISION_KINDS and EVENT_KINDS[:4] == coreconst.DECISION_KINDS
    assert ON_FAILURE is coreconst.FAILURE_MODES
    assert coreconst.METRICS is _core.METRICS
    for mode in coreconst.FAILURE_MODES:
        FailurePolicy(mode)


def test_the_bindings_argument_layouts_are_the_ones_python_packs():
    """control's input arguments, Precision's state arrays and the structure step's mission arguments, by name."""
    env = Envelopes.of([Envelope(0.12, 0.3, 0.8)] * 2)
    z = np.zeros((2, 2))
    inp = ControlInput(np.zeros((2, 3)), z, z + 1.0, z + 2.0, 0.1, 0.05, env, np.ones(2, bool))
    named = [getattr(env if hasattr(env, a) else inp, a) for a in coreconst.CONTROL_INPUT_ARGS]
    assert len(_input_args(inp)) == len(named) and all(x is y for x, y in zip(_input_args(inp), named))
    assert coreconst.PRECISION_STATE_ARGS == tuple(f.name for f in dataclasses.fields(PrecisionState))
    args = coreconst.STRUCTURE_STEP_ARGS
    assert MISSION_ARGS == args[:args.index("pose_world")] + args[args.index("radius_m"):]
    template = np.array([[0.3, 0.0], [-0.15, 0.26], [-0.15, -0.26]])
    for metric in coreconst.METRICS:
        c = dict(zip(MISSION_ARGS, core_mission(metric, template, Envelopes.of([Envelope(0.12, 0.3, 0.8)] * 3),
                                                GoalPose(Pose2(1.0, 0.5, 0.0)), StructureLimits(0.08, 0.3))))
        assert c["metric"] == coreconst.METRIC_CODES[metric] and c["goal_kind"] == coreconst.GOAL_POSE
        assert c["margin_m"] == PLAN_MARGIN_M and c["field"] is None and c["template_xy"].tolist() == template.tolist()
        assert c["limits"].tolist() == [getattr(StructureLimits(0.08, 0.3), f) for f in coreconst.LIMIT_FIELDS]


def test_a_missions_path_is_packed_as_a_path_and_the_steps_plan_is_never_a_missions_goal():
    """The goal kind decides the alignment throttle's power (vs_advance.h): a mission's path packs as GOAL_PATH, and a
    synced path (the step's own plan, VS_GOAL_PLAN) is refused rather than packed as a path the core would throttle
    otherwise than the reference."""
    env = Envelopes.of([Envelope(0.12, 0.3, 0.8)] * 3)
    template = np.array([[0.3, 0.0], [-0.15, 0.26], [-0.15, -0.26]])
    way = (Pose2(1.0, 0.0, 0.0), Pose2(2.0, 0.5, 0.3))
    c = dict(zip(MISSION_ARGS, core_mission("l2", template, env, GoalPath(way), StructureLimits(0.08, 0.3))))
    assert c["goal_kind"] == coreconst.GOAL_PATH and c["goal"].tolist() == [v for w in way for v in w.as_tuple()]
    with pytest.raises(GoalError):
        core_mission("l2", template, env, GoalPath(way, synced=True), StructureLimits(0.08, 0.3))


# ---------------------------------------------------------------- no number of the interface written again

ORDERS = {"LIMIT_FIELDS": coreconst.LIMIT_FIELDS, "PRECISION_GAIN_FIELDS": coreconst.PRECISION_GAIN_FIELDS,
          "TRACKING_GAIN_FIELDS": coreconst.TRACKING_GAIN_FIELDS, "DECISION_KINDS": coreconst.DECISION_KINDS}
DEFINED = {"METRICS": coreconst.METRICS, "FAILURE_MODES": coreconst.FAILURE_MODES}   # as a module's own name
CODED = set(coreconst.METRICS) | set(coreconst.DECISION_KINDS) | set(coreconst.FAILURE_MODES)
CODE_NAME = re.compile(r"^_?(GOAL_(POSE|PATH|TWIST|PLAN)|METRIC_(L1|L2|LINF)|DECISION_[A-Z]+|(PRECISION_)?HISTORY"
                       r"|FAILURE_(HOLD|DROP|REJOIN)|(FAILURE_)?NM_PER_M|(FAILURE_)?SETTLED_RATIO)$", re.I)
# a module-level name that is a constant of the core's under its own name (the core's, or without its area:
# field.py's WALL for FIELD_WALL), with the same value, is a copy.
SOURCES = sorted(p for d in ("vsfleet", "tests") for p in (ROOT / d).rglob("*.py")
                 if p.name not in ("coreconst.py", "test_coreconst.py"))


def _strings(node) -> tuple | None:
    if isinstance(node, (ast.Tuple, ast.List)) and node.elts and all(
            isinstance(e, ast.Constant) and isinstance(e.value, str) for e in node.elts):
        return tuple(e.value for e in node.elts)
    return None


def _numbers(node) -> bool:
    """An int / float literal, or a tuple of them."""
    if isinstance(node, ast.Tuple):
        return bool(node.elts) and all(_numbers(e) for e in node.elts)
    return isinstance(node, ast.Constant) and type(node.value) in (int, float)


AREAS = {"GOAL", "METRIC", "FAILURE", "DECISION", "PRECISION", "FIELD", "STEP", "FIT", "L1", "LINF", "WIRE"}


def _unprefixed(name: str) -> str:
    area, _, rest = name.partition("_")
    return rest if area in AREAS else name


def _literal(node):
    """The value of a number written out (literals, math.pi, arithmetic of them), else None."""
    if not all(isinstance(n, (ast.Constant, ast.BinOp, ast.UnaryOp, ast.operator, ast.unaryop, ast.Attribute,
                              ast.Name, ast.Load)) for n in ast.walk(node)):
        return None
    if any(isinstance(n, ast.Attribute) and ast.unparse(n) != "math.pi" for n in ast.walk(node)) or \
            any(isinstance(n, ast.Name) and n.id != "math" for n in ast.walk(node)):
        return None
    try:
        v = eval(compile(ast.Expression(node), "<copy>", "eval"), {"__builtins__": {}, "math": math})  # noqa: S307
    except Exception:
        return None
    return v if type(v) in (int, float) else None


def copies(text: str) -> list[str]:
    """What in this Python text writes one of the core's constants again."""
    tree = ast.parse(text)
    found = []
    top = set(map(id, tree.body))
    for node in tree.body:
        if isinstance(node, (ast.Assign, ast.AnnAssign)) and node.value is not None:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            pairs = [(t, v) for tg in targets for t, v in (
                zip(tg.elts, node.value.elts) if isinstance(tg, ast.Tuple) and isinstance(node.value, ast.Tuple)
                else [(tg, node.value)])]
            for t, v in pairs:
                if not isinstance(t, ast.Name):
                    continue
                value, short = _literal(v), t.id.lstrip("_")
                hits = [k for k, c in NUMBERS.items() if short in (k, _unprefixed(k)) and c == value
                        and value is not None]
                if hits:
                    found.append(f"line {node.lineno}: {t.id} = {value!r} is {hits[0]}")
    for node in ast.walk(tree):
        seq = _strings(node)
        for name, order in ORDERS.items():
            if seq == order:
                found.append(f"line {node.lineno}: {name} written out")
        if isinstance(node, ast.Dict) and len(node.keys) >= 2 and all(
                isinstance(k, ast.Constant) and k.value in CODED for k in node.keys) and all(
                isinstance(v, ast.Constant) and type(v.value) is int for v in node.values):
            found.append(f"line {node.lineno}: a name -> code table written out")
        if isinstance(node, ast.Assign):
            targets = [t for tg in node.targets for t in (tg.elts if isinstance(tg, ast.Tuple) else [tg])]
            names = [t.id for t in targets if isinstance(t, ast.Name)]
            if _numbers(node.value) and any(CODE_NAME.search(n) for n in names):
                found.append(f"line {node.lineno}: {', '.join(names)} = a number of the core's")
            if id(node) in top and _strings(node.value) in DEFINED.values():
                found.append(f"line {node.lineno}: {', '.join(names)} defined again")
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Mult):
            for a, b in ((node.left, node.right), (node.right, node.left)):
                if isinstance(a, ast.Constant) and a.value == coreconst.FAILURE_SETTLED_RATIO \
                        and "fail_after_s" in ast.unparse(b):
                    found.append(f"line {node.lineno}: the failure rule's factor written out")
    return found


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_python_file_writes_a_constant_of_the_core_again(path):
    found = copies(path.read_text())
    assert not found, f"{path.relative_to(ROOT)}: import it from vsfleet.coreconst instead: {found}"


def test_the_check_catches_the_copies_it_replaced():
    """The forms these constants had before vsfleet.coreconst, each caught."""
    old = {
        "advance": "_GOAL_POSE, _GOAL_PATH, _GOAL_TWIST, _GOAL_PLAN = 0, 1, 2, 3\n",
        "limits": "_LIMIT_FIELDS = (" + ", ".join(repr(f) for f in coreconst.LIMIT_FIELDS) + ")\n",
        "metrics": '_METRIC_CODES = {"l1": 0, "l2": 1, "linf": 2}\n',
        "decisions": 'DECISION_KINDS = ("fail", "drop", "rejoin", "recover")\n',
        "modes": 'ON_FAILURE = ("hold", "drop", "rejoin")\n',
        "history": "_HISTORY = 5\n",
        "nm": "_NM_PER_M = 1e9\n",
        "factor": "known = t - first >= 0.8 * policy.fail_after_s\n",
        "records": 'METRICS = ("l1", "l2", "linf")\n',
        "field": "WALL = 0xFFFFFFFF\nW_AXIS, W_DIAG = 10, 14\n",
        "clear": "CLEAR_M = 0.022\n_GAMMA_PER_S = 2.0\n",
        "fit": "CERT_TOL = 1e-10\n_MAX_ROUNDS = 60\n",
        "wire": "MAX_FRAME_BYTES = 1 << 16\n",
        "align": "ALIGN_FLOOR = 0.2\nALIGN_POWER = 8.0\n",
    }
    for what, text in old.items():
        assert copies(text), what
    assert not copies('for metric in ("l1", "l2", "linf"):\n    pass\nx = 0.8 * width\n')


def test_the_agent_bindings_layouts_are_the_structs_and_python_builds_them_by_name():
    """agent_config's policy and safety name vs_failure_policy's and vs_safety_params' members in order; the
    state's arrays are the own wheels, Precision's state and the failure rule's (vs_failure_state after n and W);
    vsfleet.agentcore packs the numbers by AGENT_SCALARS' names and reads agent_step's answer by AGENT_RESULT's."""
    from array import array

    from vsfleet import agentcore

    assert coreconst.AGENT_POLICY == struct_members("vs_failure_policy")
    assert coreconst.AGENT_SAFETY == struct_members("vs_safety_params")
    assert coreconst.AGENT_STATE == ("wheels_m_s", *coreconst.PRECISION_STATE_ARGS,
                                     *struct_members("vs_failure_state")[2:])
    assert set(coreconst.AGENT_TIMES) == {"dt_s", "ttl_s", "age_s", "resync_gap_s", "effective_t"}
    assert agentcore.STATE_ARRAYS == coreconst.AGENT_STATE
    places = {name: float(k) for k, name in enumerate(coreconst.AGENT_SCALARS)}
    assert agentcore.scalars_of(**places) == array("d", range(len(places)))
    with pytest.raises(KeyError):
        agentcore.scalars_of(**{k: v for k, v in places.items() if k != "shape"})
    assert coreconst.AGENT_RESULT[-1] == "decisions" and len(set(coreconst.AGENT_RESULT)) == len(coreconst.AGENT_RESULT)


def test_no_python_file_reads_the_agent_bindings_answers_by_number():
    """agent_step's answer (r) and the state's numbers (scalars, sc) are read by name (AGENT_RESULT, AGENT_SCALARS),
    never by a written index or by unpacking the whole answer: the forms they had before (r[12], scalars[4],
    (_, fx, fy, ...) = r), in every file that calls the binding or reads its answer."""
    def by_place(text: str) -> list[str]:
        found = []
        for n in ast.walk(ast.parse(text)):
            if isinstance(n, ast.Subscript) and isinstance(n.value, ast.Name) and n.value.id in ("r", "sc", "scalars") \
                    and isinstance(n.slice, ast.Constant) and type(n.slice.value) is int:
                found.append(ast.unparse(n))
            if isinstance(n, ast.Assign) and isinstance(n.value, ast.Name) and n.value.id in ("r", "sc", "scalars") \
                    and any(isinstance(t, ast.Tuple) for t in n.targets):
                found.append(ast.unparse(n))
        return found
    assert sorted(by_place("blocked, shape = r[12], r[14]\nx = scalars[4]\n(_, fx, *_) = r\n")) == \
        ["_, fx, *_ = r", "r[12]", "r[14]", "scalars[4]"]
    callers = [p for p in SOURCES
               if re.search(r"_core\.agent_(step|frame)\b|_core_inputs\(|def core_outputs\(", p.read_text())]
    assert {p.name for p in callers} >= {"agentcore.py", "glue.py", "test_core_agent_step.py", "step_core_records.py"}
    for path in callers:
        assert not by_place(path.read_text()), path.relative_to(ROOT)


def test_a_string_field_is_held_to_the_cores_src_limit():
    """vsfleet.wire's strings are at most VS_WIRE_MAX_SRC characters, the core decoder's limit on a frame's src."""
    from vsfleet.wire import WireError, _str

    limit = coreconst.WIRE_MAX_SRC
    assert limit == define_value("VS_WIRE_MAX_SRC")
    assert _str({"src": "a" * limit}, "src") == "a" * limit
    with pytest.raises(WireError):
        _str({"src": "a" * (limit + 1)}, "src")
