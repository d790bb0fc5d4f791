"""The structure at one frame: fit, advance and judged fit (the part of the agent step every agent computes alike).

:func:`structure_step_core` runs it in the compiled core (one call), :func:`structure_step_reference` in numpy
(the readable reference); vsfleet.impl chooses between them and vsfleet.step.structure_step calls the one
chosen. :func:`room_field` builds (and memoises) a room's navigation function, PLAN_MARGIN_M is its clearance.
"""

from __future__ import annotations

import math
from array import array
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Callable

from .lazy import lazy_numpy
from . import _core
from .coreconst import STEP_HELD_BACK, STEP_LOOKAHEAD_PER_REACH, STRUCTURE_STEP_ARGS
from .advance import Goal, GoalPath, GoalPose, GoalTwist, Twist2, advance_structure_reference
from .buffers import f64
from .clear import clearance_barrier_reference
from .field import (Field, build_field, build_field_reference, field_open_reference, first_lattice,
                    follow_field_reference, room_lattice)
from .fit import fit_structure_reference
from .geometry import Pose2, wrap_angle

np = lazy_numpy(globals())   # numpy on first use: the agent process never loads it (vsfleet.lazy)

#: clearance [m] the structure's planned way keeps between every robot body and every obstacle: beyond the
#: safety filter's own margin (15 mm), so that on the plan the filter stays idle (docs/planning.md); the
#: field's edges keep this, its states 1-2 mm more (the edges' exact bound); the clearance barrier (vsfleet.clear)
#: keeps the structure's points CLEAR_M (22 mm) away
PLAN_MARGIN_M = 0.02
HELD_BACK = STEP_HELD_BACK   # vs_step.h: the barrier keeps less than this share of the move asked for
#: [s] of a mission's time (tracker clock, from its effective_t): where its room has a first plan
#: (has_first_plan), every agent follows that plan's field before this, and the room's own field from then on
#: (docs/planning.md, "The first plan"): a function of the frame's time, so the copies agree whichever field an
#: agent had built when
FIRST_PLAN_S = 0.5


