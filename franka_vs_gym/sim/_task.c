/* The visual tasks' per-step work in C: the camera's ground truth of a tag (forward kinematics, the tag pose in
 * the camera frame, the ideal projection of its corners, the pose vector, the feature error), the torque cost, and
 * the two halves of a single environment's step around MuJoCo's physics call (franka_vs_gym.envs.visual).
 *
 * Conventions (those of franka_vs_gym.model.geometry and franka_vs_gym.vision): poses aMb are 4x4 homogeneous,
 * row-major; the camera frame c is ViSP's (z forward, y down); normalized coordinates x = X / Z, y = Y / Z; pixels
 * u = fx x + cx, v = fy y + cy; a pixel coordinate is inside the image when it is in [-0.5, size - 0.5].
 *
 * The geometry block ``geo`` (FVS_GEO numbers) describes one robot, camera and tag:
 *   [0, 96)    the chain: the placement of each of the seven revolute-z joints in its parent (R row-major 9, t 3)
 *              and, last, the frame the hand carries in the seventh joint's frame (R 9, t 3): the camera c (eye in
 *              hand) or the tag o (eye to hand);
 *   [96, 108)  the tag's corners (4 x 3) in the tag frame o, in detection order;
 *   [108, 114) fx, fy, cx, cy, width - 0.5, height - 0.5 (pixels);
 *   [114, 122) the desired features s* (8);
 *   [122]      0: eye in hand (the static pose given with q is the tag's fMo, cMo = (fMc(q))^-1 fMo), 1: eye to
 *              hand (the static pose is the fixed camera's cMf, cMo = cMf fMo(q)).
 *
 * A truth record (FVS_REC numbers) holds, for the joint position q and the static pose (fMo, or cMf eye to hand):
 *   [0, 8) features (x, y of the four corners; zeros when the tag is behind the camera or not facing it),
 *   [8, 12) corner depths Z (m), [12] visible (1 or 0), [13, 29) cMo (4 x 4), [29, 35) the pose vector of cMo
 *   (t, theta u), [35] the feature error ||s - s*|| (||s*|| + 1 when the tag is not visible).
 *
 * The floating-point operations are written out one by one (and the file is compiled without contraction into
 * fused multiply-adds), so every caller, the single environments and the batched vector env, gets the same bits.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#include <mujoco/mujoco.h>

#include "_task.h"

#define FVS_GEO 123
#define FVS_REC 36

/* ------------------------------------------------------------------------------------------------ geometry */

/* (R, t) <- (R, t) * (A, a): R = R A, t = t + R a. */
static void compose(double* R, double* t, const double* A, const double* a) {
  double Rn[9];
  for (int i = 0; i < 3; i++) {
    t[i] = t[i] + ((R[3 * i] * a[0] + R[3 * i + 1] * a[1]) + R[3 * i + 2] * a[2]);
  }
  for (int i = 0; i < 3; i++) {
    for (int j = 0; j < 3; j++) {
      Rn[3 * i + j] = (R[3 * i] * A[j] + R[3 * i + 1] * A[3 + j]) + R[3 * i + 2] * A[6 + j];
    }
  }
  memcpy(R, Rn, sizeof Rn);
}

/* R <- R Rz(theta). */
static void rotate_z(double* R, double theta) {
  const double c = cos(theta), s = sin(theta);
  for (int i = 0; i < 3; i++) {
    const double r0 = R[3 * i], r1 = R[3 * i + 1];
    R[3 * i] = r0 * c + r1 * s;
    R[3 * i + 1] = r1 * c - r0 * s;
  }
}

/* theta u (3) of a rotation matrix R (row-major), theta in [0, pi]: through the unit quaternion (w, v), taken
 * from the largest of 1 + trace and 1 + 2 R_ii - trace (well conditioned everywhere, also near theta = pi), with
 * w >= 0; theta = 2 atan2(|v|, w) and theta u = theta v / |v| (2 v / w for a tiny |v|). */
static void log3(const double* R, double* out) {
  const double tr = (R[0] + R[4]) + R[8];
  double q[4]; /* w, x, y, z */
  const double d[4] = {1.0 + tr, 1.0 + 2.0 * R[0] - tr, 1.0 + 2.0 * R[4] - tr, 1.0 + 2.0 * R[8] - tr};
  int k = 0;
  for (int i = 1; i < 4; i++) {
    if (d[i] > d[k]) {
      k = i;
    }
  }
  const double s = 2.0 * sqrt(d[k] > 0.0 ? d[k] : 0.0); /* 4 |q_k| */
  if (s <= 0.0) {
    out[0] = out[1] = out[2] = 0.0;
    return;
  }
  if (k == 0) {
    q[0] = 0.25 * s, q[1] = (R[7] - R[5]) / s, q[2] = (R[2] - R[6]) / s, q[3] = (R[3] - R[1]) / s;
  } else if (k == 1) {
    q[0] = (R[7] - R[5]) / s, q[1] = 0.25 * s, q[2] = (R[1] + R[3]) / s, q[3] = (R[2] + R[6]) / s;
  } else if (k == 2) {
    q[0] = (R[2] - R[6]) / s, q[1] = (R[1] + R[3]) / s, q[2] = 0.25 * s, q[3] = (R[5] + R[7]) / s;
  } else {
    q[0] = (R[3] - R[1]) / s, q[1] = (R[2] + R[6]) / s, q[2] = (R[5] + R[7]) / s, q[3] = 0.25 * s;
  }
  if (q[0] < 0.0) {
    q[0] = -q[0], q[1] = -q[1], q[2] = -q[2], q[3] = -q[3];
  }
  const double nv = sqrt((q[1] * q[1] + q[2] * q[2]) + q[3] * q[3]);
  double f;
  if (nv < 1e-8) {
    f = 2.0 / q[0]; /* 2 atan2(nv, w) / nv = (2 / w) (1 - nv^2 / (3 w^2) + ...), nv^2 below double precision */
  } else {
    f = 2.0 * atan2(nv, q[0]) / nv;
  }
  out[0] = f * q[1], out[1] = f * q[2], out[2] = f * q[3];
}

