/* The simulated FER's joint friction inside MuJoCo's step: a passive-force callback (mjcb_passive).
 *
 * MuJoCo's physics callbacks are global to a process, so the parameters live in each model: a joint whose first
 * user number (jnt_user[j][0]) is FVS_TAG carries the friction law of franka_vs_gym.model (per joint, SI units):
 *
 *   jnt_user[j][0..8] = [FVS_TAG, phi1 (Nm), phi2 (s/rad), phi3 (rad/s), viscous (Nm s/rad), coulomb (Nm),
 *                        coulomb_vel (rad/s), stribeck (Nm), stribeck_vel (rad/s)]
 *   tau_f(dq) = phi1 / (1 + exp(-(phi2 dq + phi2 phi3))) - phi1 / (1 + exp(-phi2 phi3))
 *             + viscous dq + coulomb tanh(dq / coulomb_vel)
 *             + stribeck exp(-(dq / stribeck_vel)^2) tanh(dq / coulomb_vel)
 *
 * and the callback adds -tau_f(qvel) to qfrc_passive of that joint's dof. Joints without the tag (other models,
 * robots with the plant's friction switched off) are left alone, so any number of robots in one scene, and any
 * number of models stepped by mujoco.batch on its threads, each get their own law.
 *
 * The same callback runs the robot's measured-state reflexes (franka_vs_gym.sim.reflexes) at every physics step.
 * A robot whose seven joints carry FVS_RTAG in jnt_user[j][FVS_RCOL] (column 9) is watched:
 *
 *   jnt_user[j][9..16] = [FVS_RTAG, slot (offset of the robot's record in userdata), k (joint index 0..6),
 *                         q_min (rad), q_max (rad), dq_max (rad/s), tau_max (Nm), tau_J offset (Nm)]
 *
 * and its record in mjData.userdata (FVS_RSLOT numbers from the slot) is
 *
 *   [status (FVS_ARMED armed, 0 off (a zeroed record), 1 position, 2 velocity, 3 tau_J: the first violation),
 *    t_from (s: only states later than this are checked), check_tau (0/1), t (s), joint k, value (rad, rad/s or
 *    Nm), held q (7, rad)]
 *
 * The callback runs at the start of each step's dynamics, on the state the previous step produced (time t), the
 * state a check after that step would see; d->qfrc_actuator still holds that step's actuator torque (it is
 * recomputed after the passive forces), so the measured torque tau_J = qfrc_actuator + offset is checked too. The
 * checks and their order are those of Reflexes.check_state: position (first joint outside [q_min, q_max]), then
 * velocity (the joint with the largest |dq|/dq_max, if any |dq| > dq_max), then tau_J (largest |tau_J|/tau_max
 * above 1). The first violation is recorded and the brakes engage from that step on: the robot's joints are put
 * back at the held position with zero velocity and its joint actuators' controls are zeroed at every step, as the
 * Python brakes do before every step. Python reads the record after the call and raises the ControlException.
 *
 * The same callback runs the robot interface's rate limiter (franka_vs_gym.sim.rate_limit, libfranka's limitRate)
 * at every physics step, one 1 ms cycle per step, when the record's limiter mode (number FVS_L0) is set:
 *
 *   jnt_user[j][17..25] = [torque rate (Nm/s), acceleration (rad/s^2), jerk (rad/s^3), velocity cap (rad/s),
 *                          offset (rad/s), k (1/s^2), q_upper (rad), q_lower (rad), tolerance (rad/s)]
 *   record[13..65] = [mode (0 off, 1 torque, 2 joint velocity), first motor actuator, first velocity actuator,
 *                     t (s: the time of the last cycle), target (7), before the last cycle: command (7),
 *                     acceleration (7), commanded position (7); after it: command (7), acceleration (7),
 *                     commanded position (7)]
 *
 * A cycle at a new time moves "after" to "before" and computes the next command from it and the target; a second
 * call at the same time (an mj_forward between steps, then a new target) recomputes it from "before", so that only
 * the physics steps advance the limiter. The command is written into the robot's motor (torque) or velocity servo
 * (joint velocity) controls, with the arithmetic of rate_limit.py in the same order (the same bits). A robot whose
 * brakes hold it is not limited.
 *
 * The same callback applies the plant's joint effects that the robot's model does not know (franka_vs_gym.model.
 * joint_effects), at a joint whose column FVS_ECOL (26) holds FVS_ETAG:
 *
 *   jnt_user[j][26..39] = [FVS_ETAG, cogging amplitude A (Nm), cycles per link turn n, phase (rad),
 *                          breakaway torque F_s (Nm), stick velocity v_s (rad/s), transmission stiffness K (Nm/rad,
 *                          0: rigid), transmission damping D (Nm s/rad), motor inertia B (kg m^2), backlash half-gap
 *                          b (rad), joint record offset in userdata, the joint's torque motor (actuator id),
 *                          stick stiffness k_s (Nm/rad), stick damping c (Nm s/rad)]
 *
 * - cogging: tau_c(x) = A sin(n x + phase), resisted by the drive like friction: -tau_c(q) is added to the link's
 *   passive force (rigid joint; the torque sensor sees it), or -tau_c(theta) to the motor (elastic joint).
 * - static friction (an elasto-plastic stick): the joint is tied to an anchor by a stiff spring-damper,
 *   f = -k_s (q - anchor) - c dq, bounded by the breakaway level F_s (1 - tanh(|slip rate| / v_s)); a joint at rest
 *   under any load below F_s holds still (deflected by load / k_s), a larger load slips it: the force is capped
 *   and the anchor follows the joint by the excess (-k_s (q - anchor) - c dq = the cap); while sliding (the
 *   anchor's rate, the slip rate, is the joint's) the cap decays over a few v_s and the friction law above takes
 *   over. k_s and c come from the joint's inertia (a mode of 0.2 / dt, critically damped), so that the explicit
 *   spring is stable.
 * - elastic joint with backlash (Spong's model): the motor (theta, dtheta; inertia B, on the motor side) is driven
 *   by the torque motor's command plus the gravity compensation tau_m; the link feels the transmission torque
 *   tau_t = K dz(theta - q) + s D (dtheta - dq), dz the dead zone of half-width b (b = 0: none) and s = min(1,
 *   |engaged deflection| / (b / 20)) (no damping through an open gap); the callback adds tau_t - tau_m to the
 *   link's passive force (MuJoCo's actuator applies tau_m). The joint velocity servo (motion-generator modes) acts
 *   on the link directly, as without elasticity. The motor is integrated by semi-implicit Euler with the link
 *   (stable for sqrt(K (1/B + 1/M)) dt < 2; the Python side requires <= 1).
 * An elastic or sticking joint's record in userdata: [initialised (0/1), t (s), theta, dtheta at t, theta, dtheta
 *   at t + dt, the correction tau_t - tau_m of the step from t, the correction of the step before, the anchor at
 *   t, the anchor at t + dt, the slip rate of the step before t, the slip rate of the step from t]; a call at a
 *   new time moves "t + dt" to "t" (an mj_forward between steps recomputes from "t" and changes nothing). An
 *   uninitialised record starts at the static deflection tau_m / K (+ b sign(tau_m)) with the link's velocity,
 *   and the anchor at q.
 *
 * The callback reads and writes only its arguments: it is thread-safe and never takes the GIL.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>

#include <mujoco/mujoco.h>

#include "_task.h"

#define FVS_TAG 1179013959.0 /* "FVSG" as an integer, exactly representable */
#define FVS_RTAG 1179013960.0 /* a robot whose reflexes the plant watches */
#define FVS_RCOL 9 /* first reflex column (after the friction law's) */
#define FVS_NUSER 26
#define FVS_RSLOT 66
#define FVS_LCOL 17 /* first rate-limiter column (after the reflexes') */
#define FVS_L0 13 /* the rate limiter's part of a robot's record */
#define FVS_ARMED -1.0 /* record status of a robot whose reflexes the plant checks */
#define FVS_ECOL 26 /* first joint-effect column (after the rate limiter's) */
#define FVS_ETAG 1179013961.0 /* a joint with cogging, static friction or an elastic transmission */
#define FVS_ENUSER 40 /* user numbers per joint with the joint-effect columns */
#define FVS_MREC 12 /* userdata numbers of an elastic or sticking joint's record */

