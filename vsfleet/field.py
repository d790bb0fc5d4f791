"""The structure's way through a room, planned once per mission for its bodies in SE(2) (docs/planning.md).

A navigation function over a lattice of structure poses ``(gx + ix h, gy + iy h, gth + k dth)``, aligned
on the goal pose: every state holds its integer cost to go (or WALL where some robot body would come
closer to an obstacle than its edges' exact bound allows: every pose on an edge keeps ``margin``).
Following it from any pose is a cheap descent, so the plan is made once per mission and never repaired:
from wherever the structure is, the field says which way to go. It is a pure function of the mission, so every agent holds the same field.

:func:`build_field` / :func:`follow_field` run the compiled core (vsfleet/_core/vs_field.c);
:func:`build_field_reference` / :func:`follow_field_reference` are the readable reference (numpy and
scipy's Dijkstra), which gives the same integer costs, bit for bit (tests/test_core_field.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .lazy import lazy_numpy
from . import _core
from .coreconst import (  # the core's (vs_field.h, vs_step.h), under the names this module has always used
    FIELD_BLOCKED_BIT as BLOCKED_BIT,
    FIELD_COMFORT_M as COMFORT_M,
    FIELD_COST_MASK as COST_MASK,
    FIELD_GROW as GROW,
    FIELD_SEARCH_CELLS as SEARCH_CELLS,
    FIELD_TIGHT_BIT as TIGHT_BIT,
    FIELD_W_AXIS as W_AXIS,
    FIELD_W_DIAG as W_DIAG,
    FIELD_WALL as WALL,
    STEP_PATH_CAP as PATH_CAP,
    STEP_PATH_M as PATH_M,
)
from .buffers import f64
from .errors import VsfleetValueError
from .geometry import Pose2

np = lazy_numpy(globals())   # numpy on first use: the agent process never loads it (vsfleet.lazy)

# COMFORT_M [m]: beyond the margin, edges near obstacles cost twice (the safety filter stays idle)

#: the lattice the agents use: 3 cm cells, 48 headings (7.5 degrees), at most 2 million states
CELL_M = 0.03
HEADINGS = 48
MAX_STATES = 2_000_000
# PATH_M, PATH_CAP: the descent handed to the advance each frame [m], and its waypoints at most (vs_step.h)

#: the heading counts a room's lattice may take (field_headings): 48 unless a large structure's turns inflate more
HEADING_CHOICES = (48, 64, 96)
HEADING_GAIN_M = 0.005   # a larger count only if its lattice inflates at least this much less [m]

#: the finer lattice a room's field asks where it has no way (field_refinement, vs_field_set_refine): at most
#: 6 million states (24 MB, built only where the coarse lattice has no way), at the heading count of these whose
#: lattice inflates least
REFINE_MAX_STATES = 6_000_000
REFINE_HEADING_CHOICES = (48, 64, 96, 128)

#: the first plan's coarse kind (first_lattice): a lattice of the same room, at most 150,000 states, at the first of
#: these heading counts whose lattice inflates within HEADING_GAIN_M of the least; only where the room's own lattice
#: holds more than FIRST_GAIN times as many states (docs/planning.md, "The first plan")
FIRST_MAX_STATES = 150_000
FIRST_HEADING_CHOICES = (16, 24, 32, 48)
FIRST_GAIN = 4
FIRST_EXTRA_M = 0.04   # [m] the first lattice inflates at most this much more than the room's own


def lattice_sizing(template_xy, radius_m, margin_m: float, obstacles, goal_xy, n_headings: int,
                   cell_m: float = CELL_M, max_states: int = MAX_STATES):
    """vs_field_build's sizing of a room's lattice, in the same order: (h [m], inflation [m], ix0, ix1, iy0, iy1,
    pmax [m]), the cell grown by GROW until the lattice holds at most max_states; None if it never does. The
    inflation is max(h / sqrt 2, the farthest point's turn of half a heading step). Plain arithmetic: every agent
    computes the same (build_field_reference and field_headings both size by it)."""
    flat = f64(template_xy)
    pts = list(zip(flat[0::2], flat[1::2]))
    rad = f64(radius_m).tolist()
    pmax = max([0.0] + [math.sqrt(x * x + y * y) for x, y in pts])
    reach = max([0.0] + [math.sqrt(x * x + y * y) + r for (x, y), r in zip(pts, rad)])
    gx, gy = float(goal_xy[0]), float(goal_xy[1])
    flat = f64(obstacles)
    obs = list(zip(flat[0::3], flat[1::3], flat[2::3]))
    lo_x = min([0.0] + [(o[0] - o[2]) - gx for o in obs])
    hi_x = max([0.0] + [(o[0] + o[2]) - gx for o in obs])
    lo_y = min([0.0] + [(o[1] - o[2]) - gy for o in obs])
    hi_y = max([0.0] + [(o[1] + o[2]) - gy for o in obs])
    h = float(cell_m)
    while True:
        infl = max(h * math.sqrt(0.5), pmax * (math.pi / n_headings))
        pad = ((reach + margin_m) + infl) + COMFORT_M + 2.0 * h
        ix0, ix1 = _floor((lo_x - pad) / h), -_floor(-(hi_x + pad) / h)
        iy0, iy1 = _floor((lo_y - pad) / h), -_floor(-(hi_y + pad) / h)
        if (ix1 - ix0 + 1) * (iy1 - iy0 + 1) * n_headings <= max_states:
            return h, infl, ix0, ix1, iy0, iy1, pmax
        h *= GROW
        if h > 1e6:
            return None


def lattice_inflation_m(template_xy, radius_m, margin_m: float, obstacles, goal_xy, n_headings: int,
                        cell_m: float = CELL_M, max_states: int = MAX_STATES) -> float:
    """The inflation [m] vs_field_build will give a room's lattice of n_headings (lattice_sizing; inf if the room
    does not fit)."""
    sized = lattice_sizing(template_xy, radius_m, margin_m, obstacles, goal_xy, n_headings, cell_m, max_states)
    return math.inf if sized is None else sized[1]


def field_headings(template_xy, radius_m, margin_m: float, obstacles, goal_xy) -> int:
    """The heading count of a room's lattice: the first of HEADING_CHOICES whose lattice inflates within
    HEADING_GAIN_M of the least. A small structure keeps 48 (7.5 degrees): its turns move a body less than half a cell's diagonal.
    A large one (a 5 x 6 grid, a line of 10) took 6.3-8.8 cm of inflation at 48, from its turns alone, and passages
    its bodies clear by less were closed to it (bench/room.py, 200 rooms: 7 of its 17 rooms closed were 5 x 6 grids)."""
    infl = [lattice_inflation_m(template_xy, radius_m, margin_m, obstacles, goal_xy, k) for k in HEADING_CHOICES]
    least = min(infl)
    return next(k for k, i in zip(HEADING_CHOICES, infl) if i <= least + HEADING_GAIN_M)


def field_refinement(template_xy, radius_m, margin_m: float, obstacles, goal_xy,
                     n_headings: int) -> tuple[int, int] | None:
    """The finer lattice (n_headings, max_states) a room's field of n_headings (at MAX_STATES) asks where it has no
    way (build_field's refine), or None when no lattice of REFINE_MAX_STATES inflates HEADING_GAIN_M less than it:
    the first of REFINE_HEADING_CHOICES whose lattice inflates within HEADING_GAIN_M of the least. A plain function
    of the mission, as field_headings is. Why (bench/room.py rooms 70 and 130, a line of 10 robots): their rooms'
    lattices grew to cells of 7.3 cm to fit MAX_STATES, which sealed the goal from the start; at 128 headings and
    6 million states (cells of 4.7 cm, 1.9 cm less inflation) both are open, and the line reaches the goal."""
    coarse = lattice_inflation_m(template_xy, radius_m, margin_m, obstacles, goal_xy, n_headings)
    infl = [lattice_inflation_m(template_xy, radius_m, margin_m, obstacles, goal_xy, k, max_states=REFINE_MAX_STATES)
            for k in REFINE_HEADING_CHOICES]
    least = min(infl)
    if not least <= coarse - HEADING_GAIN_M:
        return None
    return next(k for k, i in zip(REFINE_HEADING_CHOICES, infl) if i <= least + HEADING_GAIN_M), REFINE_MAX_STATES


def room_lattice(template_xy, radius_m, margin_m: float, obstacles, goal_xy) -> dict:
    """The agents' lattice for a room, as build_field's keywords: n_headings (field_headings) and refine
    (field_refinement). vsfleet.structure.room_field builds by it, and so do the benches."""
    heads = field_headings(template_xy, radius_m, margin_m, obstacles, goal_xy)
    return {"n_headings": heads,
            "refine": field_refinement(template_xy, radius_m, margin_m, obstacles, goal_xy, heads)}


def lattice_states(template_xy, radius_m, margin_m: float, obstacles, goal_xy, n_headings: int,
                   max_states: int = MAX_STATES) -> int | None:
    """How many states vs_field_build's lattice of n_headings holds (lattice_sizing; None if the room never fits)."""
    sized = lattice_sizing(template_xy, radius_m, margin_m, obstacles, goal_xy, n_headings, max_states=max_states)
    if sized is None:
        return None
    _h, _infl, ix0, ix1, iy0, iy1, _pmax = sized
    return (ix1 - ix0 + 1) * (iy1 - iy0 + 1) * n_headings


def first_lattice(template_xy, radius_m, margin_m: float, obstacles, goal_xy) -> dict | None:
    """The first plan's lattice of a room, as build_field's keywords, or None where the room has none (docs/planning.md,
    "The first plan"). A plain function of the mission, as room_lattice is; the agents follow its field for the
    mission's first FIRST_PLAN_S (vsfleet.structure) while they build the room's own. Two kinds:

    - coarse: where the room's own lattice holds more than FIRST_GAIN times FIRST_MAX_STATES, a lattice of the same room
      of at most FIRST_MAX_STATES, at the first of FIRST_HEADING_CHOICES whose lattice inflates within HEADING_GAIN_M
      of the least, if it inflates at most FIRST_EXTRA_M more than the room's own (a large structure's coarse lattice
      closes most ways). Why: the triangle's own lattice among 64 pillars (1.7-1.9 million states) takes 30-37 ms to
      plan, this one 2-3 ms (bench/plan_cost.py);
    - the room's own: else, where the room's own lattice asks a finer one (field_refinement), that lattice without
      it (no max_states: the room's own). Why: 30 robots among 256 pillars plan in 22-35 ms on their own lattice, but
      64-116 ms where it has no way and the finer lattice is built to find whether it has one.

    Either is provisional (vs_field_set_provisional): where it has no way, the structure holds, with no verdict,
    until the room's own field answers; so no frame of the first plan builds a field, and every verdict is the room's
    own field's. (Until 2026-12-07 noon a coarse first plan asked the room's own lattice where it had no way (a
    chain of finer lattices in the core, since removed), and the frame that asked built it: 30-40 ms, in 33 of
    bench/room.py's 102 coarse rooms. Holding instead changed their times to the goal by 0.00 s on average, and none
    its verdict or its being in time.)"""
    own = room_lattice(template_xy, radius_m, margin_m, obstacles, goal_xy)
    states = lattice_states(template_xy, radius_m, margin_m, obstacles, goal_xy, own["n_headings"])
    if states is not None and states > FIRST_GAIN * FIRST_MAX_STATES:
        infl = [lattice_inflation_m(template_xy, radius_m, margin_m, obstacles, goal_xy, k,
                                    max_states=FIRST_MAX_STATES) for k in FIRST_HEADING_CHOICES]
        least = min(infl)
        if least <= lattice_inflation_m(template_xy, radius_m, margin_m, obstacles, goal_xy,
                                        own["n_headings"]) + FIRST_EXTRA_M:
            heads = next(k for k, i in zip(FIRST_HEADING_CHOICES, infl) if i <= least + HEADING_GAIN_M)
            return {"n_headings": heads, "max_states": FIRST_MAX_STATES, "provisional": True}
    if own["refine"] is not None:
        return {"n_headings": own["n_headings"], "provisional": True}
    return None


_DX = (1, -1, 0, 0, 1, -1, 1, -1)
_DY = (0, 0, 1, -1, 1, 1, -1, -1)


@dataclass(frozen=True)
class Lattice:
    """Where the field's states are: state (col, row, k) is the pose (gx + (ix_lo + col) h,
    gy + (iy_lo + row) h, gth + k dth); costs (K, ny, nx) uint32."""

    gx: float
    gy: float
    gth: float
    cell_m: float
    dth_rad: float
    inflation_m: float
    n_headings: int
    ix_lo: int
    iy_lo: int
    nx: int
    ny: int
    w_rot: int
    goal_free: bool


class Field:
    """A built field: its lattice and costs; ``handle`` is the core's (None for a reference build). refine: the
    finer lattice (n_headings, max_states) asked where this one has no way (None: none); a reference field builds it
    the first time it is asked (``fine``), the core's field holds it in the core."""

    def __init__(self, lattice: Lattice, costs: np.ndarray, handle=None, refine: tuple[int, int] | None = None,
                 fine_build=None):
        self.lattice, self.costs, self.handle, self.refine = lattice, costs, handle, refine
        self._fine_build, self._fine = fine_build, None
        # a first plan that holds where it has no way (vs_field_set_provisional; the step reads it, the descent not)
        self.provisional = False

    def refine_now(self) -> bool:
        """Build the finer lattice now if there is one; whether it is built. The answers are the same whenever it is
        built. Not beside another thread that follows this field (the core's build writes into it unlocked): the agent
        calls it only while it builds the field, before any frame follows it (vsfleet.structure, where the first plan
        is the room's own lattice); elsewhere its first frame with no way on the room's own lattice builds it."""
        if self.refine is None:
            return False
        if self.handle is not None:
            return _core.field_refine_now(self.handle)
        return self.fine() is not None

    @property
    def refined(self) -> bool:
        """Whether the finer lattice is built (asking does not build it)."""
        if self.handle is not None:
            return _core.field_refined(self.handle)
        return self._fine is not None

    def fine(self) -> "Field | None":
        """A reference field's finer lattice, built on first use (None: none; a core field's lives in the core,
        which the reference functions do not read: give them a reference field)."""
        if self._fine is None and self._fine_build is not None:
            self._fine = self._fine_build()
        return self._fine


def build_field(template_xy, radius_m, margin_m: float, obstacles, goal: Pose2, cell_m: float = CELL_M,
                n_headings: int = HEADINGS, max_states: int = MAX_STATES, deferred: bool = False,
                refine: tuple[int, int] | None = None, provisional: bool = False) -> Field:
    """The compiled core's field (vs_field_build); costs read back lazily by tests only. deferred: the components
    the goal cannot reach are resolved when a descent first needs one (vs_field_build_deferred): every descent the
    same, the build several times faster in rooms with walls. refine (n_headings, max_states): the finer lattice of
    the same room (at cell_m) asked where this one has no way from a pose (vs_field_set_refine; field_refinement).
    provisional: a first plan, which the step holds where it has no way (vs_field_set_provisional; first_lattice)."""
    handle = _core.field_build(f64(template_xy), f64(radius_m), float(margin_m), f64(obstacles), f64(goal.as_tuple()),
                               float(cell_m), int(n_headings), int(max_states), bool(deferred))
    if refine is not None:
        _core.field_set_refine(handle, f64(template_xy), f64(radius_m), f64(obstacles), float(cell_m),
                               int(refine[0]), int(refine[1]))
    if provisional:
        _core.field_set_provisional(handle)
    lat = Lattice(*_core.field_info(handle))
    fld = Field(lat, _CoreCosts(handle, lat), handle, refine)
    fld.provisional = bool(provisional)
    return fld


def build_field_deferred(template_xy, radius_m, margin_m: float, obstacles, goal: Pose2, cell_m: float = CELL_M,
                         n_headings: int = HEADINGS, max_states: int = MAX_STATES,
                         refine: tuple[int, int] | None = None, provisional: bool = False) -> Field:
    """build_field(deferred=True): the agent's build (vsfleet.agentstate)."""
    return build_field(template_xy, radius_m, margin_m, obstacles, goal, cell_m, n_headings, max_states, deferred=True,
                       refine=refine, provisional=provisional)


class _CoreCosts:
    """The core's cost array, copied out on first use (tests, plots). A deferred field's copy is as of that use: the
    components a descent resolved later are not in it (vsfleet._core.field_costs reads them afresh)."""

    def __init__(self, handle, lat: Lattice):
        self._handle, self._lat, self._a = handle, lat, None

    def __array__(self, dtype=None, copy=None):
        if self._a is None:
            self._a = np.frombuffer(_core.field_costs(self._handle), dtype=np.uint32).reshape(
                self._lat.n_headings, self._lat.ny, self._lat.nx)
        return self._a if dtype is None else self._a.astype(dtype)


def follow_field(field: Field, pose: Pose2, path_m: float = PATH_M, cap: int = PATH_CAP):
    """(waypoints (k, 3), blocked, left_m) of the core's descent from ``pose`` (vs_field_follow)."""
    out = np.empty((cap, 3))
    k, blocked, left = _core.field_follow(field.handle, np.array(pose.as_tuple(), dtype=float), float(path_m), out)
    return out[:k], blocked, left


# ------------------------------------------------------------------------------------------- reference


def _wrap_outside(th: float) -> float:
    """An angle in [-pi, pi) as it is, any other wrapped (the core's wrap is not the identity inside)."""
    return th if -math.pi <= th < math.pi else _core.wrap_angle(th)


def _floor(v: float) -> int:
    return math.floor(v)


def build_field_reference(template_xy, radius_m, margin_m: float, obstacles, goal: Pose2, cell_m: float = CELL_M,
                          n_headings: int = HEADINGS, max_states: int = MAX_STATES,
                          refine: tuple[int, int] | None = None, provisional: bool = False) -> Field:
    """vs_field_build in numpy and scipy: the same lattice, the same raster, the same integer costs (refine: as
    build_field's, its finer lattice built by the first descent or shape test that asks for it; provisional: as
    build_field's)."""
    if provisional:
        fld = build_field_reference(template_xy, radius_m, margin_m, obstacles, goal, cell_m, n_headings, max_states,
                                    refine)
        fld.provisional = True
        return fld
    if refine is not None:
        fld = build_field_reference(template_xy, radius_m, margin_m, obstacles, goal, cell_m, n_headings, max_states)
        fld.refine = (int(refine[0]), int(refine[1]))
        # the inputs copied now, as the core's vs_field_set_refine copies them
        tpl, rad, obs = (np.array(a, dtype=float) for a in (template_xy, radius_m, obstacles))
        fld._fine_build = lambda: build_field_reference(tpl, rad, margin_m, obs, goal, cell_m, *fld.refine)
        return fld
    from scipy.sparse.csgraph import connected_components, dijkstra  # noqa: PLC0415 - the reference only
    if not (4 <= n_headings <= 1024 and 1024 <= max_states <= 1_000_000_000 and 9 * n_headings <= max_states):
        raise VsfleetValueError("build_field: n_headings in [4, 1024], max_states in [1024, 1e9] and >= 9 n_headings")
    tpl = np.asarray(template_xy, dtype=float).reshape(-1, 2)
    rad = np.asarray(radius_m, dtype=float).reshape(-1)
    obs = np.asarray(obstacles, dtype=float).reshape(-1, 3)
    # the core's own checks (vs_field_build: VS_EVALUE / VS_ENONFINITE): the raster's windows below rely on radii
    # and the margin >= 0 and obstacles of radius > 0 (then a wall's bound is within the tight bound)
    finite = all(np.isfinite(a).all() for a in (tpl, rad, obs)) and math.isfinite(margin_m) and math.isfinite(cell_m)
    if len(tpl) == 0 or len(rad) != len(tpl) or not finite or not (margin_m >= 0.0) or not (cell_m >= 1e-3) \
            or not (rad >= 0.0).all() or not (obs[:, 2] > 0.0).all():
        raise VsfleetValueError("build_field: at least one robot, finite inputs, radii and margin >= 0, obstacles of "
                                "radius > 0, cell >= 1 mm")
    gx, gy, gth = goal.x, goal.y, _wrap_outside(goal.th)
    K = int(n_headings)
    dth = (2.0 * math.pi) / K
    sized = lattice_sizing(tpl, rad, margin_m, obs, (gx, gy), K, cell_m, max_states)
    if sized is None:
        raise VsfleetValueError("build_field: the room does not fit max_states")
    h, infl, ix0, ix1, iy0, iy1, pmax = sized
    nx, ny = ix1 - ix0 + 1, iy1 - iy0 + 1
    w_rot = max(1, _floor(float(W_AXIS) * (pmax * dth) / h + 0.5))
    lattice_x = gx + np.arange(ix0, ix1 + 1, dtype=float) * h      # (nx,)
    lattice_y = gy + np.arange(iy0, iy1 + 1, dtype=float) * h      # (ny,)
    wall = np.zeros((K, ny, nx), dtype=bool)
    tight = np.zeros((K, ny, nx), dtype=bool)
    # body i's centre at heading k, every k at once: the core's own sine and cosine (the same bits on every host)
    c = np.array([_core.cos(gth + k * dth) for k in range(K)])
    s = np.array([_core.sin(gth + k * dth) for k in range(K)])
    for i in range(len(tpl)):
        qx, qy = c * tpl[i, 0] - s * tpl[i, 1], s * tpl[i, 0] + c * tpl[i, 1]          # (K,)
        bx, by = lattice_x[None, :] + qx[:, None], lattice_y[None, :] + qy[:, None]    # (K, nx), (K, ny)
        px, py = float(tpl[i, 0]), float(tpl[i, 1])
        arm = math.sqrt(px * px + py * py)           # the body's arc radius when the structure turns
        chord = arm * dth                            # >= a turn edge's chord
        sagitta = (arm * (dth * dth)) / 8.0          # >= the arc's bulge beyond it
        for o in obs:
            # the exact bound of the edges: a move keeps `need` where both ends keep sqrt(need^2 + h^2 / 2), a turn
            # where both keep sqrt((need + sagitta)^2 + chord^2 / 4)
            need = (float(rad[i]) + float(o[2])) + margin_m
            move2 = need * need + (h * h) / 2.0
            bulge = need + sagitta
            turn2 = bulge * bulge + (chord * chord) / 4.0
            w2 = turn2 if turn2 > move2 else move2
            rho_tight = math.sqrt(w2) + COMFORT_M
            r2 = rho_tight * rho_tight
            dx, dy = bx - o[0], by - o[1]
            # a state is a wall where d2 = dy^2 + dx^2 < w2 (tight: < rho_tight^2). Only the window where
            # dx^2 and dy^2 are each below rho_tight^2 at some heading can hold one: rounding is monotonic, so d2
            # is never below either term. The same bits as the whole lattice, at a fraction of the cost.
            cols, rows = np.flatnonzero((dx * dx < r2).any(axis=0)), np.flatnonzero((dy * dy < r2).any(axis=0))
            if cols.size == 0 or rows.size == 0:
                continue
            r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
            dxw, dyw = dx[:, c0:c1], dy[:, r0:r1]
            d2 = dyw[:, :, None] * dyw[:, :, None] + dxw[:, None, :] * dxw[:, None, :]   # (K, rows, cols)
            wall[:, r0:r1, c0:c1] |= d2 < w2
            tight[:, r0:r1, c0:c1] |= d2 < r2
    tight &= ~wall
    free = ~wall.ravel()
    tight_flat = tight.ravel()
    graph = _graph(K, ny, nx, free, tight_flat, w_rot)
    total = K * ny * nx
    goal_state = (-iy0) * nx + (-ix0)
    dist = np.full(total, np.inf)
    reached = np.zeros(total, dtype=bool)
    if free[goal_state]:
        dist = dijkstra(graph, directed=False, indices=goal_state)
        reached = np.isfinite(dist)
    # every component the goal cannot reach leads to its state nearest the goal (lattice distance, then index)
    rest = np.flatnonzero(free & ~reached)
    if rest.size:
        _, labels = connected_components(graph, directed=False)
        rem = rest % (ny * nx)
        col, row = rem % nx + ix0, rem // nx + iy0
        d2 = col.astype(np.int64) ** 2 + row.astype(np.int64) ** 2
        order = np.lexsort((rest, d2))                    # by d2, then index
        # each component's first state in that order (np.unique's index is of a label's first occurrence)
        _, first = np.unique(labels[rest[order]], return_index=True)
        targets = rest[order[np.sort(first)]].tolist()
        d_blocked = dijkstra(graph, directed=False, indices=targets, min_only=True)
        dist = np.where(reached, dist, d_blocked)
    costs = np.full(total, WALL, dtype=np.uint32)
    cost = np.where(free, dist, 0).astype(np.uint32)
    cost |= np.where(tight_flat, TIGHT_BIT, 0).astype(np.uint32)
    cost |= np.where(reached, 0, BLOCKED_BIT).astype(np.uint32)
    costs[free] = cost[free]
    lat = Lattice(gx, gy, gth, h, dth, infl, K, ix0, iy0, nx, ny, w_rot, bool(free[goal_state]))
    return Field(lat, costs.reshape(K, ny, nx))


def _graph(K: int, ny: int, nx: int, free: np.ndarray, tight: np.ndarray, w_rot: int):
    """The lattice's edges between free states as a sparse matrix (each edge once; weights doubled where
    an end is tight)."""
    from scipy.sparse import coo_matrix  # noqa: PLC0415 - the reference only (agents never import scipy)
    idx = np.arange(K * ny * nx, dtype=np.int32).reshape(K, ny, nx)   # the matrix's index type (max_states < 2^31)
    free3, tight3 = free.reshape(K, ny, nx), tight.reshape(K, ny, nx)
    rows, cols, ws = [], [], []

    def ends(where) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The states at ``where`` (a view of the lattice): their indices, free and tight flags."""
        return idx[where], free3[where], tight3[where]

    def add(a, b, w: int) -> None:
        """An edge from each state of view a to the state at the same place of view b, where both are free;
        a boolean mask picks in C order (the states' order)."""
        (ia, fa, ta), (ib, fb, tb) = a, b
        keep = fa & fb
        rows.append(ia[keep])
        cols.append(ib[keep])
        ws.append(np.where(ta[keep] | tb[keep], float(2 * w), float(w)))

    add(ends(np.s_[:, :, :-1]), ends(np.s_[:, :, 1:]), W_AXIS)
    add(ends(np.s_[:, :-1, :]), ends(np.s_[:, 1:, :]), W_AXIS)
    add(ends(np.s_[:, :-1, :-1]), ends(np.s_[:, 1:, 1:]), W_DIAG)
    add(ends(np.s_[:, :-1, 1:]), ends(np.s_[:, 1:, :-1]), W_DIAG)
    add(ends(np.s_[:]), tuple(np.roll(x, -1, axis=0) for x in (idx, free3, tight3)), w_rot)   # heading k to k + 1
    n = K * ny * nx
    return coo_matrix((np.concatenate(ws), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)).tocsr()


def _axis_index(u: float, lo: int, count: int) -> tuple[int, bool]:
    """The column (row) of u = coordinate / h + 0.5 on an axis of ``count`` from ``lo``, clamped (and whether)."""
    if not u >= lo:
        return 0, True
    if u >= lo + count:
        return count - 1, True
    return math.floor(u) - lo, False


def _nearest(lat: Lattice, x: float, y: float, th: float) -> tuple[int, int, int, bool]:
    c, out_c = _axis_index((x - lat.gx) / lat.cell_m + 0.5, lat.ix_lo, lat.nx)
    r, out_r = _axis_index((y - lat.gy) / lat.cell_m + 0.5, lat.iy_lo, lat.ny)
    k = math.floor(_core.wrap_angle(th - lat.gth) / lat.dth_rad + 0.5) % lat.n_headings
    return c, r, k, out_c or out_r


def _state_pose(lat: Lattice, s: int) -> tuple[float, float, float]:
    plane = lat.nx * lat.ny
    k, rem = divmod(s, plane)
    return (lat.gx + float(rem % lat.nx + lat.ix_lo) * lat.cell_m, lat.gy + float(rem // lat.nx + lat.iy_lo) * lat.cell_m,
            _wrap_outside(lat.gth + float(k) * lat.dth_rad))


def _neighbours(lat: Lattice, s: int):
    plane = lat.nx * lat.ny
    k, rem = divmod(s, plane)
    r, c = divmod(rem, lat.nx)
    for j in range(8):
        cc, rr = c + _DX[j], r + _DY[j]
        if 0 <= cc < lat.nx and 0 <= rr < lat.ny:
            yield k * plane + rr * lat.nx + cc, (W_AXIS if j < 4 else W_DIAG)
    yield ((k + 1) % lat.n_headings) * plane + rem, lat.w_rot
    yield ((k - 1) % lat.n_headings) * plane + rem, lat.w_rot


def _descend(lat: Lattice, cost: np.ndarray, s: int):
    """The neighbour a descent from state s takes and its edge's weight (None, 0 at the goal or at a local minimum).
    cost: _cost_view's (its items are Python ints)."""
    vs = cost[s]
    cs = vs & COST_MASK
    if cs == 0:
        return None, 0
    best, best_v, best_w = None, 0, 0
    for t, w in _neighbours(lat, s):
        ct = cost[t]
        if ct == WALL or (ct & COST_MASK) >= cs:
            continue
        if (vs | ct) & TIGHT_BIT:
            w *= 2
        v = (ct & COST_MASK) + w
        if best is None or v < best_v:
            best, best_v, best_w = t, v, w
    return best, best_w


def _start_state(lat: Lattice, cost: np.ndarray, pose: Pose2) -> tuple[int | None, bool]:
    """Where a descent from ``pose`` starts (vs_field.c start_state), among the free states within SEARCH_CELLS
    cells of it (ring 0: the pose's own cell), at the nearest heading and two either side: of the nearest ring that
    has one the goal can be reached from, the cheapest such; else of the nearest ring that has any free state, the
    cheapest (whose cost is to its own component's end); None if none; and whether the pose lies outside the
    lattice."""
    plane = lat.nx * lat.ny
    c0, r0, k0, outside = _nearest(lat, pose.x, pose.y, pose.th)
    start, start_v, start_b, start_d = None, 0, 0, 0
    for d in range(SEARCH_CELLS + 1):
        for dk in (0, 1, -1, 2, -2):
            k = (k0 + lat.n_headings + dk) % lat.n_headings
            for dr in range(-d, d + 1):
                for dc in range(-d, d + 1):
                    if abs(dr) != d and abs(dc) != d:
                        continue
                    c, r = c0 + dc, r0 + dr
                    if not (0 <= c < lat.nx and 0 <= r < lat.ny):
                        continue
                    s = k * plane + r * lat.nx + c
                    if int(cost[s]) == WALL:
                        continue
                    v = int(cost[s]) & COST_MASK
                    b = 1 if int(cost[s]) & BLOCKED_BIT else 0
                    if start is not None and b and (not start_b or start_d < d):
                        continue     # a reachable one, or a blocked one of a nearer ring, stands
                    if start is None or b < start_b or (b == start_b and v < start_v):
                        start, start_v, start_b, start_d = s, v, b, d
        if start is not None and not start_b:
            break
    return start, outside


def _cost_view(field: Field) -> memoryview:
    """The field's costs, one state after another, as Python ints when indexed (what int(costs[s]) gives, at a
    third of the cost of indexing the array: a descent reads a few hundred states)."""
    return memoryview(np.ascontiguousarray(np.asarray(field.costs), dtype=np.uint32).reshape(-1))


def field_open_reference(field: Field, pose: Pose2) -> tuple[bool, bool]:
    """vs_field_open in Python: (the descent from the pose starts on a free state the goal can be reached from,
    that state lies in the comfort band); where it does not, the finer lattice's answer if that one is open."""
    answer = _open_one(field, pose)
    fine = field.fine() if not answer[0] else None
    if fine is not None:
        fine_answer = _open_one(fine, pose)
        if fine_answer[0]:
            return fine_answer
    return answer


def _open_one(field: Field, pose: Pose2) -> tuple[bool, bool]:
    cost = _cost_view(field)
    start, _outside = _start_state(field.lattice, cost, pose)
    if start is None:
        return False, False
    v = int(cost[start])
    return not v & BLOCKED_BIT, bool(v & TIGHT_BIT)


def follow_field_reference(field: Field, pose: Pose2, path_m: float = PATH_M, cap: int = PATH_CAP):
    """vs_field_follow in Python: (waypoints (k, 3), blocked, left_m); where the goal cannot be reached from the
    pose, the finer lattice's descent if the goal can be reached from it there (vs_field_set_refine)."""
    answer = _follow_one(field, pose, path_m, cap)
    fine = field.fine() if answer[1] else None
    if fine is not None and _open_one(fine, pose)[0]:
        return _follow_one(fine, pose, path_m, cap)
    return answer


def _follow_one(field: Field, pose: Pose2, path_m: float, cap: int):
    lat = field.lattice
    cost = _cost_view(field)
    start, outside = _start_state(lat, cost, pose)
    way = [pose.as_tuple()]
    if start is None:
        return np.array(way), True, math.sqrt((lat.gx - pose.x) ** 2 + (lat.gy - pose.y) ** 2)
    blocked = bool(int(cost[start]) & BLOCKED_BIT)
    s = start
    way.append(_state_pose(lat, s))
    run = 0.0
    while len(way) < cap and run < path_m:
        t, w = _descend(lat, cost, s)
        if t is None:
            break
        s = t
        way.append(_state_pose(lat, s))
        run += float(min(w, 2 * W_DIAG)) / float(W_AXIS) * lat.cell_m
    want = BLOCKED_BIT if blocked else 0
    for j in range(len(way) - 1, 1, -1) if not outside else ():
        if _segment_clear(lat, cost, way[0], way[j], want):
            way = [way[0]] + way[j:]
            break
    left = 0.0
    if blocked:
        u = s
        while True:
            t, _ = _descend(lat, cost, u)
            if t is None:
                break
            u = t
        ex, ey, _ = _state_pose(lat, u)
        left = math.sqrt((lat.gx - ex) * (lat.gx - ex) + (lat.gy - ey) * (lat.gy - ey))
    return np.array(way), blocked, left


def _segment_clear(lat: Lattice, cost: np.ndarray, a, b, want: int) -> bool:
    dx, dy, dth = b[0] - a[0], b[1] - a[1], _core.wrap_angle(b[2] - a[2])
    steps_xy = math.sqrt(dx * dx + dy * dy) / (0.5 * lat.cell_m)
    steps_th = abs(dth) / (0.5 * lat.dth_rad)
    m = _floor(max(steps_xy, steps_th)) + 1
    nx, plane = lat.nx, lat.nx * lat.ny
    (ax, ay, ath), nearest = a, _nearest
    for i in range(m + 1):
        t = i / m
        c, r, k, _ = nearest(lat, ax + dx * t, ay + dy * t, ath + dth * t)
        v = cost[k * plane + r * nx + c]   # a Python int (_cost_view)
        if v == WALL or (v & TIGHT_BIT) or (v & BLOCKED_BIT) != want:
            return False
    return True