/* One truth record (see the file's comment) for the joint position q (7) and the static pose S (16): the tag's
 * fMo (eye in hand) or the camera's cMf (eye to hand). */
static void truth_row(const double* geo, const double* q, const double* S, double* rec) {
  double R[9] = {1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0}, t[3] = {0.0, 0.0, 0.0};
  for (int k = 0; k < 7; k++) {
    const double* P = geo + 12 * k;
    compose(R, t, P, P + 9);
    rotate_z(R, q[k]);
  }
  compose(R, t, geo + 84, geo + 93); /* fMc (eye in hand) or fMo (eye to hand) */
  double Rs[9], Rc[9], tc[3];
  for (int i = 0; i < 3; i++) {
    Rs[3 * i] = S[4 * i], Rs[3 * i + 1] = S[4 * i + 1], Rs[3 * i + 2] = S[4 * i + 2];
  }
  if (geo[122] != 0.0) { /* cMo = cMf fMo = [Rs R, Rs t + ts] */
    for (int i = 0; i < 3; i++) {
      for (int j = 0; j < 3; j++) {
        Rc[3 * i + j] = (Rs[3 * i] * R[j] + Rs[3 * i + 1] * R[3 + j]) + Rs[3 * i + 2] * R[6 + j];
      }
      tc[i] = ((Rs[3 * i] * t[0] + Rs[3 * i + 1] * t[1]) + Rs[3 * i + 2] * t[2]) + S[4 * i + 3];
    }
  } else { /* cMo = (fMc)^-1 fMo = [R^T Ro, R^T (to - t)] */
    double d[3];
    for (int i = 0; i < 3; i++) {
      d[i] = S[4 * i + 3] - t[i];
    }
    for (int i = 0; i < 3; i++) {
      for (int j = 0; j < 3; j++) {
        Rc[3 * i + j] = (R[i] * Rs[j] + R[3 + i] * Rs[3 + j]) + R[6 + i] * Rs[6 + j];
      }
      tc[i] = (R[i] * d[0] + R[3 + i] * d[1]) + R[6 + i] * d[2];
    }
  }
  double* M = rec + 13;
  for (int i = 0; i < 3; i++) {
    M[4 * i] = Rc[3 * i], M[4 * i + 1] = Rc[3 * i + 1], M[4 * i + 2] = Rc[3 * i + 2], M[4 * i + 3] = tc[i];
  }
  M[12] = 0.0, M[13] = 0.0, M[14] = 0.0, M[15] = 1.0;
  /* the corners in c, the ideal projection, visibility */
  const double* corners = geo + 96;
  const double* cam = geo + 108;
  double X[4], Y[4], Z[4];
  int front = Rc[8] < 0.0;
  for (int j = 0; j < 4; j++) {
    const double* p = corners + 3 * j;
    X[j] = ((Rc[0] * p[0] + Rc[1] * p[1]) + Rc[2] * p[2]) + tc[0];
    Y[j] = ((Rc[3] * p[0] + Rc[4] * p[1]) + Rc[5] * p[2]) + tc[1];
    Z[j] = ((Rc[6] * p[0] + Rc[7] * p[1]) + Rc[8] * p[2]) + tc[2];
    front = front && Z[j] > 1e-6;
  }
  int inside = front;
  for (int j = 0; j < 4; j++) {
    rec[8 + j] = Z[j];
    if (front) {
      const double x = X[j] / Z[j], y = Y[j] / Z[j];
      const double u = x * cam[0] + cam[2], v = y * cam[1] + cam[3];
      inside = inside && u >= -0.5 && u <= cam[4] && v >= -0.5 && v <= cam[5];
      rec[2 * j] = x, rec[2 * j + 1] = y;
    } else {
      rec[2 * j] = 0.0, rec[2 * j + 1] = 0.0;
    }
  }
  rec[12] = inside ? 1.0 : 0.0;
  rec[29] = tc[0], rec[30] = tc[1], rec[31] = tc[2];
  log3(Rc, rec + 32);
  const double* sd = geo + 114;
  double ss = 0.0;
  if (inside) {
    for (int j = 0; j < 8; j++) {
      const double e = rec[j] - sd[j];
      ss = ss + e * e;
    }
    rec[35] = sqrt(ss);
  } else {
    for (int j = 0; j < 8; j++) {
      ss = ss + sd[j] * sd[j];
    }
    rec[35] = sqrt(ss) + 1.0;
  }
}

/* cost * sum((tau / tau_max)^2) / 7 of one command. */
static double torque_cost_row(const double* tau, const double* tau_max, double cost) {
  double ss = 0.0;
  for (int k = 0; k < 7; k++) {
    const double x = tau[k] / tau_max[k];
    ss = ss + x * x;
  }
  return cost * ss / 7.0;
}

/* ------------------------------------------------------------------------------------------------ buffers */

