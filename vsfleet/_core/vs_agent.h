/* vs_agent.h - the agent's decision at one frame, past its frame's poses: one call into the core.
 *
 * vsfleet.step.agent_step is the readable reference; this code computes the same bits for the part
 * of it that runs on every frame once the frame is known to be of the mission in force, not stale,
 * and of a mission that names this robot (those checks, a change of mission, the notes and the
 * events' wording stay in Python, which calls this once per frame):
 *   - a gap longer than ttl_s since the last command: every robot has halted, so the previous
 *     commands are zero and the controller starts afresh; a gap longer than resync_gap_s since the
 *     last frame: the failure timers, the motion window and (unless stalled) the stall watch restart
 *     (out->resynced);
 *   - the structure step (vs_step.h): fit, plan, advance, shape, deviations;
 *   - with bodies, the assembly tie-break (vs_assembly_targets);
 *   - every robot's command by the mission's controller (vs_control.h), the deadband of Held
 *     around it when deadband_m > 0, zero for robots not driven;
 *   - in a room (bodies or obstacles), every robot's command through the fleet-wide safety filter
 *     (vs_safety.h) over the robots seen; a robot whose command it changed, or sent round another
 *     robot, is held (the failure rule's assembly phase);
 *   - the motion each robot's command should make (vs_kin.h), and the failure rule (vs_failure.h);
 *   - the room's stall watch (vsfleet.step.stall_state) and whether the structure turned blocked or
 *     went on again (an event), and its shape.
 *
 * Units and frames as vscore.h: times [s] on the tracker's clock, lengths [m], poses [m, m, rad;
 * world], wheel speeds [m/s]; rows are robots in the mission's sorted id order.
 */
#ifndef VS_AGENT_H
#define VS_AGENT_H

#include <stddef.h>

#include "vscore.h"
#include "vs_control.h"
#include "vs_failure.h"
#include "vs_safety.h"
#include "vs_step.h"

/* the controllers (vsfleet.control.CONTROLLERS), as the agent's config names them */
#define VS_AGENT_PRECISION 0
#define VS_AGENT_TURN_THEN_GO 1
#define VS_AGENT_ARC 2
#define VS_AGENT_TRACKING 3

/* the stall watch (vsfleet.step.stall_state): stuck after VS_AGENT_STALL_S [s] of the safety filter changing
 * commands while the structure stays within VS_AGENT_STALL_MOVE_M [m] and VS_AGENT_STALL_TURN_RAD [rad] of
 * where the watch began; going again once it moves more than that within VS_AGENT_STALL_S of the watch's pose
 * (stuck, the watch's pose moves on with the structure every VS_AGENT_STALL_S: a crawl stays stuck) */
#define VS_AGENT_STALL_S 3.0
#define VS_AGENT_STALL_MOVE_M 0.02
#define VS_AGENT_STALL_TURN_RAD 0.05

/* what an agent fixes for a mission (and its process: dt_s, ttl_s, ...) */
typedef struct {
    const vs_mission *mission;
    size_t own;                          /* this agent's robot: its row */
    int controller;                      /* VS_AGENT_* */
    vs_precision_gains precision;        /* VS_AGENT_PRECISION */
    vs_turn_then_go_gains turn_then_go;  /* VS_AGENT_TURN_THEN_GO */
    double arc_horizon_s;                /* VS_AGENT_ARC [s] */
    vs_tracking_gains tracking;          /* VS_AGENT_TRACKING */
    double deadband_m;                   /* > 0: vsfleet.control.Held around the controller [m] */
    double still_speed_m_s;              /* Held's resting speed [m/s] */
    vs_failure_policy policy;
    vs_safety_params safety;             /* the safety filter's; its margin_m is also the tie-break's */
    double dt_s;                         /* [s] > 0: the structure's advance per frame */
    double ttl_s;                        /* [s] the commands' time to live */
    double age_s;                        /* [s] observation -> command in effect, compensated */
    double resync_gap_s;                 /* [s] a longer gap between frames restarts the failure timers and the
                                          * stall watch */
    double effective_t;                  /* [s] the mission took effect (the advance's elapsed time) */
    int room;                            /* bodies or obstacles: the safety filter runs */
    int bodies;                          /* some body radius > 0: the assembly tie-break runs */
} vs_agent_config;

/* what an agent carries from one frame to the next (vsfleet.step.AgentState's arrays and numbers), updated
 * in place by vs_agent_step */