static void fvs_brake(const mjModel* m, mjData* d, int j0, const mjtNum* s) {
  for (int k = 0; k < 7; k++) {
    d->qpos[m->jnt_qposadr[j0 + k]] = s[6 + k];
    d->qvel[m->jnt_dofadr[j0 + k]] = 0.0;
  }
  for (int a = 0; a < m->nu; a++) {
    if (m->actuator_trntype[a] == mjTRN_JOINT) {
      const int jid = m->actuator_trnid[2 * a];
      if (jid >= j0 && jid < j0 + 7) {
        d->ctrl[a] = 0.0;
      }
    }
  }
}

/* The robot whose joints are j0..j0+6 and whose record is at userdata offset off, if its joints carry the reflex
 * columns consistently; else NULL. */
static mjtNum* fvs_record(const mjModel* m, mjData* d, int j0) {
  const mjtSize nu = m->nuser_jnt;
  if (nu < FVS_NUSER || j0 < 0 || j0 + 7 > m->njnt) {
    return NULL;
  }
  const mjtNum* u = m->jnt_user + j0 * nu;
  if (u[FVS_RCOL] != FVS_RTAG || u[FVS_RCOL + 2] != 0.0) {
    return NULL;
  }
  for (int k = 1; k < 7; k++) {
    const mjtNum* uk = m->jnt_user + (j0 + k) * nu;
    if (uk[FVS_RCOL] != FVS_RTAG || uk[FVS_RCOL + 1] != u[FVS_RCOL + 1] || uk[FVS_RCOL + 2] != (mjtNum)k) {
      return NULL;
    }
  }
  const int off = (int)u[FVS_RCOL + 1];
  if (off < 0 || off + FVS_RSLOT > m->nuserdata) {
    return NULL;
  }
  return d->userdata + off;
}