/* A C-contiguous float64 buffer of exactly n numbers (n < 0: any multiple of -n); 0 on success. */
static int get_f64(PyObject* obj, Py_buffer* view, Py_ssize_t n, int writable, const char* name) {
  if (PyObject_GetBuffer(obj, view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0)) < 0) {
    return -1;
  }
  const char* f = view->format;
  if (view->itemsize != 8 || f == NULL || !(strcmp(f, "d") == 0 || strcmp(f, "<d") == 0 || strcmp(f, "=d") == 0)) {
    PyErr_Format(PyExc_TypeError, "%s must be a float64 array", name);
    PyBuffer_Release(view);
    return -1;
  }
  const Py_ssize_t len = view->len / 8;
  if ((n >= 0 && len != n) || (n < 0 && (len % (-n)) != 0)) {
    PyErr_Format(PyExc_ValueError, "%s has %zd numbers, expected %s%zd", name, len, n < 0 ? "a multiple of " : "",
                 n < 0 ? -n : n);
    PyBuffer_Release(view);
    return -1;
  }
  return 0;
}

/* tag_truth(geo, q (n, 7), fMo (n, 16), out (n, FVS_REC)): the truth records of n robots. */
PyObject* fvs_tag_truth(PyObject* self, PyObject* const* args, Py_ssize_t nargs) {
  (void)self;
  if (nargs != 4) {
    PyErr_SetString(PyExc_TypeError, "tag_truth(geo, q, fMo, out)");
    return NULL;
  }
  Py_buffer g, q, f, o;
  if (get_f64(args[0], &g, FVS_GEO, 0, "geo") < 0) {
    return NULL;
  }
  if (get_f64(args[1], &q, -7, 0, "q") < 0) {
    PyBuffer_Release(&g);
    return NULL;
  }
  const Py_ssize_t n = q.len / 56;
  if (get_f64(args[2], &f, 16 * n, 0, "fMo") < 0) {
    PyBuffer_Release(&g), PyBuffer_Release(&q);
    return NULL;
  }
  if (get_f64(args[3], &o, FVS_REC * n, 1, "out") < 0) {
    PyBuffer_Release(&g), PyBuffer_Release(&q), PyBuffer_Release(&f);
    return NULL;
  }
  for (Py_ssize_t i = 0; i < n; i++) {
    truth_row((const double*)g.buf, (const double*)q.buf + 7 * i, (const double*)f.buf + 16 * i,
              (double*)o.buf + FVS_REC * i);
  }
  PyBuffer_Release(&g), PyBuffer_Release(&q), PyBuffer_Release(&f), PyBuffer_Release(&o);
  Py_RETURN_NONE;
}

/* torque_cost(tau (n, 7), tau_max (7), cost, out (n)): cost * mean((tau / tau_max)^2) of each row. */
PyObject* fvs_torque_cost(PyObject* self, PyObject* const* args, Py_ssize_t nargs) {
  (void)self;
  if (nargs != 4) {
    PyErr_SetString(PyExc_TypeError, "torque_cost(tau, tau_max, cost, out)");
    return NULL;
  }
  const double cost = PyFloat_AsDouble(args[2]);
  if (cost == -1.0 && PyErr_Occurred()) {
    return NULL;
  }
  Py_buffer t, m, o;
  if (get_f64(args[0], &t, -7, 0, "tau") < 0) {
    return NULL;
  }
  const Py_ssize_t n = t.len / 56;
  if (get_f64(args[1], &m, 7, 0, "tau_max") < 0) {
    PyBuffer_Release(&t);
    return NULL;
  }
  if (get_f64(args[3], &o, n, 1, "out") < 0) {
    PyBuffer_Release(&t), PyBuffer_Release(&m);
    return NULL;
  }
  for (Py_ssize_t i = 0; i < n; i++) {
    ((double*)o.buf)[i] = torque_cost_row((const double*)t.buf + 7 * i, (const double*)m.buf, cost);
  }
  PyBuffer_Release(&t), PyBuffer_Release(&m), PyBuffer_Release(&o);
  Py_RETURN_NONE;
}

/* ------------------------------------------------------------------------------------------------ env step */
/* The plan of a single visual environment (franka_vs_gym.envs.visual.StepPlan): one float64 block P and one int64
 * block I, laid out as below (offsets in numbers). The truth, the held frame and the observation packer's work
 * vector live in P, so the Python and the C halves of the environment read and write the same numbers. */
