/* The visual tasks' per-step kernels (_task.c) and what they use of the plant (_plant.c). */
#ifndef FVS_TASK_H
#define FVS_TASK_H

#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <mujoco/mujoco.h>

/* _plant.c: the reflex record of the robot whose first joint is j0 (NULL if it has none), and its check on the
 * current state (the violation's code, recorded with the brakes engaged; 0 within the limits). */
mjtNum* fvs_reflex_record(const mjModel* m, mjData* d, int j0);
int fvs_reflex_check(const mjModel* m, mjData* d, int j0, mjtNum* s);

/* _task.c */
int fvs_plan_sizes(int* p_fixed, int* i_size);
PyObject* fvs_tag_truth(PyObject* self, PyObject* const* args, Py_ssize_t nargs);
PyObject* fvs_torque_cost(PyObject* self, PyObject* const* args, Py_ssize_t nargs);
PyObject* fvs_visual_pre(PyObject* self, PyObject* const* args, Py_ssize_t nargs);
PyObject* fvs_visual_post(PyObject* self, PyObject* const* args, Py_ssize_t nargs);
PyObject* fvs_tracking(PyObject* self, PyObject* const* args, Py_ssize_t nargs);
PyObject* fvs_tracking_batch(PyObject* self, PyObject* const* args, Py_ssize_t nargs);
PyObject* fvs_tracking_post(PyObject* self, PyObject* const* args, Py_ssize_t nargs);

#endif