/* Check the armed robot (record s) on the current state; record and brake on the first violation. Returns the
 * reason code (0: within the limits). */
static int fvs_check(const mjModel* m, mjData* d, int j0, mjtNum* s) {
  const mjtSize nu = m->nuser_jnt;
  int code = 0, jk = 0;
  mjtNum value = 0.0;
  for (int k = 0; k < 7; k++) {
    const mjtNum* uk = m->jnt_user + (j0 + k) * nu;
    const mjtNum q = d->qpos[m->jnt_qposadr[j0 + k]];
    if (q < uk[FVS_RCOL + 3] || q > uk[FVS_RCOL + 4]) {
      code = 1, jk = k, value = q;
      break;
    }
  }
  if (!code) {
    mjtNum rmax = -1.0;
    int over = 0;
    for (int k = 0; k < 7; k++) {
      const mjtNum* uk = m->jnt_user + (j0 + k) * nu;
      const mjtNum v = d->qvel[m->jnt_dofadr[j0 + k]];
      const mjtNum r = fabs(v) / uk[FVS_RCOL + 5];
      over |= fabs(v) > uk[FVS_RCOL + 5];
      if (r > rmax) {
        rmax = r, jk = k, value = v;
      }
    }
    if (over) {
      code = 2;
    }
  }
  if (!code && s[2] != 0.0) {
    mjtNum rmax = -1.0;
    for (int k = 0; k < 7; k++) {
      const mjtNum* uk = m->jnt_user + (j0 + k) * nu;
      const mjtNum tau = d->qfrc_actuator[m->jnt_dofadr[j0 + k]] + uk[FVS_RCOL + 7];
      const mjtNum r = fabs(tau) / uk[FVS_RCOL + 6];
      if (r > rmax) {
        rmax = r, jk = k, value = tau;
      }
    }
    if (rmax > 1.0) {
      code = 3;
    }
  }
  if (code) {
    s[0] = code, s[3] = d->time, s[4] = jk, s[5] = value;
    for (int k = 0; k < 7; k++) {
      s[6 + k] = d->qpos[m->jnt_qposadr[j0 + k]];
    }
    fvs_brake(m, d, j0, s);
  }
  return code;
}

