"""The assembly tie-break (issue 28, crowded starts): every robot's target when robots bar each other's way.

``assembly_targets`` runs the compiled core (vsfleet/_core/vs_assembly.c, issue 29) and
``assembly_targets_reference`` is the numpy specification it reproduces bit for bit; vsfleet.impl picks one
(``Impl.assembly_targets``) and vsfleet.step.agent_step calls it on every frame of a mission with bodies.
"""

from __future__ import annotations

import math

from .lazy import lazy_numpy
from . import _core
from .coreconst import ASSEMBLING_M, DETOUR_CLEAR_M, ESCAPE_M, PRESSED_M, PRIORITY_S
from .errors import ShapeError

np = lazy_numpy(globals())   # numpy on first use: the agent process never loads it (vsfleet.lazy)


def assembly_targets(radii_m: np.ndarray, pose_world: np.ndarray, seen: np.ndarray, points_now: np.ndarray,
                     points_next: np.ndarray, margin_m: float,
                     elapsed_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The assembly tie-break in the compiled core: (points_now, points_next, detoured (n,) bool), new arrays.

    The same arguments and the same bits as :func:`assembly_targets_reference`. Only seen rows are read:
    their radius, x, y and points must be finite, and margin_m and elapsed_s (NonFiniteError); radii and
    margin_m >= 0 (VsfleetValueError).
    """
    radii = np.ascontiguousarray(radii_m, dtype=float)
    pose = np.ascontiguousarray(pose_world, dtype=float)
    flags = np.ascontiguousarray(seen, dtype=bool)
    now_in = np.ascontiguousarray(points_now, dtype=float)
    next_in = np.ascontiguousarray(points_next, dtype=float)
    n = len(radii)
    if (radii.shape != (n,) or pose.shape != (n, 3) or flags.shape != (n,) or now_in.shape != (n, 2)
            or next_in.shape != (n, 2)):
        raise ShapeError(f"assembly_targets: radii (n,), pose_world (n, 3), seen (n,), points_now and points_next "
                         f"(n, 2), got {radii.shape}, {pose.shape}, {flags.shape}, {now_in.shape}, {next_in.shape}")
    now, nxt, detoured = np.empty((n, 2)), np.empty((n, 2)), np.empty(n, dtype=bool)
    _core.assembly_targets(radii, pose, flags, now_in, next_in, float(margin_m), float(elapsed_s), now, nxt, detoured)
    return now, nxt, detoured


_M32 = 0xFFFFFFFF


def priority_draw(elapsed_s: float) -> int:
    """The priorities' draw for a mission elapsed_s [s] old: 0 for its first PRIORITY_S seconds (and before them),
    then the count of whole periods, saturated at 2^32 - 1 (vs_assembly.h)."""
    q = elapsed_s / PRIORITY_S
    if not q >= 1.0:
        return 0
    return int(q) if q < 4294967296.0 else _M32


def rank(i: int, draw: int) -> int:
    """Robot (row) i's rank in a draw: i itself in draw 0, else a 32-bit mix of i and the draw (vs_assembly.h)."""
    i = int(i)
    if draw == 0:
        return i
    h = ((i * 0x9E3779B1) & _M32) ^ ((draw * 0x85EBCA77) & _M32)
    h ^= h >> 15
    h = (h * 0x2C1B3C6D) & _M32
    h ^= h >> 12
    h = (h * 0x297A2D39) & _M32
    h ^= h >> 15
    return h


def _before(a: int, b: int, draw: int) -> bool:
    """Does robot a come before robot b in the draw (the lower rank; equal ranks: the lower row)?"""
    ra, rb = rank(a, draw), rank(b, draw)
    return ra < rb or (ra == rb and a < b)


def assembly_targets_reference(radii_m: np.ndarray, pose_world: np.ndarray, seen: np.ndarray, points_now: np.ndarray,
                               points_next: np.ndarray, margin_m: float,
                               elapsed_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The assembly tie-break: (points_now, points_next, detoured (n,) bool), every robot's target.

    Robot i, seen and more than ASSEMBLING_M from its point, is barred by robot j (seen) when j's centre lies
    ahead on i's straight way to its point (0 < along < distance + width) within width = r_i + r_j + margin
    of that line; its first blocker is the nearest such j (ties: the lower row). Which of two robots *comes
    first* is drawn afresh every PRIORITY_S seconds of the mission (elapsed_s: the frame's time less the
    mission's effective time): :func:`rank` in draw :func:`priority_draw`, the rows' own order in the first
    period. Two robots that bar each other (head on): the one that comes later gives way and passes the other
    on its right; the other keeps its way, unless a robot that comes before it bars it head on too (then it
    too passes its first blocker on its right: two robots never both keep their way into each other). A
    robot barred by one that does not bar it passes it on the side it is already on (on the right when dead
    ahead). Passing j means heading for the waypoint c = width + DETOUR_CLEAR_M to that side of the line from
    i to j and c short of j along it: never towards j while they touch, and round j as i goes. A robot sent
    round j (either way above) that is boxed in (gap - width < PRESSED_M, and its way to that waypoint
    barred by a third robot) escapes (:func:`_way_out`): ESCAPE_M straight back from j, else straight out of
    the crowd (away from the centroid of the seen robots, summed in row order), else 45 degrees off back
    towards its passing side, then the other, then 90 degrees off the same two ways, the first way no robot bars;
    else it waits where it stands (its target is its position). Then a robot that kept its way (head on)
    into a first blocker that waits gives way in turn: it goes round that blocker on its right, as above
    (boxed in or not); each row reads these first targets. Then a robot on its way pressed against the first
    robot k on its way to its target, k coming first and barring k's way to k's target in turn (their
    targets cross), escapes from k as above, passing on its right; each row reads the second pass's targets.
    Last, a placed robot (seen, not on its way) that bars the way of a robot boxed in by the first or second pass
    (and not sent off by the third) to the waypoint it could not take steps aside (the lowest such row): ESCAPE_M
    straight away from that robot, else 45 degrees off that to its left, then its right, then 90 degrees the same,
    the first way no robot bars.
    Every agent computes the same targets from the same frame (a pure function of it, in + - * / and sqrt,
    which IEEE 754 rounds alike everywhere, and 32-bit integer arithmetic: no libm function whose last bit
    could differ between hosts)."""
    n = len(pose_world)
    xy = pose_world[:, :2]
    to = points_now - xy
    dist = np.sqrt(to[:, 0] * to[:, 0] + to[:, 1] * to[:, 1])   # + * / sqrt only: the same bits on every platform
    on_way = seen & (dist > ASSEMBLING_M)
    detoured = np.zeros(n, dtype=bool)
    if n < 2 or not on_way.any():
        return points_now, points_next, detoured
    d = to / np.where(on_way, dist, 1.0)[:, None]
    rel = xy[None, :, :] - xy[:, None, :]                              # rel[i, j] = p_j - p_i
    along = rel[:, :, 0] * d[:, None, 0] + rel[:, :, 1] * d[:, None, 1]
    lateral = d[:, None, 0] * rel[:, :, 1] - d[:, None, 1] * rel[:, :, 0]   # > 0: j left of i's way
    width = radii_m[:, None] + radii_m[None, :] + margin_m
    bars = (on_way[:, None] & seen[None, :] & ~np.eye(n, dtype=bool) & (along > 0.0)
            & (along < dist[:, None] + width) & (np.abs(lateral) < width))
    first = np.argmin(np.where(bars, along, np.inf), axis=1)
    rows = np.flatnonzero(bars.any(axis=1))
    now, nxt = points_now.copy(), points_next.copy()
    cx = cy = count = 0.0
    for k in range(n):                      # the centroid of the seen robots, summed in row order
        if seen[k]:
            cx, cy, count = cx + float(xy[k, 0]), cy + float(xy[k, 1]), count + 1.0
    if count > 0.0:
        cx, cy = cx / count, cy / count
    draw = priority_draw(elapsed_s)
    boxed = {}      # a row boxed in (its target an escape) -> the waypoint round its blocker it could not take
    for i in rows:
        j = int(first[i])
        mutual = bool(bars[j, i])
        if mutual and _before(i, j, draw) and not any(bars[i, k] and bars[k, i] and _before(k, i, draw)
                                                      for k in range(n)):
            continue     # head on, i comes first, and no robot before it bars it head on: i keeps its way
        left = 1.0 if (not mutual and lateral[i, j] < 0.0) else -1.0     # j on i's right: pass on its left
        now[i] = nxt[i] = _round(radii_m, xy, seen, margin_m, i, j, left, width[i, j], (cx, cy), boxed)
        detoured[i] = True
    # a robot that kept its way into a first blocker that waits (sent round, its target its own position)
    # gives way in turn, round it on its right; each row reads the first pass's targets
    waits = detoured & (now[:, 0] == xy[:, 0]) & (now[:, 1] == xy[:, 1])
    kept = ~detoured
    for i in rows:
        j = int(first[i])
        if kept[i] and waits[j]:
            now[i] = nxt[i] = _round(radii_m, xy, seen, margin_m, i, j, -1.0, width[i, j], (cx, cy), boxed)
            detoured[i] = True
    # a robot pressed against the first robot on its way to its target, which comes first and bars its way to its own
    # target in turn (their targets cross): the robot escapes, passing on its right; each row reads the second pass's
    # targets
    crossing = []
    for i in range(n):
        if not on_way[i]:
            continue
        k = _first_on_target(radii_m, xy, seen, margin_m, now, i)
        if k < 0 or not _before(k, i, draw):
            continue
        rx, ry = float(xy[k, 0]) - float(xy[i, 0]), float(xy[k, 1]) - float(xy[i, 1])
        gap = math.sqrt(rx * rx + ry * ry)
        if not gap > 0.0 or not gap - ((float(radii_m[i]) + float(radii_m[k])) + margin_m) < PRESSED_M:
            continue
        if _first_on_target(radii_m, xy, seen, margin_m, now, k, only=i) == i:
            crossing.append((i, k))
    for i, k in crossing:
        rel = xy[k] - xy[i]
        u = rel / math.sqrt(rel[0] * rel[0] + rel[1] * rel[1])
        now[i] = nxt[i] = _way_out(radii_m, xy, seen, margin_m, i, (cx, cy), u, np.array([u[1], -u[0]]))
        detoured[i] = True
        boxed.pop(i, None)          # its target is now this escape
    # a placed robot (seen, not on its way) that bars the way of a boxed-in robot i (the lowest such row) to the
    # waypoint it could not take steps aside: ESCAPE_M straight away from i, if no robot bars that way; each row reads
    # the passes' targets above
    for k in range(n):
        if not seen[k] or on_way[k] or detoured[k]:
            continue
        for i in sorted(boxed):
            if not any(True for _ in _barring(radii_m, xy, seen, margin_m, i, boxed[i], (k,))):
                continue
            rx, ry = float(xy[k, 0]) - float(xy[i, 0]), float(xy[k, 1]) - float(xy[i, 1])
            g = math.sqrt(rx * rx + ry * ry)
            if g > 0.0:     # away from i, then 45 degrees off it to the left and the right, then 90
                ux, uy, h = rx / g, ry / g, math.sqrt(0.5)
                for fx, fy in ((ux, uy), (h * (ux - uy), h * (uy + ux)), (h * (ux + uy), h * (uy - ux)), (-uy, ux),
                               (uy, -ux)):
                    way = np.array([float(xy[k, 0]) + fx * ESCAPE_M, float(xy[k, 1]) + fy * ESCAPE_M])
                    if not _way_barred(radii_m, xy, seen, margin_m, k, -1, way):
                        now[k] = nxt[k] = way
                        detoured[k] = True
                        break
            break
    return now, nxt, detoured


def _barring(radii_m: np.ndarray, xy: np.ndarray, seen: np.ndarray, margin_m: float, i: int, way: np.ndarray, ks):
    """The robots of ``ks`` (seen, not i) that bar robot i's straight way to ``way``, as a blocker bars a way to its
    point, each as (along [m], row), in the order of ks; none where the way has length 0."""
    tx, ty = float(way[0]) - float(xy[i, 0]), float(way[1]) - float(xy[i, 1])
    length = math.sqrt(tx * tx + ty * ty)
    if not length > 0.0:
        return
    dx, dy = tx / length, ty / length
    for k in ks:
        if k == i or not seen[k]:
            continue
        rx, ry = float(xy[k, 0]) - float(xy[i, 0]), float(xy[k, 1]) - float(xy[i, 1])
        along, lateral = rx * dx + ry * dy, dx * ry - dy * rx
        width = (float(radii_m[i]) + float(radii_m[k])) + margin_m
        if along > 0.0 and along < length + width and abs(lateral) < width:
            yield along, k


def _first_on_target(radii_m: np.ndarray, xy: np.ndarray, seen: np.ndarray, margin_m: float, targets: np.ndarray,
                     i: int, only: int = -1) -> int:
    """The first robot (the least along; ties: the lower row) that bars robot i's straight way to its target
    ``targets[i]``, as a blocker bars a way to a point; -1 if none or the target is i's position. only >= 0: that
    robot if it bars the way (whether first or not), else -1."""
    best, first = 0.0, -1
    for along, k in _barring(radii_m, xy, seen, margin_m, i, targets[i], range(len(xy)) if only < 0 else (only,)):
        if first < 0 or along < best:
            best, first = along, k
    return first


def _round(radii_m: np.ndarray, xy: np.ndarray, seen: np.ndarray, margin_m: float, i: int, j: int, left: float,
           width: float, centroid: tuple[float, float], boxed: dict) -> np.ndarray:
    """Robot i's target round its blocker j on the side ``left`` (1.0: pass on j's left), ``width`` = r_i + r_j +
    margin: the detour's waypoint, or, boxed in, :func:`_way_out` (then ``boxed[i]`` is the waypoint)."""
    rel = xy[j] - xy[i]
    gap = math.sqrt(rel[0] * rel[0] + rel[1] * rel[1])
    u = rel / gap                                                    # towards j
    normal = np.array([-u[1], u[0]]) * left
    clear = width + DETOUR_CLEAR_M          # round j: as far beside the line to j, and that much short of j
    way = xy[i] + normal * clear + u * (gap - clear)
    boxed.pop(i, None)
    if gap - width < PRESSED_M and _way_barred(radii_m, xy, seen, margin_m, i, j, way):
        boxed[i] = way
        way = _way_out(radii_m, xy, seen, margin_m, i, centroid, u, normal)   # boxed in
    return way


def _way_barred(radii_m: np.ndarray, xy: np.ndarray, seen: np.ndarray, margin_m: float, i: int, skip: int,
                way: np.ndarray) -> bool:
    """Is robot i's straight way to ``way`` barred, as on the way to its point, by a seen robot other than i
    and ``skip`` (-1: none)? A way of length 0 is not."""
    return any(True for _ in _barring(radii_m, xy, seen, margin_m, i, way,
                                      (k for k in range(len(xy)) if k != skip)))


def _way_out(radii_m: np.ndarray, xy: np.ndarray, seen: np.ndarray, margin_m: float, i: int,
             centroid: tuple[float, float], u: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """A robot's escape from the robot ``u`` points at, ``normal`` the unit normal to its passing side: ESCAPE_M back
    from it if that way is free, else ESCAPE_M out of the crowd (away from ``centroid``) if that way is free, else
    ESCAPE_M 45 degrees off back towards the passing side, then the other, then 90 degrees off the same two ways, the
    first way that is free; else its own position."""
    x, y = float(xy[i, 0]), float(xy[i, 1])
    way = np.array([x - float(u[0]) * ESCAPE_M, y - float(u[1]) * ESCAPE_M])
    if not _way_barred(radii_m, xy, seen, margin_m, i, -1, way):
        return way
    ox, oy = x - centroid[0], y - centroid[1]
    out = math.sqrt(ox * ox + oy * oy)
    if out > 0.0:
        way = np.array([x + (ox / out) * ESCAPE_M, y + (oy / out) * ESCAPE_M])
        if not _way_barred(radii_m, xy, seen, margin_m, i, -1, way):
            return way
    ux, uy, nx, ny, h = float(u[0]), float(u[1]), float(normal[0]), float(normal[1]), math.sqrt(0.5)
    for fx, fy in ((h * (nx - ux), h * (ny - uy)), (h * (-nx - ux), h * (-ny - uy)), (nx, ny), (-nx, -ny)):
        way = np.array([x + fx * ESCAPE_M, y + fy * ESCAPE_M])
        if not _way_barred(radii_m, xy, seen, margin_m, i, -1, way):
            return way
    return np.array([x, y])
