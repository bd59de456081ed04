// The 1 kHz sample loop of h4bench.sim.simulate in compiled code: encoder rounding, the velocity filter, the
// joint PI law, the torque error (precomputed part, q-dependent ripple, command-proportional gain), MuJoCo's
// forward pass at the sampled state, the recording and the integrator, for samples [k0, k1).
//
// It is the Python loop (sim/simulate.py: _loop, _FloatLaw.step_list, the noise streams' at_list) operation
// for operation on IEEE doubles, in the same order (built with -ffp-contract=off: no fused multiply-add), so
// both paths give the same bits; tests/sim/test_compiled_loop.py checks it. No MuJoCo header is used: MuJoCo's
// functions come as addresses from the library the Python bindings loaded, the model and data as opaque
// pointers, the arrays as addresses of numpy buffers and of MjData's own arrays, checked by the Python caller
// (sim/compiled.py), which is the only caller.

#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <string>

namespace {

typedef void (*fn_md)(const void*, void*);
typedef void (*fn_mdi)(const void*, void*, int);
typedef void (*fn_err)(const char*);

struct MujocoError {
  std::string message;
};

void throwing_error(const char* msg) { throw MujocoError{msg ? msg : ""}; }

// pointer slots (the order of sim/compiled.py's _PTRS)
enum {
  P_MODEL, P_DATA, P_FORWARD, P_FIRST, P_STEP, P_USER_ERROR,
  P_QPOS, P_QVEL, P_QACC, P_CTRL, P_ACT, P_EFC_POS,
  P_QREF, P_QDREF, P_FF, P_PRE, P_RIPPLE, P_GAIN,
  P_REC_QPOS, P_REC_QVEL, P_REC_QACC, P_REC_APP, P_EFC, P_REC_CMD, P_REC_QM,
  P_STATE, P_OUT, NPTR
};
// integer slots
enum { I_NQ, I_NV, I_NE, I_NU, I_SUBSTEPS, I_FIRST_KIND, I_N, I_NRIP, I_NGAIN, I_HAS_RES, I_EFC_COLS, I_CHECK,
       I_QM0, I_QM1, I_QM2, I_QM3, NINT };
// double slots: res, pole, gain, then kp[4], kv[4], kidt[4], tmax[4], lo[4], hi[4]
enum { D_RES, D_POLE, D_GAIN, D_KP, D_KV = D_KP + 4, D_KIDT = D_KV + 4, D_TMAX = D_KIDT + 4, D_LO = D_TMAX + 4,
       D_HI = D_LO + 4, NDBL = D_HI + 4 };
// state: integrator[4], e_prev[4], qd_est[4], q_prev[4], saturated[4], q_prev_set
enum { S_INTEG = 0, S_EPREV = 4, S_QD = 8, S_QPREV = 12, S_SAT = 16, S_QPREV_SET = 20, NSTATE };

enum Status { OK = 0, NONFINITE_ANGLE = 1, NOISE_CHECK = 2, MUJOCO_ERROR = 3 };

inline int sign(double x) { return (x > 0) - (x < 0); }

// samples [k0, k1); returns the status and sets *at to the sample it stopped at (k1 when OK)
int run(const uint64_t* p, const int64_t* ni, const double* c, int64_t k0, int64_t k1, int64_t* at,
        std::string* message) {
  const void* m = reinterpret_cast<const void*>(p[P_MODEL]);
  void* d = reinterpret_cast<void*>(p[P_DATA]);
  fn_md forward = reinterpret_cast<fn_md>(p[P_FORWARD]);
  fn_md step = reinterpret_cast<fn_md>(p[P_STEP]);
  const int first_kind = static_cast<int>(ni[I_FIRST_KIND]);  // 0: RK4 (m, d, 4); 1: (m, d)
  fn_mdi first_rk = reinterpret_cast<fn_mdi>(p[P_FIRST]);
  fn_md first_md = reinterpret_cast<fn_md>(p[P_FIRST]);
  const double* qpos = reinterpret_cast<const double*>(p[P_QPOS]);
  const double* qvel = reinterpret_cast<const double*>(p[P_QVEL]);
  const double* qacc = reinterpret_cast<const double*>(p[P_QACC]);
  double* ctrl = reinterpret_cast<double*>(p[P_CTRL]);
  const double* act = reinterpret_cast<const double*>(p[P_ACT]);
  const double* efc_pos = reinterpret_cast<const double*>(p[P_EFC_POS]);
  const double* q_ref = reinterpret_cast<const double*>(p[P_QREF]);
  const double* qd_ref = reinterpret_cast<const double*>(p[P_QDREF]);
  const double* ff = reinterpret_cast<const double*>(p[P_FF]);
  const double* pre = reinterpret_cast<const double*>(p[P_PRE]);
  const double* ripple = reinterpret_cast<const double*>(p[P_RIPPLE]);
  const double* gainerr = reinterpret_cast<const double*>(p[P_GAIN]);
  double* rec_qpos = reinterpret_cast<double*>(p[P_REC_QPOS]);
  double* rec_qvel = reinterpret_cast<double*>(p[P_REC_QVEL]);
  double* rec_qacc = reinterpret_cast<double*>(p[P_REC_QACC]);
  double* rec_app = reinterpret_cast<double*>(p[P_REC_APP]);
  double* efc = reinterpret_cast<double*>(p[P_EFC]);
  double* rec_cmd = reinterpret_cast<double*>(p[P_REC_CMD]);
  double* rec_qm = reinterpret_cast<double*>(p[P_REC_QM]);
  double* s = reinterpret_cast<double*>(p[P_STATE]);
  double* out = reinterpret_cast<double*>(p[P_OUT]);  // q_true[4], tau[4] of the sample a check stopped at

  const int64_t nq = ni[I_NQ], nv = ni[I_NV], ne = ni[I_NE], nu = ni[I_NU], substeps = ni[I_SUBSTEPS];
  const int64_t nrip = ni[I_NRIP], ngain = ni[I_NGAIN], efc_cols = ni[I_EFC_COLS];
  const bool has_res = ni[I_HAS_RES] != 0, check = ni[I_CHECK] != 0;
  const int64_t qm_idx[4] = {ni[I_QM0], ni[I_QM1], ni[I_QM2], ni[I_QM3]};
  const double res = c[D_RES], pole = c[D_POLE], gain = c[D_GAIN];

  fn_err* user_error = reinterpret_cast<fn_err*>(p[P_USER_ERROR]);
  fn_err saved = *user_error;
  *user_error = throwing_error;  // a MuJoCo error inside these calls returns here instead of ending the process
  int status = OK;
  int64_t k = k0;
  try {
    for (; k < k1; ++k) {
      double q_true[4], qm[4], tau[4], e[4];
      for (int j = 0; j < 4; ++j) q_true[j] = qpos[qm_idx[j]];
      if (has_res) {
        bool finite = true;
        for (int j = 0; j < 4; ++j) finite = finite && std::isfinite(q_true[j]);
        if (!finite) { status = NONFINITE_ANGLE; break; }
        for (int j = 0; j < 4; ++j) qm[j] = std::nearbyint(q_true[j] / res) * res;  // round half to even
      } else {
        for (int j = 0; j < 4; ++j) qm[j] = q_true[j];
      }
      const double* q_prev = s[S_QPREV_SET] != 0.0 ? s + S_QPREV : qm;
      double q_prev_copy[4];
      std::memcpy(q_prev_copy, q_prev, sizeof q_prev_copy);
      for (int j = 0; j < 4; ++j) {
        const double kp = c[D_KP + j], kv = c[D_KV + j], kidt = c[D_KIDT + j], t = c[D_TMAX + j], nt = -t;
        const double lo = c[D_LO + j], hi = c[D_HI + j];
        double ii = s[S_INTEG + j];
        const double v = pole * s[S_QD + j] + gain * (qm[j] - q_prev_copy[j]);  // VelocityFilter.step
        const double e_j = kp * (q_ref[4 * k + j] - qm[j]) + qd_ref[4 * k + j] - v;
        double cand = ii + kidt * (e_j + s[S_EPREV + j]);
        cand = cand < nt ? nt : (cand > t ? t : cand);
        double u = kv * e_j + cand + ff[4 * k + j];
        if (!(std::fabs(u) > t && sign(e_j) == sign(u))) ii = cand;
        u = kv * e_j + ii + ff[4 * k + j];
        s[S_QD + j] = v;
        s[S_EPREV + j] = e_j;
        s[S_INTEG + j] = ii;
        s[S_SAT + j] = std::fabs(u) > t ? 1.0 : 0.0;
        u = u < nt ? nt : (u > t ? t : u);
        tau[j] = u > hi ? hi : (u < lo ? lo : u);
      }
      for (int j = 0; j < 4; ++j) s[S_QPREV + j] = qm[j];
      s[S_QPREV_SET] = 1.0;
      // the torque error: ErrorStream.at_list / the precomputed rows
      for (int j = 0; j < 4; ++j) e[j] = pre[4 * k + j];
      for (int64_t h = 0; h < nrip; ++h) {
        const double* r = ripple + 6 * h;  // order, amplitude, phase_0..3
        for (int j = 0; j < 4; ++j) e[j] += r[1] * std::sin(r[0] * q_true[j] + r[2 + j]);
      }
      bool stop = false;
      for (int64_t g = 0; g < ngain && !stop; ++g) {
        const double* r = gainerr + 5 * g;  // g_0..3, torque limit
        const double lim = r[4];
        bool inside = true;
        for (int j = 0; j < 4; ++j) inside = inside && (-lim <= tau[j] && tau[j] <= lim);
        if (!inside) { stop = true; break; }
        for (int j = 0; j < 4; ++j) e[j] += r[j] * tau[j];
      }
      if (!stop && check) {
        const double sum = e[0] + e[1] + e[2] + e[3];
        stop = (sum - sum != 0.0);
      }
      if (stop) {
        for (int j = 0; j < 4; ++j) { out[j] = q_true[j]; out[4 + j] = tau[j]; }
        status = NOISE_CHECK;
        break;
      }
      for (int j = 0; j < 4; ++j) ctrl[j] = tau[j] + e[j];
      forward(m, d);  // at the sampled state: MuJoCo's qacc, applied torque, loop violation
      std::memcpy(rec_qpos + nq * k, qpos, sizeof(double) * nq);
      std::memcpy(rec_qvel + nv * k, qvel, sizeof(double) * nv);
      std::memcpy(rec_qacc + nv * k, qacc, sizeof(double) * nv);
      std::memcpy(rec_app + nu * k, act, sizeof(double) * nu);
      if (ne > 0) std::memcpy(efc + efc_cols * k, efc_pos, sizeof(double) * ne);
      std::memcpy(rec_cmd + 4 * k, tau, sizeof tau);
      std::memcpy(rec_qm + 4 * k, qm, sizeof qm);
      if (first_kind == 0) first_rk(m, d, 4); else first_md(m, d);
      for (int64_t i = 1; i < substeps; ++i) step(m, d);
    }
  } catch (const MujocoError& err) {
    status = MUJOCO_ERROR;
    *message = err.message;
  }
  *user_error = saved;
  *at = k;
  return status;
}

PyObject* py_run(PyObject*, PyObject* args) {
  unsigned long long pp, pi, pc;
  long long k0, k1;
  if (!PyArg_ParseTuple(args, "KKKLL", &pp, &pi, &pc, &k0, &k1)) return nullptr;
  int64_t at = k0;
  std::string message;
  int status;
  Py_BEGIN_ALLOW_THREADS
  status = run(reinterpret_cast<const uint64_t*>(pp), reinterpret_cast<const int64_t*>(pi),
               reinterpret_cast<const double*>(pc), k0, k1, &at, &message);
  Py_END_ALLOW_THREADS
  return Py_BuildValue("iLs", status, static_cast<long long>(at), message.c_str());
}

// mju_error(message) called through MuJoCo's library under the swapped handler, as inside run(): returns what
// came back (the check that an error raised in MuJoCo unwinds to the caller instead of ending the process)
PyObject* py_error_roundtrip(PyObject*, PyObject* args) {
  unsigned long long user_error_addr, mju_error_addr;
  const char* text;
  if (!PyArg_ParseTuple(args, "KKs", &user_error_addr, &mju_error_addr, &text)) return nullptr;
  fn_err* user_error = reinterpret_cast<fn_err*>(user_error_addr);
  typedef void (*fn_mju_error)(const char*, ...);
  fn_mju_error mju_error = reinterpret_cast<fn_mju_error>(mju_error_addr);
  fn_err saved = *user_error;
  *user_error = throwing_error;
  std::string message = "(no error came back)";
  try {
    mju_error("%s", text);
  } catch (const MujocoError& err) {
    message = err.message;
  }
  *user_error = saved;
  return PyUnicode_FromString(message.c_str());
}

PyMethodDef methods[] = {
    {"error_roundtrip", py_error_roundtrip, METH_VARARGS,
     "error_roundtrip(mju_user_error address, mju_error address, text) -> the message caught."},
    {"run", py_run, METH_VARARGS,
     "run(pointers, ints, doubles, k0, k1) -> (status, k, message): samples [k0, k1) of the sample loop "
     "(the layout: h4bench.sim.compiled)."},
    {nullptr, nullptr, 0, nullptr}};

PyModuleDef module = {PyModuleDef_HEAD_INIT, "_loop", "The compiled sample loop of h4bench.sim.simulate.", -1,
                      methods};

}  // namespace

extern "C" PyMODINIT_FUNC PyInit__loop(void) {
  PyObject* mod = PyModule_Create(&module);
  if (mod == nullptr) return nullptr;
  if (PyModule_AddIntConstant(mod, "LAYOUT_VERSION", 1) < 0 || PyModule_AddIntConstant(mod, "NPTR", NPTR) < 0 ||
      PyModule_AddIntConstant(mod, "NINT", NINT) < 0 || PyModule_AddIntConstant(mod, "NDBL", NDBL) < 0 ||
      PyModule_AddIntConstant(mod, "NSTATE", NSTATE) < 0) {
    Py_DECREF(mod);
    return nullptr;
  }
  return mod;
}
