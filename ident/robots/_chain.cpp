// The joint-torque regressor of a serial chain of revolute joints, batched (ident/robots/chain.py).
//
// For each evaluation b: the regressor Y (n x 10 n) of tau = Y pi at joint positions given by their cosines and
// sines, speeds v and accelerations a, the parameters pi of each body in pinocchio's order (m, m c, I at the
// joint frame's origin: xx, xy, yy, xz, yz, zz), the same quantity as pinocchio's computeJointTorqueRegressor.
// A forward pass gives each body's spatial velocity and acceleration (gravity as the base's acceleration) in its
// own frame, the body's 6 x 10 regressor follows, and joint j's row of body i's block is the motion axis of j,
// carried into frame i, against it.
//
// It is ident/robots/chain.py's numpy formulas (_regressor_numpy) operation for operation on IEEE doubles, in the
// same order (built with -ffp-contract=off: no fused multiply-add), so both give the same bits;
// tests/ident/test_chain.py checks it, and checks both against pinocchio and a long-double evaluation.
// chain.py is the only caller: it checks the arrays (C-contiguous doubles of the stated shapes) and passes their
// addresses.

#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <cmath>
#include <cstdint>
#include <new>

namespace {

const int MAXJ = 32;  // joints at most (chain.py checks)

inline void cross(const double* a, const double* b, double* o) {
  o[0] = a[1] * b[2] - a[2] * b[1];
  o[1] = a[2] * b[0] - a[0] * b[2];
  o[2] = a[0] * b[1] - a[1] * b[0];
}

// x <- R^T (x + w x p)  (the motion (x, w) seen from the child frame: its linear part)
inline void inv_linear(const double* R, const double* w, const double* p, double* x) {
  double c[3], t[3];
  cross(w, p, c);
  t[0] = x[0] + c[0];
  t[1] = x[1] + c[1];
  t[2] = x[2] + c[2];
  for (int k = 0; k < 3; ++k) x[k] = (R[k] * t[0] + R[3 + k] * t[1]) + R[6 + k] * t[2];
}

// w <- R^T w
inline void inv_angular(const double* R, double* w) {
  const double t0 = w[0], t1 = w[1], t2 = w[2];
  for (int k = 0; k < 3; ++k) w[k] = (R[k] * t0 + R[3 + k] * t1) + R[6 + k] * t2;
}

// The kinematics of one position: each joint's rotation R[i] (its frame in its parent's) and the motion axes of
// joints j <= i seen from frame i, S[i][j] = (linear, angular): a function of the cosines and sines only, kept
// while the next evaluations share them (the same numbers as recomputing them).
struct Kinematics {
  double R[MAXJ][9];
  double S[MAXJ][MAXJ][6];
};

void kinematics(int n, const double* cq, const double* sq, const double* R0, const double* p0, const double* ax,
                const double* IA, const double* K, const double* AA, Kinematics& kin) {
  for (int i = 0; i < n; ++i) {
    const double c = cq[i], s = sq[i];
    const double* r0 = R0 + 9 * i;
    const double* p = p0 + 3 * i;
    double Rj[9];
    double* R = kin.R[i];
    for (int k = 0; k < 9; ++k) Rj[k] = (c * IA[9 * i + k] + s * K[9 * i + k]) + AA[9 * i + k];
    for (int r = 0; r < 3; ++r)
      for (int k = 0; k < 3; ++k)
        R[3 * r + k] = (r0[3 * r] * Rj[k] + r0[3 * r + 1] * Rj[3 + k]) + r0[3 * r + 2] * Rj[6 + k];
    for (int j = 0; j < i; ++j) {  // the ancestors' axes, from frame i - 1 to frame i
      double* o = kin.S[i][j];
      const double* src = kin.S[i - 1][j];
      o[0] = src[0];
      o[1] = src[1];
      o[2] = src[2];
      o[3] = src[3];
      o[4] = src[4];
      o[5] = src[5];
      inv_linear(R, o + 3, p, o);
      inv_angular(R, o + 3);
    }
    double* o = kin.S[i][i];
    o[0] = 0.0;
    o[1] = 0.0;
    o[2] = 0.0;
    o[3] = ax[3 * i];
    o[4] = ax[3 * i + 1];
    o[5] = ax[3 * i + 2];
  }
}

// one evaluation at the kinematics kin; Y (n x 10 n, row-major) zero-filled by the caller, or with packed the
// live entries only (joint j's row from body j on: row j starts at 10 (j n - j (j - 1) / 2))
void evaluate(int n, const Kinematics& kin, const double* qd, const double* qdd, const double* p0, const double* ax,
              const double* g, bool packed, double* Y) {
  double lv[3] = {0.0, 0.0, 0.0}, w[3] = {0.0, 0.0, 0.0};
  double la[3] = {-g[0], -g[1], -g[2]}, dw[3] = {0.0, 0.0, 0.0};
  const int cols = 10 * n;
  for (int i = 0; i < n; ++i) {
    const double* p = p0 + 3 * i;
    const double* e = ax + 3 * i;
    const double* R = kin.R[i];
    // velocity: the parent's seen from this frame, plus the joint's
    inv_linear(R, w, p, lv);
    inv_angular(R, w);
    double u[3];
    for (int k = 0; k < 3; ++k) {
      u[k] = e[k] * qd[i];
      w[k] = w[k] + u[k];
    }
    // acceleration: the parent's seen from this frame, plus v x (S qd) and S qdd
    inv_linear(R, dw, p, la);
    inv_angular(R, dw);
    double t[3];
    cross(lv, u, t);
    for (int k = 0; k < 3; ++k) la[k] = la[k] + t[k];
    cross(w, u, t);
    for (int k = 0; k < 3; ++k) dw[k] = (dw[k] + t[k]) + e[k] * qdd[i];
    // the body's regressor: linear rows [b, skew(dw) + skew(w)^2, 0], angular rows [0, -skew(b), L(dw) + w x L(w)]
    double b[3];
    cross(w, lv, t);
    for (int k = 0; k < 3; ++k) b[k] = la[k] + t[k];
    const double w0 = w[0], w1 = w[1], w2 = w[2];
    const double d0 = dw[0], d1 = dw[1], d2 = dw[2];
    const double ww = (w0 * w0 + w1 * w1) + w2 * w2;
    const double M3[3][3] = {{w0 * w0 - ww, w0 * w1 - d2, w0 * w2 + d1},
                             {w1 * w0 + d2, w1 * w1 - ww, w1 * w2 - d0},
                             {w2 * w0 - d1, w2 * w1 + d0, w2 * w2 - ww}};
    const double N3[3][3] = {{0.0, b[2], -b[1]}, {-b[2], 0.0, b[0]}, {b[1], -b[0], 0.0}};
    const double A6[3][6] = {{d0, d1 - w2 * w0, -(w2 * w1), d2 + w1 * w0, w1 * w1 - w2 * w2, w1 * w2},
                             {w2 * w0, d0 + w2 * w1, d1, w2 * w2 - w0 * w0, d2 - w0 * w1, -(w0 * w2)},
                             {-(w1 * w0), w0 * w0 - w1 * w1, w0 * w1, d0 - w1 * w2, d1 + w0 * w2, d2}};
    for (int j = 0; j <= i; ++j) {
      const double* sl = kin.S[i][j];
      const double* sa = sl + 3;
      double* y = packed ? Y + 10 * (j * n - j * (j - 1) / 2) + 10 * (i - j) : Y + j * cols + 10 * i;
      y[0] = (sl[0] * b[0] + sl[1] * b[1]) + sl[2] * b[2];
      for (int k = 0; k < 3; ++k)
        y[1 + k] = ((((sl[0] * M3[0][k] + sl[1] * M3[1][k]) + sl[2] * M3[2][k]) + sa[0] * N3[0][k]) +
                    sa[1] * N3[1][k]) + sa[2] * N3[2][k];
      for (int k = 0; k < 6; ++k) y[4 + k] = (sa[0] * A6[0][k] + sa[1] * A6[1][k]) + sa[2] * A6[2][k];
    }
  }
}

bool same(const double* a, const double* b, long long n) {
  for (long long k = 0; k < n; ++k)
    if (a[k] != b[k] || std::signbit(a[k]) != std::signbit(b[k])) return false;
  return true;
}

template <typename T>
T* at(unsigned long long address) {
  return reinterpret_cast<T*>(static_cast<std::uintptr_t>(address));
}

// regressor(B, n, packed, cq, sq, qd, qdd, R0, p0, ax, IA, K, AA, g, Y): addresses of C-contiguous double arrays
// (B, n) x 4, (n, 9), (n, 3), (n, 3), (n, 9) x 3, (3,), Y (B, n, 10 n) zero-filled or, packed, (B, 5 n (n + 1))
PyObject* regressor(PyObject*, PyObject* args) {
  long long B = 0, n = 0;
  int packed = 0;
  unsigned long long a[14];
  if (!PyArg_ParseTuple(args, "LLpKKKKKKKKKKKK", &B, &n, &packed, &a[0], &a[1], &a[2], &a[3], &a[4], &a[5], &a[6],
                        &a[7], &a[8], &a[9], &a[10], &a[11]))
    return nullptr;
  if (n < 1 || n > MAXJ || B < 0) {
    PyErr_SetString(PyExc_ValueError, "regressor: n must be in [1, 32] and B >= 0");
    return nullptr;
  }
  const double *cq = at<const double>(a[0]), *sq = at<const double>(a[1]), *qd = at<const double>(a[2]),
               *qdd = at<const double>(a[3]), *R0 = at<const double>(a[4]), *p0 = at<const double>(a[5]),
               *ax = at<const double>(a[6]), *IA = at<const double>(a[7]), *K = at<const double>(a[8]),
               *AA = at<const double>(a[9]), *g = at<const double>(a[10]);
  double* Y = at<double>(a[11]);
  const long long stride = packed ? 5 * n * (n + 1) : n * 10 * n;
  Kinematics* kin = new (std::nothrow) Kinematics;
  if (kin == nullptr) return PyErr_NoMemory();
  Py_BEGIN_ALLOW_THREADS;
  for (long long k = 0; k < B; ++k) {
    // consecutive evaluations at one position (the same cosines and sines) share its kinematics
    if (k == 0 || !same(cq + k * n, cq + (k - 1) * n, n) || !same(sq + k * n, sq + (k - 1) * n, n))
      kinematics(int(n), cq + k * n, sq + k * n, R0, p0, ax, IA, K, AA, *kin);
    evaluate(int(n), *kin, qd + k * n, qdd + k * n, p0, ax, g, packed != 0, Y + k * stride);
  }
  Py_END_ALLOW_THREADS;
  delete kin;
  Py_RETURN_NONE;
}

PyMethodDef methods[] = {
    {"regressor", regressor, METH_VARARGS, "The batched joint-torque regressor (ident/robots/chain.py)."},
    {nullptr, nullptr, 0, nullptr}};

PyModuleDef module = {PyModuleDef_HEAD_INIT, "_chain", "The batched regressor of a serial chain.", -1, methods};

}  // namespace

extern "C" PyMODINIT_FUNC PyInit__chain(void) {
  PyObject* m = PyModule_Create(&module);
  if (m == nullptr) return nullptr;
  if (PyModule_AddIntConstant(m, "LAYOUT_VERSION", 2) < 0 || PyModule_AddIntConstant(m, "MAXJ", MAXJ) < 0) {
    Py_DECREF(m);
    return nullptr;
  }
  return m;
}