mjtNum* fvs_reflex_record(const mjModel* m, mjData* d, int j0) {
  return fvs_record(m, d, j0);
}

int fvs_reflex_check(const mjModel* m, mjData* d, int j0, mjtNum* s) {
  return fvs_check(m, d, j0, s);
}

/* One rate-limiter cycle of the robot (joints j0.., record s); see the header comment. */
static void fvs_limit(const mjModel* m, mjData* d, int j0, mjtNum* s) {
  const mjtSize nu = m->nuser_jnt;
  const int mode = (int)s[FVS_L0];
  mjtNum* target = s + FVS_L0 + 4;
  mjtNum *prev = target + 7, *prev_acc = target + 14, *prev_qd = target + 21;
  mjtNum *now = target + 28, *now_acc = target + 35, *now_qd = target + 42;
  if (d->time != s[FVS_L0 + 3]) {
    for (int k = 0; k < 7; k++) {
      prev[k] = now[k], prev_acc[k] = now_acc[k], prev_qd[k] = now_qd[k];
    }
    s[FVS_L0 + 3] = d->time;
  }
  const mjtNum dt = m->opt.timestep;
  const int a0 = (int)s[mode == 1 ? FVS_L0 + 1 : FVS_L0 + 2];
  if (a0 < 0 || a0 + 7 > m->nu) {
    return;
  }
  for (int k = 0; k < 7; k++) {
    const mjtNum* L = m->jnt_user + (j0 + k) * nu + FVS_LCOL;
    mjtNum out;
    if (mode == 1) {
      const mjtNum r = (target[k] - prev[k]) / dt;
      out = prev[k] + fmin(fmax(r, -L[0]), L[0]) * dt;
      now_acc[k] = 0.0, now_qd[k] = prev_qd[k];
    } else {
      const mjtNum A = L[1], J = L[2], cap = L[3], off = L[4], kk = L[5], tol = L[8];
      const mjtNum v = prev[k], a = prev_acc[k], qd = prev_qd[k];
      const mjtNum up = fmin(cap, fmax(0.0, off + sqrt(fmax(0.0, kk * (L[6] - qd))))) - tol;
      const mjtNum lo = fmax(-cap, fmin(0.0, -off - sqrt(fmax(0.0, kk * (qd - L[7]))))) + tol;
      const mjtNum jerk = ((target[k] - v) / dt - a) / dt;
      const mjtNum acc = a + fmin(fmax(jerk, -J), J) * dt;
      const mjtNum hi_a = fmin((J / A) * (up - v), A), lo_a = fmax((J / A) * (lo - v), -A);
      out = v + fmax(fmin(acc, hi_a), lo_a) * dt;
      now_acc[k] = (out - v) / dt;
      now_qd[k] = qd + out * dt;
    }
    now[k] = out;
    d->ctrl[a0 + k] = out;
  }
}

