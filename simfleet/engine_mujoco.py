"""The MuJoCo engine: each simulated robot a rigid differential-drive body on a floor (docs/engine.md).

Built from the scenario (vsfleet.scenario.SimRobot), one body per robot on a free joint:

- a chassis: a cylinder of the robot's ``radius`` (a point robot: just wide enough to cover its wheels),
  ``CHASSIS_HEIGHT_M`` tall, ``CHASSIS_CLEARANCE_M`` above the floor; the only geometry that touches
  other robots and obstacles;
- two driven wheels on hinges, ``wheel_base`` apart, on the axle through the tracked point (the pose
  the tracker reports). Their true radii are ``wheel_radius * gain`` (left, right): the scenario's gains,
  true/commanded wheel speed, become a mismatch of wheel radii. Each is driven by a velocity servo
  (MuJoCo's ``velocity`` actuator, time constant ``SERVO_TAU_S``) on the wheel's share of the mass and its
  rotor (``ROTOR_INERTIA``), its torque limited to accelerate that at ``MOTOR_ACCEL_G`` g;
  its set point is the wheel speed physics.applied_wheels gives (gains, faults, speed and acceleration
  limits, a stale command braking to rest), over the wheel's true radius;
- two passive casters, frictionless balls (contact normal only) fore and aft;
- wheels and casters meet the floor with MuJoCo's stiffest safe contact (time constant two steps): the
  default (20 ms) let a wheel creep against the floor (2 mm behind the kinematic engine over a 0.4 m run);
- ``mass`` split chassis 80 %, wheels 7 % each, casters 3 % each; wheel-floor friction ``friction``.

Obstacles of the mission are static cylinders ``OBSTACLE_HEIGHT_M`` tall. Physics steps at the
scenario's sim rate (one mj_step per step, implicit-in-velocity integration).

The pose reported is the body's frame: the axle's midpoint (x, y) and its heading; the wheel speeds
reported are those of the wheels' rims, measured (joint speed x true radius), so a wheel that spins
or stalls against an obstacle says so. Contacts between bodies (robot-robot, robot-obstacle; never a
wheel or caster on the floor) are reported when they begin: a pair that touches again within
``CONTACT_GAP_S`` of its last touch continues the same contact.
"""

from __future__ import annotations

import math
from xml.sax.saxutils import quoteattr

import mujoco
import numpy as np

from .physics import Contact, FaultArrays, FleetParams, applied_wheels

GRAVITY_M_S2 = 9.81
CHASSIS_HEIGHT_M = 0.04
CHASSIS_CLEARANCE_M = 0.005
OBSTACLE_HEIGHT_M = 0.2
WHEEL_WIDTH_M = 0.01
CASTER_RADIUS_FRACTION = 0.4   # of the nominal wheel radius
MOTOR_ACCEL_G = 0.5            # each wheel's torque limit: half the robot's mass accelerated at this [g]
SERVO_TAU_S = 0.005            # the velocity servo's time constant on the robot's mass [s]
ROTOR_INERTIA = 0.5            # each wheel's motor and gear inertia (armature), as a share of mass * wheel_radius^2
BODY_FRICTION = 0.3            # chassis against chassis or obstacle (sliding)
FLOOR_FRICTION = 0.1           # the floor's own (MuJoCo takes the larger of two geoms': the wheels')
SETTLE_S = 0.2                 # bodies settle on the floor, wheels held, before the start pose is set
CONTACT_GAP_S = 0.1            # a pair apart for less than this and touching again: the same contact
MASS_SHARE = {"chassis": 0.80, "wheel": 0.07, "caster": 0.03}

_ROBOT, _OBSTACLE = 1, 2  # contype/conaffinity bits: bodies and obstacles touch each other; wheels, floor


def body_radius(robot) -> float:
    """The chassis radius [m]: the robot's ``radius``, or (a point robot) its wheels' outer edge."""
    return robot.radius if robot.radius is not None else robot.wheel_base / 2 + WHEEL_WIDTH_M / 2


def _f(*values: float) -> str:
    return quoteattr(" ".join(repr(float(v)) for v in values))