enum {
  P_GEO = 0,
  P_FMO = P_GEO + FVS_GEO, /* fMo (16) */
  P_TRUTH = P_FMO + 16,    /* truth record */
  P_FRAME = P_TRUTH + FVS_REC, /* held frame record */
  P_ACT_LO = P_FRAME + FVS_REC, /* action bounds with their tolerance (7 each) */
  P_ACT_HI = P_ACT_LO + 7,
  P_TAU_MAX = P_ACT_HI + 7,
  P_ACTION = P_TAU_MAX + 7, /* the checked action (7) */
  P_Q_LO = P_ACTION + 7,    /* joint-limit failure bounds (7 each) */
  P_Q_HI = P_Q_LO + 7,
  P_DEPTH_D = P_Q_HI + 7, /* desired depths (4) */
  P_POSE_D = P_DEPTH_D + 4, /* desired pose vector (6) */
  P_COST = P_POSE_D + 6,    /* torque cost coefficient */
  P_COST_NOW = P_COST + 1,  /* this step's torque cost */
  P_ACT_SCALE = P_COST_NOW + 1, /* physical value of an action of 1 (7; ones for physical actions) */
  P_DQ_CAP = P_ACT_SCALE + 7, /* joint velocity commands: the servo's limit per joint (7, rad/s) */
  P_FRIC = P_DQ_CAP + 7, /* joint velocity commands: the feed-forward friction phi1, phi2, phi2 phi3, offset (7 each) */
  P_WORK = P_FRIC + 28, /* work (S), low (S), high (S) */
};
enum {
  I_J0 = 0,    /* first joint (reflex record) */
  I_QADR = 1,  /* qpos addresses (7) */
  I_DADR = 8,  /* dof addresses (7) */
  I_CTRL = 15, /* first torque actuator */
  I_KEYS = 16, /* offsets in work of q, dq, features, features_desired, feature_depth, tag_pose, tag_pose_desired,
                  visible (-1 when absent) */
  I_S = 24,    /* work size S */
  I_LIM = 25,  /* userdata index of the rate limiter's target (7; -1: the command goes to the controls) */
  I_MODE = 26, /* the action: 2 joint velocity, anything else joint torque */
  I_CTRL_VEL = 27, /* first velocity-servo actuator (joint velocity actions) */
  I_FRIC = 28, /* joint velocity actions: 1 the sigmoid feed-forward friction of P_FRIC, 0 none */
  I_SIZE = 29,
};

int fvs_plan_sizes(int* p_fixed, int* i_size) {
  *p_fixed = P_WORK;
  *i_size = I_SIZE;
  return FVS_REC;
}

/* visual_pre(P, I, data_address, action, cmd, applied) -> 0: the action (a float32 or float64 vector of 7 inside
 * the bounds) times the action scale is copied to P's action (the physical command), then
 *  - joint torque: saturated at tau_max into cmd (the commanded torque) and either the torque actuators' controls
 *    and applied (the last applied torque) or, rate-limited (I_LIM >= 0), the limiter's target in userdata (the
 *    plant's callback then writes the controls at every physics step), and its torque cost computed;
 *  - joint velocity (I_MODE 2): scaled down uniformly when a joint exceeds the servo's limit (the largest
 *    |dq_k| / cap_k above 1 divides every joint), into cmd (the velocity target) and either the velocity servos'
 *    controls and applied (the velocity reference) or the limiter's target, and the feed-forward friction
 *    phi1 / (1 + exp(-(phi2 dq + phi2 phi3))) - offset (or 0) into the torque actuators' controls, as
 *    FrankaSim.set_velocity with the model's sigmoid friction law;
 * -1: nothing was done (the caller takes the general path). */
