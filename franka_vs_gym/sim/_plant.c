/* The simulated FER's joint friction inside MuJoCo's step: a passive-force callback (mjcb_passive).
 *
 * MuJoCo's physics callbacks are global to a process, so the parameters live in each model: a joint whose first
 * user number (jnt_user[j][0]) is FVS_TAG carries the friction law of franka_vs_gym.model (per joint, SI units):
 *
 *   jnt_user[j] = [FVS_TAG, phi1 (Nm), phi2 (s/rad), phi3 (rad/s), viscous (Nm s/rad), coulomb (Nm),
 *                  coulomb_vel (rad/s)]
 *   tau_f(dq) = phi1 / (1 + exp(-(phi2 dq + phi2 phi3))) - phi1 / (1 + exp(-phi2 phi3))
 *             + viscous dq + coulomb tanh(dq / coulomb_vel)
 *
 * and the callback adds -tau_f(qvel) to qfrc_passive of that joint's dof. Joints without the tag (other models,
 * robots with the plant's friction switched off) are left alone, so any number of robots in one scene, and any
 * number of models stepped by mujoco.batch on its threads, each get their own law. The callback reads only its
 * arguments: it is thread-safe and never takes the GIL.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>

#include <mujoco/mujoco.h>

#define FVS_TAG 1179013959.0 /* "FVSG" as an integer, exactly representable */
#define FVS_NUSER 7

static void fvs_passive(const mjModel* m, mjData* d) {
  const mjtSize nu = m->nuser_jnt;
  if (nu < FVS_NUSER) {
    return;
  }
  for (mjtSize j = 0; j < m->njnt; j++) {
    const mjtNum* u = m->jnt_user + j * nu;
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
    d->qfrc_passive[dof] -= tau;
  }
}

static PyObject* callback_address(PyObject* self, PyObject* args) {
  (void)self;
  (void)args;
  return PyLong_FromVoidPtr((void*)&fvs_passive);
}

static PyMethodDef methods[] = {
    {"callback_address", callback_address, METH_NOARGS,
     "Address of the C passive-force callback (for mujoco.set_mjcb_passive through ctypes)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_plant",
    "The plant's joint friction as a C passive-force callback for MuJoCo (see franka_vs_gym.sim.plant).", -1,
    methods,
};

PyMODINIT_FUNC PyInit__plant(void) {
  PyObject* mod = PyModule_Create(&module);
  if (mod == NULL) {
    return NULL;
  }
  if (PyModule_AddIntConstant(mod, "MJ_VERSION_HEADER", mjVERSION_HEADER) < 0 ||
      PyModule_AddObject(mod, "TAG", PyFloat_FromDouble(FVS_TAG)) < 0 ||
      PyModule_AddIntConstant(mod, "NUSER", FVS_NUSER) < 0) {
    Py_DECREF(mod);
    return NULL;
  }
  return mod;
}