static void fvs_reflexes(const mjModel* m, mjData* d) {
  for (int j0 = 0; j0 + 7 <= m->njnt; j0++) {
    mjtNum* s = fvs_record(m, d, j0);
    if (s == NULL) {
      continue;
    }
    if (s[0] > 0.0) {
      fvs_brake(m, d, j0, s);
    } else if (s[0] == FVS_ARMED && d->time > s[1]) {
      fvs_check(m, d, j0, s);
    }
    if (s[FVS_L0] != 0.0 && !(s[0] > 0.0)) {
      fvs_limit(m, d, j0, s);
    }
  }
}

/* The joint effects of joint j (e = its user numbers from column FVS_ECOL + 1); see the header comment. */
static void fvs_joint_effects(const mjModel* m, mjData* d, int j, const mjtNum* e) {
  const int dof = m->jnt_dofadr[j];
  const mjtNum v = d->qvel[dof];
  const mjtNum q = d->qpos[m->jnt_qposadr[j]];
  const mjtNum K = e[5], Fs = e[3];
  mjtNum f = 0.0; /* added to the link's passive force */
  mjtNum* r = NULL;
  mjtNum u = 0.0;
  if (K > 0.0 || Fs > 0.0) {
    const int off = (int)e[9], a = (int)e[10];
    if (off < 0 || off + FVS_MREC > m->nuserdata || a < 0 || a >= m->nu) {
      return;
    }
    r = d->userdata + off;
    u = d->ctrl[a];
    if (m->actuator_ctrllimited[a]) {
      u = fmin(fmax(u, m->actuator_ctrlrange[2 * a]), m->actuator_ctrlrange[2 * a + 1]);
    }
    if (m->jnt_actgravcomp[j]) {
      u += d->qfrc_gravcomp[dof];
    }
    if (m->jnt_actfrclimited[j]) {
      u = fmin(fmax(u, m->jnt_actfrcrange[2 * j]), m->jnt_actfrcrange[2 * j + 1]);
    }
    if (r[0] == 0.0) { /* start at the static deflection, the anchor at the joint */
      const mjtNum b = e[8];
      const mjtNum d0 = K > 0.0 ? u / K + (u > 0.0 ? b : (u < 0.0 ? -b : 0.0)) : 0.0;
      r[0] = 1.0, r[1] = d->time;
      r[2] = r[4] = q + d0;
      r[3] = r[5] = v;
      r[6] = r[7] = 0.0;
      r[8] = r[9] = q;
      r[10] = r[11] = 0.0;
    } else if (d->time != r[1]) {
      r[2] = r[4], r[3] = r[5], r[7] = r[6], r[8] = r[9], r[10] = r[11], r[1] = d->time;
    }
  }
  if (Fs > 0.0) { /* static friction: the anchor spring, capped by the decaying breakaway level */
    const mjtNum ks = e[11], c = e[12];
    const mjtNum cap = Fs * (1.0 - tanh(fabs(r[10]) / e[4]));
    const mjtNum fs = -ks * (q - r[8]) - c * v;
    if (fs > cap || fs < -cap) {
      const mjtNum fc = fs > 0.0 ? cap : -cap;
      r[9] = q + (fc + c * v) / ks; /* the anchor moves just enough to bring the force to the cap */
      f += fc;
    } else {
      r[9] = r[8];
      f += fs;
    }
    r[11] = (r[9] - r[8]) / m->opt.timestep;
  }
  if (K > 0.0) {
    const mjtNum D = e[6], B = e[7], b = e[8];
    const mjtNum th = r[2], dth = r[3];
    const mjtNum delta = th - q;
    const mjtNum dz = delta > b ? delta - b : (delta < -b ? delta + b : 0.0);
    mjtNum s = 1.0;
    if (b > 0.0) {
      s = fmin(1.0, fabs(dz) * 20.0 / b);
    }
    const mjtNum tau_t = K * dz + s * D * (dth - v);
    mjtNum tau_motor = u - tau_t;
    if (e[0] != 0.0) { /* cogging acts on the motor */
      tau_motor -= e[0] * sin(e[1] * th + e[2]);
    }
    const mjtNum dth1 = dth + m->opt.timestep * tau_motor / B;
    r[5] = dth1;
    r[4] = th + m->opt.timestep * dth1;
    r[6] = tau_t - u;
    f += r[6];
  } else if (e[0] != 0.0) { /* cogging on the rigid joint */
    f -= e[0] * sin(e[1] * q + e[2]);
  }
  d->qfrc_passive[dof] += f;
}