PyObject* fvs_visual_pre(PyObject* self, PyObject* const* args, Py_ssize_t nargs) {
  (void)self;
  if (nargs != 6) {
    PyErr_SetString(PyExc_TypeError, "visual_pre(P, I, data_address, action, cmd, applied)");
    return NULL;
  }
  Py_buffer a;
  if (PyObject_GetBuffer(args[3], &a, PyBUF_RECORDS_RO) < 0) {
    PyErr_Clear();
    return PyLong_FromLong(-1);
  }
  double v[7];
  int ok = a.ndim == 1 && a.shape[0] == 7 && a.format != NULL;
  if (ok) {
    const char* f = a.format;
    if (*f == '<' || *f == '=') {
      f++;
    }
    const int f32 = strcmp(f, "f") == 0 && a.itemsize == 4, f64 = strcmp(f, "d") == 0 && a.itemsize == 8;
    ok = f32 || f64;
    for (int k = 0; ok && k < 7; k++) {
      const char* p = (const char*)a.buf + k * a.strides[0];
      v[k] = f32 ? (double)*(const float*)p : *(const double*)p;
    }
  }
  PyBuffer_Release(&a);
  if (!ok) {
    return PyLong_FromLong(-1);
  }
  Py_buffer pb, ib, tc, ta;
  if (get_f64(args[0], &pb, -1, 1, "P") < 0) {
    return NULL;
  }
  if (pb.len < P_WORK * 8) {
    PyErr_SetString(PyExc_ValueError, "visual_pre: plan block P too short");
    PyBuffer_Release(&pb);
    return NULL;
  }
  double* P = (double*)pb.buf;
  for (int k = 0; k < 7; k++) {
    if (!(v[k] >= P[P_ACT_LO + k] && v[k] <= P[P_ACT_HI + k])) { /* (NaN fails) */
      PyBuffer_Release(&pb);
      return PyLong_FromLong(-1);
    }
  }
  if (PyObject_GetBuffer(args[1], &ib, PyBUF_C_CONTIGUOUS) < 0) {
    PyBuffer_Release(&pb);
    return NULL;
  }
  if (ib.len != I_SIZE * 8) {
    PyErr_SetString(PyExc_ValueError, "visual_pre: plan block I of the wrong size");
    PyBuffer_Release(&pb), PyBuffer_Release(&ib);
    return NULL;
  }
  mjData* d = (mjData*)PyLong_AsVoidPtr(args[2]);
  if (d == NULL || get_f64(args[4], &tc, 7, 1, "tau_cmd") < 0) {
    if (d == NULL && !PyErr_Occurred()) {
      PyErr_SetString(PyExc_ValueError, "visual_pre: null data");
    }
    PyBuffer_Release(&pb), PyBuffer_Release(&ib);
    return NULL;
  }
  if (get_f64(args[5], &ta, 7, 1, "tau_applied") < 0) {
    PyBuffer_Release(&pb), PyBuffer_Release(&ib), PyBuffer_Release(&tc);
    return NULL;
  }
  const int64_t* I = (const int64_t*)ib.buf;
  if (I[I_CTRL] < 0) {
    PyErr_SetString(PyExc_ValueError, "visual_pre: no torque actuators in the plan");
    PyBuffer_Release(&pb), PyBuffer_Release(&ib), PyBuffer_Release(&tc), PyBuffer_Release(&ta);
    return NULL;
  }
  double* tau_cmd = (double*)tc.buf;
  double* tau_applied = (double*)ta.buf;
  if (I[I_MODE] == 2) {
    if (I[I_CTRL_VEL] < 0) {
      PyErr_SetString(PyExc_ValueError, "visual_pre: no velocity actuators in the plan");
      PyBuffer_Release(&pb), PyBuffer_Release(&ib), PyBuffer_Release(&tc), PyBuffer_Release(&ta);
      return NULL;
    }
    double u[7], ratio = 0.0;
    for (int k = 0; k < 7; k++) {
      u[k] = v[k] * P[P_ACT_SCALE + k];
      P[P_ACTION + k] = u[k];
      const double r = fabs(u[k]) / P[P_DQ_CAP + k];
      ratio = r > ratio ? r : ratio;
    }
    const double* F = P + P_FRIC;
    for (int k = 0; k < 7; k++) {
      const double dq = ratio > 1.0 ? u[k] / ratio : u[k];
      tau_cmd[k] = dq;
      if (I[I_LIM] >= 0) {
        d->userdata[I[I_LIM] + k] = dq;
      } else {
        tau_applied[k] = dq;
        d->ctrl[I[I_CTRL_VEL] + k] = dq;
      }
      /* phi1 expit(phi2 dq + phi2 phi3) - offset, expit(x) = 1 / (1 + exp(-x)) */
      d->ctrl[I[I_CTRL] + k] = I[I_FRIC] == 1 ? F[k] * (1.0 / (1.0 + exp(-(F[7 + k] * dq + F[14 + k])))) - F[21 + k]
                                              : 0.0;
    }
    P[P_COST_NOW] = 0.0;
    PyBuffer_Release(&pb), PyBuffer_Release(&ib), PyBuffer_Release(&tc), PyBuffer_Release(&ta);
    return PyLong_FromLong(0);
  }
  for (int k = 0; k < 7; k++) {
    const double hi = P[P_TAU_MAX + k];
    const double u = v[k] * P[P_ACT_SCALE + k];
    double tau = u < hi ? u : hi; /* np.minimum then np.maximum with -tau_max */
    tau = tau > -hi ? tau : -hi;
    P[P_ACTION + k] = u;
    tau_cmd[k] = tau;
    if (I[I_LIM] >= 0) {
      d->userdata[I[I_LIM] + k] = tau;
    } else {
      tau_applied[k] = tau;
      d->ctrl[I[I_CTRL] + k] = tau;
    }
  }
  P[P_COST_NOW] = torque_cost_row(P + P_ACTION, P + P_TAU_MAX, P[P_COST]);
  PyBuffer_Release(&pb), PyBuffer_Release(&ib), PyBuffer_Release(&tc), PyBuffer_Release(&ta);
  return PyLong_FromLong(0);
}

/* An observation's work vector clipped in place to [low, high] and cast into out (float32), NaN as 0 (not
 * clipped): kernels.clip_observation's operations, so the same bits. */
static void clip_cast(double* work, const double* low, const double* high, float* out, Py_ssize_t S) {
  for (Py_ssize_t i = 0; i < S; i++) {
    double x = work[i];
    if (x != x) {
      work[i] = 0.0;
      out[i] = 0.0f;
      continue;
    }
    x = x < low[i] ? low[i] : x;
    x = x > high[i] ? high[i] : x;
    work[i] = x;
    out[i] = (float)x;
  }
}

/* Copy n numbers into the work vector at key offset off (skipped when the key is absent). */
static void put(double* work, int64_t off, const double* src, int n) {
  if (off >= 0) {
    memcpy(work + off, src, n * sizeof(double));
  }
}

/* What the two post-physics halves share: the plan's blocks and the output buffer, validated, the reflex check of
 * the state the period ends with, and the joint state with its failure flag. */
typedef struct {
  Py_buffer pb, ib, ob;
  double* P;
  const int64_t* I;
  int64_t S;
  double q[7], dq[7];
  int fail; /* a joint outside its failure bounds or a contact in the data */
} post_ctx;

/* Returns 0 (c ready: the state within the reflexes' limits, marked checked), -1 (MuJoCo warned of a diverging
 * state, or the reflex record is not armed or a violation is recorded now: nothing else done) or -2 (a Python error
 * is set). args: P, I, model_address, data_address, out; key_size: the numbers of each observation key slot. */