typedef struct {
    double *wheels_m_s;                  /* (n, 2) every robot's last command (own sent, others predicted) */
    int ctrl_ready;                      /* 0: the controller starts afresh at the next frame */
    vs_precision_state precision;        /* VS_AGENT_PRECISION's state (unused by the others) */
    vs_failure_state failure;
    double last_frame_t, last_cmd_t;     /* [s]; -inf: none yet */
    int blocked;                         /* the plan's last verdict */
    double stall_since_t;                /* [s] the stall watch: since when (NaN: not watching) */
    int stall_watch;                     /* 1: stall_pose holds where the watch began */
    double stall_pose[3];                /* [m, m, rad; world] */
    int stall_filter;                    /* the safety filter changed a command since the watch began */
    int stalled;
    int shape;                           /* the shape taken at the last frame (0: the template) */
} vs_agent_state;

/* what one frame gives */
typedef struct {
    int ran;                 /* 0: no robot usable: nothing below is written (the state's gap handling is) */
    int resynced;            /* the gap since the last frame restarted the failure timers (and the watch) */
    vs_structure s;          /* the structure of this frame */
    double vl_m_s, vr_m_s;   /* this agent's command */
    int own_seen;            /* its robot was seen: err_m is written */
    double err_m;            /* its robot's distance to its point on the fitted structure [m] */
    int event;               /* 0 none, 1 the structure is blocked or stuck, 2 it goes on again */
    double event_dev_m;      /* [m] how far short of the goal (1: from the plan's end when blocked) */
    int shape_before;        /* the state's shape before this frame */
    size_t n_decisions;      /* the failure rule's decisions, in decisions[0 .. n_decisions) */
} vs_agent_out;

/* Scratch doubles and bytes vs_agent_step needs for n robots (the caller's, sized once per mission). */
#define VS_AGENT_SCRATCH_F64_PER_ROBOT 40
#define VS_AGENT_SCRATCH_U8_PER_ROBOT 12
#define VS_AGENT_SCRATCH_F64(n) (VS_AGENT_SCRATCH_F64_PER_ROBOT * (n))
#define VS_AGENT_SCRATCH_U8(n) (VS_AGENT_SCRATCH_U8_PER_ROBOT * (n))

/* Doubles of workspace the kernels of vs_agent_step_ws need for the mission m (the fit's search tables, the safety
 * filter's rows over its obstacles, the controller's and the kinematics' scratch): a function of m->n, m->metric and
 * m->n_obstacles, so the caller sizes it once, when it adopts the mission.  (size_t)-1: more robots or obstacles
 * than the safety filter takes. */
size_t vs_agent_work_f64(const vs_mission *m);

/* One frame at tracker time t [s]: pose_world (n, 3) read on seen rows (NaN elsewhere allowed), seen and fresh
 * (n) 0/1.  Writes *out, used (n) (the robots the fit used), wheels_out (n, 2) (every robot's command; the
 * state's wheels_m_s then hold them), decisions (cap 2n).  scratch_f64 / scratch_u8: VS_AGENT_SCRATCH_*(n);
 * work: vs_agent_work_f64(cfg->mission) doubles (NULL: VS_EVALUE).  Allocates nothing.
 * Returns VS_OK or the first kernel's error (the state may then be partly advanced: the caller drops it). */
int vs_agent_step_ws(const vs_agent_config *cfg, vs_agent_state *st, const double *pose_world,
                     const unsigned char *seen, const unsigned char *fresh, double t, vs_agent_out *out,
                     unsigned char *used, vs_failure_decision *decisions, double *scratch_f64,
                     unsigned char *scratch_u8, double *work);

/* vs_agent_step_ws with its work allocated and freed in the call (the same results, bit for bit). */
int vs_agent_step(const vs_agent_config *cfg, vs_agent_state *st, const double *pose_world,
                  const unsigned char *seen, const unsigned char *fresh, double t, vs_agent_out *out,
                  unsigned char *used, vs_failure_decision *decisions, double *scratch_f64,
                  unsigned char *scratch_u8);

/* The ttl [s] of the command answering a frame taken at frame_t [s, tracker clock] and sent at now_s [s, this host's
 * clock]: cfg->ttl_s, cut where the safety filter's guarantee for that command ends when the filter runs (cfg->room):
 * 1 / gamma_per_s after the poses were taken.  Over that horizon the barrier's linear bound h(t) >= (1 - gamma t) h
 * stays >= 0 (docs/safety.md); a robot that held the command longer, or applied it later, could move past it.
 * <= 0: the frame is too old to move on, and the agent does not run it, as a stale frame (docs/protocol.md). */
double vs_agent_command_ttl(const vs_agent_config *cfg, double frame_t, double now_s);

#endif
