// Midpoint-radius interval arithmetic (ident/numerics/jets.py, class MR and ein) as fused numpy ufuncs.
//
// Each ufunc is one of MR's operations with its operands' midpoints, linear parts (a Taylor model in tau) and
// radii as separate arrays: numpy broadcasts them and calls these loops, which evaluate jets.py's formulas
// operation for operation on IEEE doubles in the same order (built with -ffp-contract=off: no fused multiply-add),
// so the compiled and the numpy paths give the same bits; tests/ident/test_fused_mr.py checks it on random and
// special operands. The point is speed: numpy evaluates one formula as 10-25 passes over temporaries, these as one.
//
// The contractions (ein) are generalized ufuncs over a last core axis n: the sums run from k = 0 to n - 1, the
// order ident/numerics/jets.py's numpy fallback (_contract_numpy) uses too.

#define PY_SSIZE_T_CLEAN
#include <Python.h>

#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>
#include <numpy/ufuncobject.h>

#include <cmath>

namespace {

const double U = 0x1p-53;
const double ONE = 1.0 + 16 * 0x1p-53;
const double TINY = 1e-300;

// One elementwise loop per operation: BODY reads the inputs ARG(0) .. ARG(NIN - 1) of element k and writes the
// outputs OUT(NIN) ..; scalars only (locals in registers: a local array of operands cost store-forwarding stalls).
// Where every operand is contiguous (operands of one shape) the strides are the constant 8, so the compiler may
// vectorise; the same operations per element in the same order either way, so the same bits.
#define ARG(i) (*reinterpret_cast<const double*>(args[i] + k * st[i]))
#define OUT(i) (*reinterpret_cast<double*>(args[i] + k * st[i]))
#define ELEMENTWISE(NAME, NARGS, ...)                                                             \
  void NAME(char** args, const npy_intp* dims, const npy_intp* steps, void*) {                  \
    const npy_intp n = dims[0];                                                                 \
    bool contiguous = true;                                                                     \
    for (int i = 0; i < NARGS; ++i) contiguous = contiguous && steps[i] == npy_intp(sizeof(double)); \
    if (contiguous) {                                                                           \
      const npy_intp st[9] = {8, 8, 8, 8, 8, 8, 8, 8, 8};                                       \
      for (npy_intp k = 0; k < n; ++k) __VA_ARGS__                                                   \
    } else {                                                                                    \
      const npy_intp* st = steps;                                                               \
      for (npy_intp k = 0; k < n; ++k) __VA_ARGS__                                                   \
    }                                                                                           \
  }

// MR + MR, plain: (ac, ar, bc, br) -> (c, r)
ELEMENTWISE(add_plain, 6, {
  const double c = ARG(0) + ARG(2);
  OUT(4) = c;
  OUT(5) = ((ARG(1) + ARG(3)) + U * std::fabs(c)) * ONE + TINY;
})

// MR + MR, both Taylor models: (ac, aa, ar, bc, ba, br) -> (c, a, r)
ELEMENTWISE(add_tm, 9, {
  const double c = ARG(0) + ARG(3);
  const double a = ARG(1) + ARG(4);
  OUT(6) = c;
  OUT(7) = a;
  OUT(8) = ((ARG(2) + ARG(5)) + U * (std::fabs(c) + std::fabs(a))) * ONE + TINY;
})

// MR + MR, one Taylor model (its linear part a): (ac, ar, bc, br, a) -> (c, r)
ELEMENTWISE(add_tm1, 7, {
  const double c = ARG(0) + ARG(2);
  OUT(5) = c;
  OUT(6) = ((ARG(1) + ARG(3)) + U * (std::fabs(c) + std::fabs(ARG(4)))) * ONE + TINY;
})

// MR * exact constant, plain: (ac, ar, bc) -> (c, r)
ELEMENTWISE(mul_const, 5, {
  const double c = ARG(0) * ARG(2);
  OUT(3) = c;
  OUT(4) = (ARG(1) * std::fabs(ARG(2)) + U * std::fabs(c)) * ONE + TINY;
})

// Taylor model * exact constant: (ac, aa, ar, bc) -> (c, a, r)
ELEMENTWISE(mul_const_tm, 7, {
  const double c = ARG(0) * ARG(3);
  const double a = ARG(1) * ARG(3);
  const double err = std::fabs(c) + std::fabs(a);
  OUT(4) = c;
  OUT(5) = a;
  OUT(6) = (ARG(2) * std::fabs(ARG(3)) + U * err) * ONE + TINY;
})

// MR * MR, plain: (ac, ar, bc, br) -> (c, r)
ELEMENTWISE(mul_plain, 6, {
  const double ac = ARG(0), ar = ARG(1), bc = ARG(2), br = ARG(3);
  const double c = ac * bc;
  OUT(4) = c;
  OUT(5) = ((std::fabs(ac) * br + ar * (std::fabs(bc) + br)) + U * std::fabs(c)) * ONE + TINY;
})

// Taylor model * Taylor model: (ac, aa, ar, bc, ba, br) -> (c, a, r)
ELEMENTWISE(mul_tm, 9, {
  const double ac = ARG(0), aa = ARG(1), ar = ARG(2), bc = ARG(3), ba = ARG(4), br = ARG(5);
  const double m1 = std::fabs(ac) + std::fabs(aa);
  const double m2 = std::fabs(bc) + std::fabs(ba);
  const double p = aa * ba;
  const double extra = 0.5 * std::fabs(p);
  OUT(6) = ac * bc + 0.5 * p;
  OUT(7) = ac * ba + aa * bc;
  OUT(8) = (((m1 * br + ar * (m2 + br)) + extra) + 4 * U * m1 * m2) * ONE + TINY;
})

// Taylor model (left) * MR with a radius: (ac, aa, ar, bc, br) -> (c, a, r)
ELEMENTWISE(mul_tm_left, 8, {
  const double ac = ARG(0), aa = ARG(1), ar = ARG(2), bc = ARG(3), br = ARG(4);
  const double m1 = std::fabs(ac) + std::fabs(aa);
  const double m2 = std::fabs(bc);
  OUT(5) = ac * bc;
  OUT(6) = aa * bc;
  OUT(7) = (((m1 * br + ar * (m2 + br)) + 0.0) + 4 * U * m1 * m2) * ONE + TINY;
})

// MR with a radius (left) * Taylor model: (ac, ar, bc, ba, br) -> (c, a, r)
ELEMENTWISE(mul_tm_right, 8, {
  const double ac = ARG(0), ar = ARG(1), bc = ARG(2), ba = ARG(3), br = ARG(4);
  const double m1 = std::fabs(ac);
  const double m2 = std::fabs(bc) + std::fabs(ba);
  OUT(5) = ac * bc;
  OUT(6) = ac * ba;
  OUT(7) = (((m1 * br + ar * (m2 + br)) + 0.0) + 4 * U * m1 * m2) * ONE + TINY;
})

#undef ELEMENTWISE
#undef ARG
#undef OUT

// the j-th element of the core axis of argument i in outer iteration k
#define CORE(i, j) (*reinterpret_cast<const double*>(args[i] + k * steps[i] + (j) * core[i]))
#define OUTG(i) (*reinterpret_cast<double*>(args[i] + k * steps[i]))

// The contractions take each operand's per-element parts that do not depend on the other operand already formed
// (ident/numerics/fused.py: the same expressions, so the same values), which halves the work per term.

// sum_j of plain operands: (ac, |ac|, ar)(n), (bc, p1, p2)(n), g () -> (c, r), p1 = br + g |bc|, p2 = |bc| + br:
//   c = sum ac bc;  r = (sum |ac| p1 + sum ar p2) (1 + 3 g) + TINY
// N > 0: a core axis of N (unrolled), else dims[1]; the first term assigned, the others added in index order.
template <int N>
void plain_sums(char** args, const npy_intp* dims, const npy_intp* steps) {
  const npy_intp n = N > 0 ? N : dims[1];
  const npy_intp* core = steps + 9;  // core strides of the 6 inputs with a core axis
  for (npy_intp k = 0; k < dims[0]; ++k) {
    const double g = *reinterpret_cast<const double*>(args[6] + k * steps[6]);
    double c = 0.0, r1 = 0.0, r2 = 0.0;
    for (npy_intp j = 0; j < n; ++j) {
      const double t = CORE(0, j) * CORE(3, j);
      const double t1 = CORE(1, j) * CORE(4, j);
      const double t2 = CORE(2, j) * CORE(5, j);
      if (j == 0) {
        c = t;
        r1 = t1;
        r2 = t2;
      } else {
        c = c + t;
        r1 = r1 + t1;
        r2 = r2 + t2;
      }
    }
    OUTG(7) = c;
    OUTG(8) = (r1 + r2) * (1.0 + 3 * g) + TINY;
  }
}

// sum_j of Taylor models: (ac, aa, ar, m1, |aa|)(n), (bc, ba, q1, q2, |ba|)(n), g () -> (c, lin, r), with
// m1 = |ac| + |aa|, m2 = |bc| + |ba|, q1 = br + 2 g m2, q2 = m2 + br:
//   c = sum ac bc + 0.5 sum aa ba;  lin = sum ac ba + sum aa bc
//   r = (sum m1 q1 + sum ar q2 + 0.5 sum |aa| |ba|) (1 + 4 g) + TINY
template <int N>
void tm_sums(char** args, const npy_intp* dims, const npy_intp* steps) {
  const npy_intp n = N > 0 ? N : dims[1];
  const npy_intp* core = steps + 14;
  for (npy_intp k = 0; k < dims[0]; ++k) {
    const double g = *reinterpret_cast<const double*>(args[10] + k * steps[10]);
    double cc = 0.0, aa2 = 0.0, l1 = 0.0, l2 = 0.0, r1 = 0.0, r2 = 0.0, r3 = 0.0;
    for (npy_intp j = 0; j < n; ++j) {
      const double ac = CORE(0, j), aa = CORE(1, j), bc = CORE(5, j), ba = CORE(6, j);
      const double t_cc = ac * bc, t_aa = aa * ba, t_l1 = ac * ba, t_l2 = aa * bc;
      const double t_r1 = CORE(3, j) * CORE(7, j), t_r2 = CORE(2, j) * CORE(8, j), t_r3 = CORE(4, j) * CORE(9, j);
      if (j == 0) {
        cc = t_cc; aa2 = t_aa; l1 = t_l1; l2 = t_l2; r1 = t_r1; r2 = t_r2; r3 = t_r3;
      } else {
        cc = cc + t_cc; aa2 = aa2 + t_aa; l1 = l1 + t_l1; l2 = l2 + t_l2; r1 = r1 + t_r1; r2 = r2 + t_r2;
        r3 = r3 + t_r3;
      }
    }
    OUTG(11) = cc + 0.5 * aa2;
    OUTG(12) = l1 + l2;
    OUTG(13) = ((r1 + r2) + 0.5 * r3) * (1.0 + 4 * g) + TINY;
  }
}

// the core axes of the jets' contractions: 3 (vectors), 4 (joints) and 8 (variables) unrolled
#define BY_SIZE(FN)                                   \
  switch (dims[1]) {                                  \
    case 1: return FN<1>(args, dims, steps);          \
    case 2: return FN<2>(args, dims, steps);          \
    case 3: return FN<3>(args, dims, steps);          \
    case 4: return FN<4>(args, dims, steps);          \
    case 8: return FN<8>(args, dims, steps);          \
    default: return FN<0>(args, dims, steps);         \
  }

void contract_plain(char** args, const npy_intp* dims, const npy_intp* steps, void*) { BY_SIZE(plain_sums) }
void contract_tm(char** args, const npy_intp* dims, const npy_intp* steps, void*) { BY_SIZE(tm_sums) }

#undef BY_SIZE
#undef CORE
#undef OUTG

struct Def {
  const char* name;
  PyUFuncGenericFunction fn;
  int nin, nout;
  const char* signature;  // nullptr: elementwise
};

const Def DEFS[] = {
    {"add_plain", add_plain, 4, 2, nullptr},
    {"add_tm", add_tm, 6, 3, nullptr},
    {"add_tm1", add_tm1, 5, 2, nullptr},
    {"mul_const", mul_const, 3, 2, nullptr},
    {"mul_const_tm", mul_const_tm, 4, 3, nullptr},
    {"mul_plain", mul_plain, 4, 2, nullptr},
    {"mul_tm", mul_tm, 6, 3, nullptr},
    {"mul_tm_left", mul_tm_left, 5, 3, nullptr},
    {"mul_tm_right", mul_tm_right, 5, 3, nullptr},
    {"contract_plain", contract_plain, 7, 2, "(n),(n),(n),(n),(n),(n),()->(),()"},
    {"contract_tm", contract_tm, 11, 3, "(n),(n),(n),(n),(n),(n),(n),(n),(n),(n),()->(),(),()"},
};
const int NDEFS = sizeof(DEFS) / sizeof(DEFS[0]);

PyUFuncGenericFunction FUNCS[NDEFS][1];
char TYPES[NDEFS][16];
void* DATA[1] = {nullptr};

PyModuleDef MODULE = {PyModuleDef_HEAD_INIT, "_mr", "Fused midpoint-radius interval ufuncs (see _mr.cpp).", -1,
                      nullptr};

}  // namespace