static int post_begin(PyObject* const* args, const char* name, const int* key_size, const mjModel** mp, mjData** dp,
                      post_ctx* c) {
  const mjModel* m = (const mjModel*)PyLong_AsVoidPtr(args[2]);
  mjData* d = (mjData*)PyLong_AsVoidPtr(args[3]);
  if (PyErr_Occurred()) {
    return -2;
  }
  if (m == NULL || d == NULL) {
    PyErr_Format(PyExc_ValueError, "%s: null model or data", name);
    return -2;
  }
  *mp = m, *dp = d;
  if (d->warning[mjWARN_BADQPOS].number || d->warning[mjWARN_BADQVEL].number ||
      d->warning[mjWARN_BADQACC].number) {
    return -1;
  }
  if (get_f64(args[0], &c->pb, -1, 1, "P") < 0) {
    return -2;
  }
  if (PyObject_GetBuffer(args[1], &c->ib, PyBUF_C_CONTIGUOUS) < 0) {
    PyBuffer_Release(&c->pb);
    return -2;
  }
  c->P = (double*)c->pb.buf;
  c->I = (const int64_t*)c->ib.buf;
  const int64_t* I = c->I;
  int bad = c->ib.len != I_SIZE * 8;
  const int64_t S = bad ? 0 : I[I_S];
  c->S = S;
  bad = bad || c->pb.len != (P_WORK + 3 * S) * 8;
  for (int j = 0; j < 8 && !bad; j++) {
    bad = I[I_KEYS + j] >= 0 && I[I_KEYS + j] + key_size[j] > S;
  }
  for (int k = 0; k < 7 && !bad; k++) {
    bad = I[I_QADR + k] < 0 || I[I_QADR + k] >= m->nq || I[I_DADR + k] < 0 || I[I_DADR + k] >= m->nv;
  }
  if (bad) {
    PyErr_Format(PyExc_ValueError, "%s: plan blocks of the wrong size or layout", name);
    PyBuffer_Release(&c->pb), PyBuffer_Release(&c->ib);
    return -2;
  }
  if (PyObject_GetBuffer(args[4], &c->ob, PyBUF_C_CONTIGUOUS | PyBUF_WRITABLE | PyBUF_FORMAT) < 0) {
    PyBuffer_Release(&c->pb), PyBuffer_Release(&c->ib);
    return -2;
  }
  if (c->ob.len != S * 4 || c->ob.format == NULL || strchr(c->ob.format, 'f') == NULL) {
    PyErr_Format(PyExc_ValueError, "%s: out must be a float32 vector of the observation's size", name);
    PyBuffer_Release(&c->pb), PyBuffer_Release(&c->ib), PyBuffer_Release(&c->ob);
    return -2;
  }
  /* the reflexes: the state this call ends with, checked as the world's after-call check does */
  mjtNum* s = fvs_reflex_record(m, d, (int)I[I_J0]);
  if (s == NULL || s[0] != -1.0 || fvs_reflex_check(m, d, (int)I[I_J0], s)) {
    PyBuffer_Release(&c->pb), PyBuffer_Release(&c->ib), PyBuffer_Release(&c->ob);
    return -1;
  }
  s[1] = d->time;
  c->fail = d->ncon > 0;
  for (int k = 0; k < 7; k++) {
    c->q[k] = d->qpos[I[I_QADR + k]];
    c->dq[k] = d->qvel[I[I_DADR + k]];
    c->fail |= c->q[k] < c->P[P_Q_LO + k] || c->q[k] > c->P[P_Q_HI + k];
  }
  return 0;
}

/* The work vector clipped in place to [low, high] (NaN as 0: clip_observation) and cast into out; the buffers
 * released. Returns the step's code (1 when the joints or contacts need the caller's check, else 0). */
static PyObject* post_end(post_ctx* c) {
  const int64_t S = c->S;
  double* work = c->P + P_WORK;
  clip_cast(work, work + S, work + 2 * S, (float*)c->ob.buf, S);
  PyBuffer_Release(&c->pb), PyBuffer_Release(&c->ib), PyBuffer_Release(&c->ob);
  return PyLong_FromLong(c->fail ? 1 : 0);
}

/* visual_post(P, I, model_address, data_address, out, flags) after the physics of a period (flags: 1 a camera
 * frame is taken now, 2 state observations, 4 the held frame changed since the work vector was last written):
 *   -1: MuJoCo warned of a diverging state, or the robot's reflex record is not armed or a violation is recorded
 *       now: nothing else was done (the caller takes the general path for the rest of the step);
 *    0: the truth record (and the frame record when a frame is taken) written, the observation packed into out
 *       (float32, S: work clipped to [low, high], NaN as 0), the joints inside their failure bounds and no contact;
 *    1: the same, with a joint outside its failure bounds or a contact in the data (the caller names it). */