def _robot_xml(r, dt_s: float) -> str:
    m, rw = r.mass, r.wheel_radius
    rl, rr = (rw * g for g in r.gain)
    rb = body_radius(r)
    rc = CASTER_RADIUS_FRACTION * rw
    xc = 0.6 * rb
    zc = CHASSIS_CLEARANCE_M + CHASSIS_HEIGHT_M / 2 - rw  # the chassis' centre, in the body frame (axle height rw)
    x, y, th = r.start
    mu = r.friction
    wheels = []
    for side, ys, rad in (("left", 1.0, rl), ("right", -1.0, rr)):
        wheels.append(
            f'<body name="{r.robot}/{side}" pos={_f(0.0, ys * r.wheel_base / 2, rad - rw)}>'
            f'<joint name="{r.robot}/{side}" type="hinge" axis="0 1 0" armature={_f(_armature(r))}/>'
            f'<geom name="{r.robot}/{side}" type="sphere" size={_f(rad)} '
            f'mass={_f(MASS_SHARE["wheel"] * m)} contype="{_ROBOT << 2}" conaffinity="0" condim="3" priority="1" '
            f'solref={_f(2 * dt_s, 1.0)} '
            f'friction={_f(mu, 0.005, 0.0001)}/></body>')
    casters = "".join(
        f'<geom name="{r.robot}/caster{k}" type="sphere" size={_f(rc)} pos={_f(sx * xc, 0.0, rc - rw)} '
        f'mass={_f(MASS_SHARE["caster"] * m)} contype="{_ROBOT << 2}" conaffinity="0" condim="1" priority="1" '
        f'solref={_f(2 * dt_s, 1.0)}/>'
        for k, sx in enumerate((1.0, -1.0)))
    return (f'<body name={quoteattr(r.robot)} pos={_f(x, y, rw)} euler={_f(0.0, 0.0, th)}>'
            f'<freejoint name="{r.robot}/free"/>'
            f'<geom name="{r.robot}/chassis" type="cylinder" size={_f(rb, CHASSIS_HEIGHT_M / 2)} pos={_f(0.0, 0.0, zc)} '
            f'mass={_f(MASS_SHARE["chassis"] * m)} contype="{_ROBOT}" conaffinity="{_ROBOT | _OBSTACLE}" '
            f'friction={_f(BODY_FRICTION, 0.005, 0.0001)}/>'
            + "".join(wheels) + casters + "</body>")


def _armature(r) -> float:
    """A wheel's reflected motor and gear inertia [kg m^2]. Besides being there on a geared robot, it
    keeps MuJoCo's soft friction stiff: with a bare wheel's tiny inertia the contact crept (the body ran
    50 % ahead of its wheels while speeding up)."""
    return ROTOR_INERTIA * r.mass * r.wheel_radius ** 2


def _actuators_xml(r) -> str:
    # the servo: torque = kv (set point - joint speed) [N m], on the wheel's inertia: its share of the
    # mass at its radius and the rotor's; its torque limit accelerates that at MOTOR_ACCEL_G
    inertia = r.mass * r.wheel_radius ** 2 / 2 + _armature(r)
    kv = inertia / SERVO_TAU_S
    torque = MOTOR_ACCEL_G * GRAVITY_M_S2 * inertia / r.wheel_radius
    return "".join(f'<velocity name="{r.robot}/{side}" joint="{r.robot}/{side}" kv={_f(kv)} '
                   f'forcelimited="true" forcerange={_f(-torque, torque)}/>' for side in ("left", "right"))


def model_xml(robots, obstacles, dt_s: float) -> str:
    """The MJCF scene of ``robots`` (SimRobot) among ``obstacles`` [(x, y, r)], stepped every dt_s [s]."""
    obs = "".join(f'<geom name="obstacle/{k}" type="cylinder" size={_f(ro, OBSTACLE_HEIGHT_M / 2)} '
                  f'pos={_f(ox, oy, OBSTACLE_HEIGHT_M / 2)} contype="{_OBSTACLE}" conaffinity="{_ROBOT}" '
                  f'friction={_f(BODY_FRICTION, 0.005, 0.0001)}/>'
                  for k, (ox, oy, ro) in enumerate(obstacles))
    return (f'<mujoco model="vsfleet"><compiler angle="radian" autolimits="true"/>'
            f'<option timestep={_f(dt_s)} integrator="implicitfast" gravity={_f(0.0, 0.0, -GRAVITY_M_S2)}/>'
            f'<worldbody><geom name="floor" type="plane" size="0 0 1" contype="0" conaffinity="{_ROBOT << 2}" '
            f'friction={_f(FLOOR_FRICTION, 0.005, 0.0001)}/>{obs}'
            + "".join(_robot_xml(r, dt_s) for r in robots)
            + "</worldbody><actuator>" + "".join(_actuators_xml(r) for r in robots) + "</actuator></mujoco>")


def _yaw(quat: np.ndarray) -> np.ndarray:
    w, x, y, z = quat[:, 0], quat[:, 1], quat[:, 2], quat[:, 3]
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