static void fvs_passive(const mjModel* m, mjData* d) {
  const mjtSize nu = m->nuser_jnt;
  if (nu < FVS_NUSER) {
    return;
  }
  if (m->nuserdata >= FVS_RSLOT) {
    fvs_reflexes(m, d);
  }
  const int effects = nu >= FVS_ENUSER;
  for (mjtSize j = 0; j < m->njnt; j++) {
    const mjtNum* u = m->jnt_user + j * nu;
    if (effects && u[FVS_ECOL] == FVS_ETAG) {
      fvs_joint_effects(m, d, (int)j, u + FVS_ECOL + 1);
    }
    if (u[0] != FVS_TAG) {
      continue;
    }
    const int dof = m->jnt_dofadr[j];
    const mjtNum v = d->qvel[dof];
    const mjtNum phi1 = u[1], phi2 = u[2], phi2phi3 = u[2] * u[3];
    mjtNum tau = 0.0;
    if (phi1 != 0.0) {
      tau = phi1 / (1.0 + exp(-(phi2 * v + phi2phi3))) - phi1 / (1.0 + exp(-phi2phi3));
    }
    if (u[4] != 0.0) {
      tau += u[4] * v;
    }
    if (u[5] != 0.0) {
      tau += u[5] * tanh(v / u[6]);
    }
    if (u[7] != 0.0) { /* Stribeck: stribeck exp(-(v / stribeck_vel)^2) tanh(v / coulomb_vel) */
      const mjtNum r = v / u[8];
      tau += u[7] * exp(-(r * r)) * tanh(v / u[6]);
    }
    d->qfrc_passive[dof] -= tau;
  }
}

static PyObject* callback_address(PyObject* self, PyObject* args) {
  (void)self;
  (void)args;
  return PyLong_FromVoidPtr((void*)&fvs_passive);
}

/* check(model_address, data_address, j0) -> 0: the robot is not armed (Python checks), 1: a violation is recorded
 * (now or during the last call), 2: armed and within its limits (the state is marked checked). */
static PyObject* check(PyObject* self, PyObject* const* args, Py_ssize_t nargs) {
  (void)self;
  if (nargs != 3) {
    PyErr_SetString(PyExc_TypeError, "check(model_address, data_address, first_joint)");
    return NULL;
  }
  const mjModel* m = (const mjModel*)PyLong_AsVoidPtr(args[0]);
  mjData* d = (mjData*)PyLong_AsVoidPtr(args[1]);
  const long j0 = PyLong_AsLong(args[2]);
  if (PyErr_Occurred()) {
    return NULL;
  }
  if (m == NULL || d == NULL) {
    PyErr_SetString(PyExc_ValueError, "check: null model or data");
    return NULL;
  }
  mjtNum* s = fvs_record(m, d, (int)j0);
  if (s == NULL) {
    return PyLong_FromLong(0);
  }
  if (s[0] > 0.0) {
    return PyLong_FromLong(1);
  }
  if (s[0] != FVS_ARMED) {
    return PyLong_FromLong(0);
  }
  if (fvs_check(m, d, (int)j0, s)) {
    return PyLong_FromLong(1);
  }
  s[1] = d->time;
  return PyLong_FromLong(2);
}