PyObject* fvs_visual_post(PyObject* self, PyObject* const* args, Py_ssize_t nargs) {
  (void)self;
  static const int key_size[8] = {7, 7, 8, 8, 4, 6, 6, 1};
  if (nargs != 6) {
    PyErr_SetString(PyExc_TypeError, "visual_post(P, I, model_address, data_address, out, flags)");
    return NULL;
  }
  const long flags = PyLong_AsLong(args[5]);
  if (flags == -1 && PyErr_Occurred()) {
    return NULL;
  }
  const mjModel* m;
  mjData* d;
  post_ctx c;
  const int r = post_begin(args, "visual_post", key_size, &m, &d, &c);
  if (r != 0) {
    return r == -1 ? PyLong_FromLong(-1) : NULL;
  }
  double* P = c.P;
  double* truth = P + P_TRUTH;
  truth_row(P + P_GEO, c.q, P + P_FMO, truth);
  double* frame = P + P_FRAME;
  const int seen = truth[12] != 0.0;
  if (flags & 1) { /* the frame is the truth, zeros where the tag is not seen (the goal depths) */
    memcpy(frame, truth, FVS_REC * sizeof(double));
    if (!seen) {
      memset(frame, 0, 8 * sizeof(double));
      memcpy(frame + 8, P + P_DEPTH_D, 4 * sizeof(double));
      memset(frame + 29, 0, 6 * sizeof(double));
    }
  }
  double* work = P + P_WORK;
  const int64_t* key = c.I + I_KEYS;
  put(work, key[0], c.q, 7);
  put(work, key[1], c.dq, 7);
  if (flags & 2) { /* state observations: the truth now */
    static const double zeros[8] = {0.0};
    put(work, key[2], seen ? truth : zeros, 8);
    put(work, key[4], seen ? truth + 8 : P + P_DEPTH_D, 4);
    put(work, key[5], seen ? truth + 29 : zeros, 6);
    put(work, key[7], truth + 12, 1);
    put(work, key[3], P + P_GEO + 114, 8);
    put(work, key[6], P + P_POSE_D, 6);
  } else if (flags & 5) { /* the held frame's keys, written when it changes */
    put(work, key[2], frame, 8);
    put(work, key[4], frame + 8, 4);
    put(work, key[5], frame + 29, 6);
    put(work, key[7], frame + 12, 1);
    put(work, key[3], P + P_GEO + 114, 8);
    put(work, key[6], P + P_POSE_D, 6);
  }
  (void)m, (void)d;
  return post_end(&c);
}

/* ------------------------------------------------------------------------------------------------ torque tracking */
/* FrankaTorqueTracking-v0's desired trajectory q_d = q0 + A (1 - cos(w t)), dq_d = (A w) sin(w t),
 * ddq_d = (A w) w cos(w t) (out: 21 numbers) and the tracking error ||q - q_d|| of one robot. */
static double tracking_row(const double* q0, const double* A, const double* w, double t, const double* q,
                           double* out) {
  double ss = 0.0;
  for (int k = 0; k < 7; k++) {
    const double wt = w[k] * t;
    const double c = cos(wt), s = sin(wt), Aw = A[k] * w[k];
    out[k] = q0[k] + A[k] * (1.0 - c);
    out[7 + k] = Aw * s;
    out[14 + k] = Aw * w[k] * c;
    const double e = q[k] - out[k];
    ss = ss + e * e;
  }
  return sqrt(ss);
}

/* One robot's torque-tracking observation into its work vector: q, dq, the desired trajectory des (21) and the
 * time t at the key offsets (q, dq, q_desired, dq_desired, ddq_desired, time). */
static void put_tracking(double* work, const int64_t* key, const double* q, const double* dq, const double* des,
                         const double* t) {
  put(work, key[0], q, 7);
  put(work, key[1], dq, 7);
  put(work, key[2], des, 7);
  put(work, key[3], des + 7, 7);
  put(work, key[4], des + 14, 7);
  put(work, key[5], t, 1);
}

/* tracking(q0 (n, 7), A (n, 7), w (n, 7), t (n), q (n, 7), desired (n, 21), err (n)): the desired trajectory and
 * tracking error of n robots. */
PyObject* fvs_tracking(PyObject* self, PyObject* const* args, Py_ssize_t nargs) {
  (void)self;
  if (nargs != 7) {
    PyErr_SetString(PyExc_TypeError, "tracking(q0, A, w, t, q, desired, err)");
    return NULL;
  }
  Py_buffer b[7];
  static const char* names[7] = {"q0", "A", "w", "t", "q", "desired", "err"};
  Py_ssize_t n = -1;
  int got = 0;
  for (; got < 7; got++) {
    static const int per[7] = {7, 7, 7, 1, 7, 21, 1};
    if (get_f64(args[got], &b[got], got == 0 ? -7 : per[got] * n, got >= 5, names[got]) < 0) {
      break;
    }
    if (got == 0) {
      n = b[0].len / 56;
    }
  }
  if (got == 7) {
    for (Py_ssize_t i = 0; i < n; i++) {
      ((double*)b[6].buf)[i] = tracking_row((const double*)b[0].buf + 7 * i, (const double*)b[1].buf + 7 * i,
                                            (const double*)b[2].buf + 7 * i, ((const double*)b[3].buf)[i],
                                            (const double*)b[4].buf + 7 * i, (double*)b[5].buf + 21 * i);
    }
  }
  for (int j = 0; j < got; j++) {
    PyBuffer_Release(&b[j]);
  }
  if (got < 7) {
    return NULL;
  }
  Py_RETURN_NONE;
}

/* tracking_batch(q, qo, dqo, t, q0, A, w, sq_err, steps, low, high, keys, work, out, reward, err, rms, success,
 *                error_scale, success_threshold, max_steps): one step's end of n robots of FrankaTorqueTracking-v0
 * (FrankaTorqueTrackingEnv._get_obs and _evaluate). float64 arrays: q (n, 7) true joint positions, qo and dqo
 * (n, 7) observed ones, t (n) time since the episode start, q0, A, w (n, 7) the trajectories, sq_err (n) (updated),
 * low and high (S) the observation bounds, work (n, S) (written), reward, err, rms, success (n) (written; success
 * 1.0 or 0.0); steps (n) and keys (6: offsets in an observation of q, dq, q_desired, dq_desired, ddq_desired,
 * time) int64; out (n, S) float32. The observation is packed as ObservationPacker packs it (clipped in work, NaN
 * as 0, cast into out), sq_err += err^2, reward = -min(err / error_scale, 1), rms = sqrt(sq_err / max(steps, 1)),
 * success = steps >= max_steps and rms < success_threshold. */