class MujocoEngine:
    """The fleet in MuJoCo (simfleet/engine.py's interface). Deterministic: the same robots, obstacles,
    step and inputs give the same poses, bit for bit, in one process."""

    name = "mujoco"

    def __init__(self, robots, obstacles, dt_s: float) -> None:
        robots = list(robots)
        for r in robots:
            if min(r.gain) <= 0.0:
                raise ValueError(f"robot {r.robot}: the mujoco engine makes gains wheel radii, so each must be "
                                 f"> 0, got {tuple(r.gain)}")
        self.ids = tuple(r.robot for r in robots)
        self.obstacles = tuple(tuple(map(float, o)) for o in obstacles)
        self.dt_s = dt_s
        self.params = FleetParams.of(robots)
        self.model = mujoco.MjModel.from_xml_string(model_xml(robots, self.obstacles, dt_s))
        self.data = mujoco.MjData(self.model)
        m = self.model
        jid = lambda name: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)  # noqa: E731
        aid = lambda name: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, name)  # noqa: E731
        self._qpos = np.array([m.jnt_qposadr[jid(f"{r}/free")] for r in self.ids], dtype=int)
        self._qvel = np.array([m.jnt_dofadr[jid(f"{r}/free")] for r in self.ids], dtype=int)
        self._wheel_dof = np.array([[m.jnt_dofadr[jid(f"{r}/{s}")] for s in ("left", "right")] for r in self.ids],
                                   dtype=int).reshape(-1, 2)
        self._act = np.array([[aid(f"{r}/{s}") for s in ("left", "right")] for r in self.ids],
                             dtype=int).reshape(-1, 2)
        self.radius_true = np.array([[r.wheel_radius * g for g in r.gain] for r in robots], dtype=float).reshape(-1, 2)
        # which body each geom is: robot row (chassis), len(robots) + k (obstacle k), -1 (floor, wheels, casters)
        self._entity = np.full(m.ngeom, -1, dtype=int)
        for i, r in enumerate(self.ids):
            self._entity[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"{r}/chassis")] = i
        for k in range(len(self.obstacles)):
            self._entity[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"obstacle/{k}")] = len(self.ids) + k
        self.setpoint = np.zeros((len(self.ids), 2))  # the wheels' set points [m/s, ground speed]
        self.contacts: list[Contact] = []
        self._last_touch: dict[tuple[int, int], int] = {}  # entity pair -> the step it last touched
        self._gap_steps = max(1, round(CONTACT_GAP_S / dt_s))
        self.k = 0
        self.max_depth_m = 0.0
        self._settle([r.start for r in robots])
        self._read()

    def _settle(self, starts) -> None:
        """Let the bodies come to rest on the floor (wheels held), then put each exactly at its start
        (x, y, heading; its settled height and tilt kept), at rest."""
        d = self.data
        d.ctrl[:] = 0.0
        for _ in range(max(1, round(SETTLE_S / self.dt_s))):
            mujoco.mj_step(self.model, d)
        for i, (x, y, th) in enumerate(starts):
            a = self._qpos[i]
            q = d.qpos[a + 3:a + 7].copy()
            dz = th - float(_yaw(q[None, :])[0])
            turn = np.array([math.cos(dz / 2), 0.0, 0.0, math.sin(dz / 2)])
            out = np.empty(4)
            mujoco.mju_mulQuat(out, turn, q)
            d.qpos[a:a + 2] = (x, y)
            d.qpos[a + 3:a + 7] = out / np.linalg.norm(out)
        d.qvel[:] = 0.0
        d.qacc_warmstart[:] = 0.0
        d.time = 0.0
        mujoco.mj_forward(self.model, d)

    def _read(self) -> None:
        d = self.data
        q = d.qpos
        self.pose = np.stack([q[self._qpos], q[self._qpos + 1],
                              _yaw(q[self._qpos[:, None] + np.arange(3, 7)])], axis=1)
        self.wheels = d.qvel[self._wheel_dof] * self.radius_true

    def step(self, cmd_m_s: np.ndarray, cmd_fresh: np.ndarray, faults: FaultArrays, t: float) -> list[Contact]:
        """One physics step at sim time t [s]; returns the contacts that began in it."""
        self.setpoint = applied_wheels(self.setpoint, cmd_m_s, cmd_fresh, faults, self.params, t, self.dt_s)
        self.data.ctrl[self._act] = self.setpoint / self.radius_true
        mujoco.mj_step(self.model, self.data)
        self.k += 1
        self._read()
        return self._new_contacts(t)

    def _new_contacts(self, t: float) -> list[Contact]:
        d = self.data
        if d.ncon == 0:
            return []
        ent = self._entity[d.contact.geom[:d.ncon]]
        hits = np.flatnonzero((ent[:, 0] >= 0) & (ent[:, 1] >= 0))
        if hits.size == 0:
            return []
        n = len(self.ids)
        new = []
        for c in hits:
            a, b = sorted(int(e) for e in ent[c])
            depth = max(0.0, -float(d.contact.dist[c]))
            self.max_depth_m = max(self.max_depth_m, depth)
            last = self._last_touch.get((a, b))
            self._last_touch[(a, b)] = self.k
            if last is not None and self.k - last <= self._gap_steps:
                continue
            x, y = (float(v) for v in d.contact.pos[c, :2])
            other, kind = (self.ids[b], "robot") if b < n else (b - n, "obstacle")
            new.append(Contact(t=t, robot=self.ids[a], other=other, kind=kind, x=x, y=y, depth_m=depth))
        self.contacts.extend(new)
        return new