PyMODINIT_FUNC PyInit__mr(void) {
  import_array();
  import_umath();
  PyObject* m = PyModule_Create(&MODULE);
  if (!m) return nullptr;
  for (int i = 0; i < NDEFS; ++i) {
    const Def& d = DEFS[i];
    FUNCS[i][0] = d.fn;
    for (int t = 0; t < d.nin + d.nout; ++t) TYPES[i][t] = NPY_DOUBLE;
    PyObject* f = d.signature == nullptr
                      ? PyUFunc_FromFuncAndData(FUNCS[i], DATA, TYPES[i], 1, d.nin, d.nout, PyUFunc_None, d.name,
                                                d.name, 0)
                      : PyUFunc_FromFuncAndDataAndSignature(FUNCS[i], DATA, TYPES[i], 1, d.nin, d.nout, PyUFunc_None,
                                                            d.name, d.name, 0, d.signature);
    if (!f || PyModule_AddObject(m, d.name, f) < 0) {
      Py_XDECREF(f);
      Py_DECREF(m);
      return nullptr;
    }
  }
  if (PyModule_AddIntConstant(m, "LAYOUT_VERSION", 2) < 0 || PyModule_AddObject(m, "U", PyFloat_FromDouble(U)) < 0 ||
      PyModule_AddObject(m, "ONE", PyFloat_FromDouble(ONE)) < 0 ||
      PyModule_AddObject(m, "TINY", PyFloat_FromDouble(TINY)) < 0) {
    Py_DECREF(m);
    return nullptr;
  }
  return m;
}