def room_field(template: np.ndarray, radii, obstacles: np.ndarray, goal: Goal,
               build: Callable = build_field, first: bool = False) -> Field | None:
    """The room's navigation function for a mission (None without obstacles or with a twist goal), memoised by
    what it depends on: missions that differ only in speed, version or metric (and the agents of one offline
    run, each with its own decoded mission) share one field. build: the core's build_field, or the reference's.
    first: the field of the first plan instead (vsfleet.field.first_lattice; None where the room has none), which
    the agents follow for a mission's first FIRST_PLAN_S."""
    if len(obstacles) == 0 or isinstance(goal, GoalTwist):
        return None
    target = goal.pose if isinstance(goal, GoalPose) else goal.waypoints[-1]
    tpl = f64(template)
    rad = f64(radii)
    if len(rad) == 1:   # one radius for every body (as numpy broadcast it)
        rad = array("d", [rad[0]] * (len(tpl) // 2))
    return _room_field(tpl.tobytes(), rad.tobytes(), f64(obstacles).tobytes(), target.as_tuple(), build, first)


# A few rooms and their shapes, the least recently used out: each field holds up to 8 MB (32 MB once it has built its
# finer lattice, field_refinement). A deferred field (the agents') is written by the descents that resolve its
# components (vs_field_build_deferred) or build its finer lattice, so one field must not be followed by two threads
# at once: an agent runs its frames one at a time, and its prepare thread only builds.
@lru_cache(maxsize=12)
def _room_field(tpl_bytes: bytes, rad_bytes: bytes, obs_bytes: bytes, target: tuple, build: Callable,
                first: bool = False) -> Field | None:
    """room_field's build, by its key (the arrays' bytes): the lattice's heading count by the structure, and the
    finer lattice it asks where it has no way (field_refinement); first: the first plan's (first_lattice)."""
    tpl, rad, obs = array("d", tpl_bytes), array("d", rad_bytes), array("d", obs_bytes)
    first_lat = first_lattice(tpl, rad, PLAN_MARGIN_M, obs, target[:2])
    if first:
        return None if first_lat is None else build(tpl, rad, PLAN_MARGIN_M, obs, Pose2(*target), **first_lat)
    fld = build(tpl, rad, PLAN_MARGIN_M, obs, Pose2(*target), **room_lattice(tpl, rad, PLAN_MARGIN_M, obs, target[:2]))
    if first_lat is not None and "max_states" not in first_lat:
        # a first plan on the room's own lattice without its finer one (a large structure): that finer lattice now,
        # with the field (on the agent's prepare thread, before any frame follows it), so that the frame that asks it
        # for the verdict the first plan left does not build it. Short of memory, that frame tries again (as without a
        # first plan). A coarse first plan's room keeps its finer lattice for the frame that needs it (24 MB, up to
        # 0.1 s for a small structure in a large room, rarely asked)
        try:
            fld.refine_now()
        except MemoryError:
            pass
    return fld


def has_first_plan(template: np.ndarray, radii, obstacles: np.ndarray, goal: Goal, shapes=()) -> bool:
    """Whether a mission's room has a first plan (vsfleet.field.first_lattice): its template's room has one, and the
    mission allows no other shape (shapes: their points). Plain arithmetic on the mission, no build. Why not with
    shapes: the structure takes the first shape whose field is open, and a first plan's fields, provisional, are shut
    where the room's own are open (tests/test_reshape.py's box room: scale 0.6 for the first half second, then 0.8)."""
    if len(obstacles) == 0 or isinstance(goal, GoalTwist) or len(shapes) > 0:
        return False
    target = goal.pose if isinstance(goal, GoalPose) else goal.waypoints[-1]
    rad = f64(radii)
    tpl = f64(template)
    r = array("d", [rad[0]] * (len(tpl) // 2)) if len(rad) == 1 else rad
    return first_lattice(tpl, r, PLAN_MARGIN_M, f64(obstacles), (target.x, target.y)) is not None


@dataclass(frozen=True)
class Structure:
    """The structure at one frame. fit_pose / goal_pose [m, rad; world]: fitted and advanced;
    points_now / points_next (n, 2) [m; world]: every robot's point on them; deviations_m (n,):
    each robot's distance to the point it is judged on (inf when unseen); cost [m]: the fit's."""

    fit_pose: Pose2
    goal_pose: Pose2
    twist: Twist2
    cost: float
    at_goal: bool
    used: np.ndarray
    points_now: np.ndarray
    points_next: np.ndarray
    deviations_m: np.ndarray
    blocked: bool = False   # obstacles: no path to the goal; the structure stops at the closest safe pose
    left_m: float = 0.0     # obstacles, blocked: how far [m] that pose is from the goal
    shape: int = 0          # reshape: the shape taken (0: the template; k: the mission's k-th, MissionArrays.shapes)
    cleared: bool = False   # obstacles: the clearance barrier (vsfleet.clear) changed the advance's twist
    held: bool = False      # a provisional first plan with no way here: the structure holds, no verdict (vs_step.h)



def structure_step_reference(arrays, metric: str, pose_world: np.ndarray, seen: np.ndarray, excluded: np.ndarray,
                             judged_apart: np.ndarray, elapsed_s: float, dt_s: float) -> Structure | None:
    """Fit the structure to the robots seen and not excluded, advance it one dt_s toward the goal: the
    readable reference (numpy) of :func:`structure_step_core`. arrays: the mission's (vsfleet.step.MissionArrays).

    Robots absent or excluded are left out of the fit but still bound the advance. The
    deviations are measured on the structure fitted without the ``judged_apart`` robots (when two
    or more others remain): under hold a failed robot bends the structure the robots follow, and
    the healthy robots it bends must not look non-compliant for it. None if no robot is usable.
    """
    used = seen & ~excluded
    if not used.any():
        return None
    fit_fn, advance_fn = fit_structure_reference, advance_structure_reference
    xy = pose_world[:, :2]
    template, field, shape = arrays.template, None, 0
    fit = fit_fn(template[used], xy[used], metric=metric)
    if arrays.field is not None:
        field = _reference_field(arrays, template)
        if arrays.shapes:   # reshape (vs_step.h): which shape the robots are in, which can take its way
            options = [(template, field, fit)]
            for _name, points in arrays.shapes:
                options.append((points, _reference_field(arrays, points), fit_fn(points[used], xy[used], metric=metric)))
            now_in = 0
            for j, (_t, _f, fj) in enumerate(options):
                if fj.cost < options[now_in][2].cost:
                    now_in = j
            state = [field_open_reference(fld, fj.pose) for _t, fld, fj in options]
            pick = next((j for j, (op, tight) in enumerate(state) if op and (j == now_in or not tight)),
                        next((j for j, (op, _tight) in enumerate(state) if op), 0))
            template, field, fit = options[pick]
            shape = pick
    now_pts = fit.pose.apply(template)
    dist = np.hypot(xy[:, 0] - now_pts[:, 0], xy[:, 1] - now_pts[:, 1])
    goal, blocked, left_m, limits, held = arrays.goal, False, 0.0, arrays.limits, False
    if field is not None:  # the room: follow the field's descent from the fitted pose
        way, blocked, left_m = follow_field_reference(field, fit.pose)
        if blocked and field.provisional:   # a first plan with no way from here: hold, no verdict (vs_step.h)
            way, blocked, left_m, held = way[:1], False, 0.0, True
        goal = GoalPath(tuple(Pose2(*w) for w in way), synced=True)
        # the carrot at least STEP_LOOKAHEAD_PER_REACH times the shape's reach ahead (vs_step.h)
        reach = math.sqrt(float(np.max(template[:, 0] * template[:, 0] + template[:, 1] * template[:, 1])))
        ahead = STEP_LOOKAHEAD_PER_REACH * reach
        if ahead > limits.path_lookahead_m:
            limits = replace(limits, path_lookahead_m=ahead)
    adv = advance_fn(fit.pose, goal, dt_s, limits, template, arrays.envelopes,
                     elapsed_s=elapsed_s, headings_rad=np.where(used, pose_world[:, 2], np.nan),
                     deviations_m=np.where(used, dist, np.nan))
    cleared = False
    if field is not None and len(arrays.obstacles) > 0 and not adv.at_goal:
        # the room's clearance barrier (vsfleet.clear): the points keep CLEAR_M from every obstacle
        def through_barrier(t):
            return clearance_barrier_reference(now_pts, fit.pose.x, fit.pose.y, arrays.radii, arrays.obstacles, reach,
                                               (t.vx_m_s, t.vy_m_s, t.w_rad_s))

        (vx, vy, w), changed = through_barrier(adv.twist)
        ask = adv.twist
        ask2 = ask.vx_m_s * ask.vx_m_s + ask.vy_m_s * ask.vy_m_s
        if (changed and limits.path_lookahead_m > arrays.limits.path_lookahead_m and ask2 > 0.0
                and vx * ask.vx_m_s + vy * ask.vy_m_s < HELD_BACK * ask2):
            # the barrier holds a large structure's move back head on: the mission's own lookahead (vs_step.h)
            adv = advance_fn(fit.pose, goal, dt_s, arrays.limits, template, arrays.envelopes,
                             elapsed_s=elapsed_s, headings_rad=np.where(used, pose_world[:, 2], np.nan),
                             deviations_m=np.where(used, dist, np.nan))
            changed = False
            if not adv.at_goal:
                (vx, vy, w), changed = through_barrier(adv.twist)
        cleared = changed
        if changed:   # the pose one dt_s on, as the advance forms it
            adv = replace(adv, pose=Pose2(fit.pose.x + vx * dt_s, fit.pose.y + vy * dt_s, fit.pose.th + w * dt_s),
                          twist=Twist2(vx, vy, w))
    judges = used & ~judged_apart
    if 2 <= int(judges.sum()) < int(used.sum()):  # a rigid fit needs two points to fix the heading
        judged = fit_fn(template[judges], xy[judges], metric=metric).pose.apply(template)
        dist = np.hypot(xy[:, 0] - judged[:, 0], xy[:, 1] - judged[:, 1])
    return Structure(fit_pose=fit.pose, goal_pose=adv.pose, twist=adv.twist, cost=float(fit.cost),
                     at_goal=adv.at_goal and not blocked and not held, used=used, points_now=now_pts,
                     points_next=adv.pose.apply(template), deviations_m=np.where(seen, dist, np.inf),
                     blocked=blocked, left_m=left_m, shape=shape, cleared=cleared, held=held)



def _reference_field(arrays, template: np.ndarray) -> Field:
    """The reference build of the field of a mission's template or one of its shapes (memoised by room_field)."""
    return room_field(template, arrays.radii, arrays.obstacles, arrays.goal, build_field_reference, arrays.first)



def structure_step_core(arrays, metric: str, pose_world: np.ndarray, seen: np.ndarray, excluded: np.ndarray,
                        judged_apart: np.ndarray, elapsed_s: float, dt_s: float) -> Structure | None:
    """The structure step in the compiled core (vs_structure_step): one call for the fit, the advance and the
    judged fit. arrays: the mission's (vsfleet.step.MissionArrays), whose ``core`` holds the mission packed for
    the core, its metric among it."""
    n = len(arrays.ids)
    used, now, nxt, dev = np.empty(n, dtype=bool), np.empty((n, 2)), np.empty((n, 2)), np.empty(n)
    c = arrays.core
    r = _core.structure_step(*c[:_FRAME], np.ascontiguousarray(pose_world, dtype=float),
                             np.ascontiguousarray(seen, dtype=bool), np.ascontiguousarray(excluded, dtype=bool),
                             np.ascontiguousarray(judged_apart, dtype=bool), float(elapsed_s), float(dt_s),
                             used, now, nxt, dev, *c[_FRAME:])
    if r is None:
        return None
    fx, fy, fth, gx, gy, gth, vx, vy, w, cost, at_goal, blocked, left_m, shape, cleared, held = r
    return make_structure(fx, fy, wrap_angle(fth), gx, gy, wrap_angle(gth), vx, vy, w, cost, at_goal, used, now, nxt,
                          dev, blocked, left_m, shape, cleared, held)


def make_structure(fx, fy, fth, gx, gy, gth, vx, vy, w, cost, at_goal, used, now, nxt, dev, blocked, left_m,
                   shape, cleared=False, held=False) -> Structure:
    """A Structure of the core's numbers, its headings fth and gth already wrapped (wrap_angle)."""
    # the frozen dataclasses filled without their __init__s (as advance._result and _evolve do), every field given
    # as __init__ would set it (Pose2: x and y as floats, th wrapped by wrap_angle): 2 Pose2, a Twist2 and the
    # Structure cost about 6 us through their __init__s at n = 10
    fit, goal, twist, out = _new(Pose2), _new(Pose2), _new(Twist2), _new(Structure)
    _set(fit, "__dict__", {"x": float(fx), "y": float(fy), "th": fth})
    _set(goal, "__dict__", {"x": float(gx), "y": float(gy), "th": gth})
    _set(twist, "__dict__", {"vx_m_s": vx, "vy_m_s": vy, "w_rad_s": w})
    _set(out, "__dict__", {"fit_pose": fit, "goal_pose": goal, "twist": twist, "cost": cost, "at_goal": at_goal,
                           "used": used, "points_now": now, "points_next": nxt, "deviations_m": dev,
                           "blocked": blocked, "left_m": left_m, "shape": shape, "cleared": cleared, "held": held})
    return out


_new, _set = object.__new__, object.__setattr__

# structure_step's arguments (STRUCTURE_STEP_ARGS): the mission's (core_mission packs them once, MISSION_ARGS)
# come before the frame's (from pose_world) and after them (from radius_m)
_FRAME, _AFTER = STRUCTURE_STEP_ARGS.index("pose_world"), STRUCTURE_STEP_ARGS.index("radius_m")
MISSION_ARGS = STRUCTURE_STEP_ARGS[:_FRAME] + STRUCTURE_STEP_ARGS[_AFTER:]