PyObject* fvs_tracking_batch(PyObject* self, PyObject* const* args, Py_ssize_t nargs) {
  (void)self;
  enum { NB = 18 };
  if (nargs != NB + 3) {
    PyErr_SetString(PyExc_TypeError, "tracking_batch(q, qo, dqo, t, q0, A, w, sq_err, steps, low, high, keys, work, "
                                     "out, reward, err, rms, success, error_scale, success_threshold, max_steps)");
    return NULL;
  }
  static const char* names[NB] = {"q", "qo", "dqo", "t", "q0", "A", "w", "sq_err", "steps", "low", "high", "keys",
                                  "work", "out", "reward", "err", "rms", "success"};
  const double error_scale = PyFloat_AsDouble(args[NB]), threshold = PyFloat_AsDouble(args[NB + 1]),
               max_steps = PyFloat_AsDouble(args[NB + 2]);
  if (PyErr_Occurred()) {
    return NULL;
  }
  Py_buffer b[NB];
  int got = 0, ok = 1;
  for (; got < NB; got++) {
    const int writable = got == 7 || got >= 12;
    if (PyObject_GetBuffer(args[got], &b[got], PyBUF_C_CONTIGUOUS | (writable ? PyBUF_WRITABLE : 0)) < 0) {
      ok = 0;
      break;
    }
  }
  const Py_ssize_t n = ok ? b[3].len / 8 : 0, S = ok ? b[9].len / 8 : 0;
  if (ok) { /* sizes: (n, 7) x 3, (n), (n, 7) x 3, (n), (n) int64, (S) x 2, (6) int64, (n, S), (n, S) f32, (n) x 4 */
    static const int per7[NB] = {7, 7, 7, 1, 7, 7, 7, 1, 1, 0, 0, 0, 0, 0, 1, 1, 1, 1};
    for (int j = 0; j < NB && ok; j++) {
      Py_ssize_t want;
      if (j == 9 || j == 10) {
        want = 8 * S;
      } else if (j == 11) {
        want = 48;
      } else if (j == 12) {
        want = 8 * n * S;
      } else if (j == 13) {
        want = 4 * n * S;
      } else {
        want = 8 * n * per7[j];
      }
      if (b[j].len != want) {
        PyErr_Format(PyExc_ValueError, "tracking_batch: %s has %zd bytes, expected %zd", names[j], b[j].len, want);
        ok = 0;
      }
    }
  }
  if (ok) {
    const double *q = b[0].buf, *qo = b[1].buf, *dqo = b[2].buf, *t = b[3].buf, *q0 = b[4].buf, *A = b[5].buf,
                 *w = b[6].buf, *low = b[9].buf, *high = b[10].buf;
    double *sq = b[7].buf, *work = b[12].buf, *reward = b[14].buf, *err = b[15].buf, *rms = b[16].buf,
           *success = b[17].buf;
    const int64_t *steps = b[8].buf, *key = b[11].buf;
    float* out = b[13].buf;
    for (Py_ssize_t i = 0; i < n; i++) {
      double des[21];
      const double e = tracking_row(q0 + 7 * i, A + 7 * i, w + 7 * i, t[i], q + 7 * i, des);
      double* v = work + S * i;
      put_tracking(v, key, qo + 7 * i, dqo + 7 * i, des, t + i);
      clip_cast(v, low, high, out + S * i, S);
      err[i] = e;
      sq[i] = sq[i] + e * e;
      const double st = (double)steps[i];
      rms[i] = sqrt(sq[i] / (st > 1.0 ? st : 1.0));
      success[i] = (st >= max_steps && rms[i] < threshold) ? 1.0 : 0.0;
      const double r = e / error_scale;
      reward[i] = -(r < 1.0 ? r : 1.0);
    }
  }
  for (int j = 0; j < got; j++) {
    PyBuffer_Release(&b[j]);
  }
  if (!ok) {
    return NULL;
  }
  Py_RETURN_NONE;
}

/* tracking_post(P, I, model_address, data_address, out) after the physics of a FrankaTorqueTracking-v0 period (the
 * plan's geometry block holds the episode's q0, A, w (7 each) and its start time t0; its key slots are q, dq,
 * q_desired, dq_desired, ddq_desired, time): codes as visual_post's; on 0 or 1 the desired trajectory at
 * t = time - t0 packed with q, dq and t into out and the tracking error of the true joint positions written into the
 * truth record's first number. */
PyObject* fvs_tracking_post(PyObject* self, PyObject* const* args, Py_ssize_t nargs) {
  (void)self;
  static const int key_size[8] = {7, 7, 7, 7, 7, 1, 0, 0};
  if (nargs != 5) {
    PyErr_SetString(PyExc_TypeError, "tracking_post(P, I, model_address, data_address, out)");
    return NULL;
  }
  const mjModel* m;
  mjData* d;
  post_ctx c;
  const int r = post_begin(args, "tracking_post", key_size, &m, &d, &c);
  if (r != 0) {
    return r == -1 ? PyLong_FromLong(-1) : NULL;
  }
  double* P = c.P;
  const double* traj = P + P_GEO;
  const double t = d->time - traj[21];
  double des[21];
  P[P_TRUTH] = tracking_row(traj, traj + 7, traj + 14, t, c.q, des);
  double* work = P + P_WORK;
  const int64_t* key = c.I + I_KEYS;
  put_tracking(work, key, c.q, c.dq, des, &t);
  (void)m;
  return post_end(&c);
}