static PyMethodDef methods[] = {
    {"callback_address", callback_address, METH_NOARGS,
     "Address of the C passive-force callback (for mujoco.set_mjcb_passive through ctypes)."},
    {"check", (PyCFunction)(void (*)(void))check, METH_FASTCALL,
     "check(model_address, data_address, first_joint): the plant's reflex check on the current state (0 not armed, "
     "1 violation recorded, 2 within the limits)."},
    {"tag_truth", (PyCFunction)(void (*)(void))fvs_tag_truth, METH_FASTCALL,
     "tag_truth(geo, q, fMo, out): the camera's ground truth of a tag for n robots (records, see _task.c)."},
    {"torque_cost", (PyCFunction)(void (*)(void))fvs_torque_cost, METH_FASTCALL,
     "torque_cost(tau, tau_max, cost, out): cost * mean((tau / tau_max)^2) of each row."},
    {"visual_pre", (PyCFunction)(void (*)(void))fvs_visual_pre, METH_FASTCALL,
     "visual_pre(P, I, data_address, action, cmd, applied): an env's torque or joint velocity command (see _task.c)."},
    {"visual_post", (PyCFunction)(void (*)(void))fvs_visual_post, METH_FASTCALL,
     "visual_post(P, I, model_address, data_address, out, flags): a visual env's step after its physics."},
    {"tracking", (PyCFunction)(void (*)(void))fvs_tracking, METH_FASTCALL,
     "tracking(q0, A, w, t, q, desired, err): FrankaTorqueTracking-v0's desired trajectory and tracking error."},
    {"tracking_batch", (PyCFunction)(void (*)(void))fvs_tracking_batch, METH_FASTCALL,
     "tracking_batch(...): one step's end of n FrankaTorqueTracking-v0 robots (see _task.c)."},
    {"tracking_post", (PyCFunction)(void (*)(void))fvs_tracking_post, METH_FASTCALL,
     "tracking_post(P, I, model_address, data_address, out): a torque tracking env's step after its physics."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_plant",
    "The plant's joint friction and reflexes as a C passive-force callback for MuJoCo (see franka_vs_gym.sim.plant).", -1,
    methods,
};

PyMODINIT_FUNC PyInit__plant(void) {
  int p_fixed = 0, i_size = 0;
  PyObject* mod = PyModule_Create(&module);
  if (mod == NULL) {
    return NULL;
  }
  if (PyModule_AddIntConstant(mod, "MJ_VERSION_HEADER", mjVERSION_HEADER) < 0 ||
      PyModule_AddObject(mod, "TAG", PyFloat_FromDouble(FVS_TAG)) < 0 ||
      PyModule_AddIntConstant(mod, "NUSER", FVS_NUSER) < 0 ||
      PyModule_AddIntConstant(mod, "RCOL", FVS_RCOL) < 0 ||
      PyModule_AddObject(mod, "RTAG", PyFloat_FromDouble(FVS_RTAG)) < 0 ||
      PyModule_AddIntConstant(mod, "RSLOT", FVS_RSLOT) < 0 ||
      PyModule_AddIntConstant(mod, "LCOL", FVS_LCOL) < 0 ||
      PyModule_AddIntConstant(mod, "L0", FVS_L0) < 0 ||
      PyModule_AddIntConstant(mod, "ECOL", FVS_ECOL) < 0 ||
      PyModule_AddObject(mod, "ETAG", PyFloat_FromDouble(FVS_ETAG)) < 0 ||
      PyModule_AddIntConstant(mod, "ENUSER", FVS_ENUSER) < 0 ||
      PyModule_AddIntConstant(mod, "MREC", FVS_MREC) < 0 ||
      PyModule_AddIntConstant(mod, "TASK_REC", fvs_plan_sizes(&p_fixed, &i_size)) < 0 ||
      PyModule_AddIntConstant(mod, "TASK_P_FIXED", p_fixed) < 0 ||
      PyModule_AddIntConstant(mod, "TASK_I_SIZE", i_size) < 0) {
    Py_DECREF(mod);
    return NULL;
  }
  return mod;
}
