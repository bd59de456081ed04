"""The per-window reference computation of a serial arm's certified equation (the previous implementation, kept
as the oracle of :mod:`ident.robots.serial_steps`): per window and per sample step of it, one regressor call
(:func:`ident.robots.serial_steps.regressor_one`, the regressor the vectorised computation uses) at the window's
scaled speed and acceleration, and the local bounds of each step (:class:`_Steps`, cached) evaluated one step at a
time. Slow (a Python loop over windows x steps); the same numbers as the vectorised
:func:`ident.robots.serial_steps.inertial_rows` up to floating-point rounding (tests/ident/test_serial_fast.py).
"""

from __future__ import annotations

import numpy as np

from h4bench.ident.robots.serial_steps import (PARTS, StepGrid, c2_terms, hessian_quadratic, mass_derivatives,
                                               mass_hessian_bound, q_remainder, quadratic_speed_weights,
                                               regressor_one, speed_linear, step_displacements)
from h4bench.ident.robots.serial_steps import PIN_REL as _PIN_REL

__all__ = ["inertial_rows_reference"]


class _Steps(StepGrid):
    """Per-step local data at the measured mid-step position ``qh`` and speed estimate ``vh`` (regressor
    evaluations, cached): the gravity columns, the mass-matrix columns, and the radii aggregates per row entry
    (n rows, pi inertial columns) of the module docstring's local bounds. Step j spans ``[t_j, t_j+1]``; the
    sample-instant aggregates of sample j use steps j-1 and j. The log's secants: :class:`StepGrid`."""

    ETA = 1e-4  # rad: forward-difference step of the local q-derivatives (its truncation is bounded below)

    def __init__(self, robot, geo, q, e, dt, qdm, qddm, m):
        super().__init__(q, e, dt, qddm, m)
        self.robot, self.geo, self.qdm = robot, geo, qdm
        self.cache: dict = {}

    def evict(self, below: int) -> None:
        for j in [j for j in self.cache if j < below]:
            del self.cache[j]

    def get(self, j: int) -> dict:
        if j not in self.cache:
            self.cache[j] = self._compute(j)
        return self.cache[j]

    def _compute(self, j: int, with_prev: bool = True) -> dict:  # noqa: PLR0915 - one derivation, kept in one place
        n, geo = self.n, self.geo
        eta, dt = self.ETA, self.dt
        qh, vh = self.qbar[j], self.vh[j]
        Z = np.zeros(n)
        I = np.eye(n)

        def Y(qq, v, a):
            return regressor_one(self.robot, qq, v, a)

        g0 = Y(qh, Z, Z)
        f0 = Y(qh, vh, Z)
        ha = np.stack([Y(qh, I[a], Z) - g0 for a in range(n)])
        gam = np.zeros((n, n) + g0.shape)
        for a in range(n):
            gam[a, a] = ha[a]
            for b in range(a + 1, n):
                gam[a, b] = gam[b, a] = 0.5 * (Y(qh, I[a] + I[b], Z) - g0 - ha[a] - ha[b])
        Mc = np.stack([Y(qh, Z, I[b]) - g0 for b in range(n)])  # (b, i, c): column b of M per unit parameter
        Jq = np.empty((n,) + g0.shape)
        fk = np.empty((n,) + g0.shape)
        fab = np.empty((n, n) + g0.shape)  # corners of the q-Hessian's forward differences (q_remainder)
        gab, Mab = [], []  # and the mass matrix's there, pairs a <= b in order (mass_derivatives)
        for a in range(n):
            for b in range(a, n):
                qab = qh + (eta * I[a] + eta * I[b])
                fab[a, b] = fab[b, a] = Y(qab, vh, Z)
                if a:  # the mass pairs (serial_steps.mass_pairs): M does not depend on the first joint
                    gab.append(Y(qab, Z, Z))
                    Mab.append([Y(qab, Z, I[c]) for c in range(n)])
        gab, Mab = np.array(gab), np.array(Mab)
        Mk = np.empty((n, n) + g0.shape)
        gks = np.empty((n,) + g0.shape)
        dJv = np.empty((n, n) + g0.shape)  # (k, a, i, c): d/dq_k of dh/dv_a at (qh, vh)
        Jh = 2 * np.einsum("abic,b->aic", gam, vh)  # dh/dv, exact: h is quadratic in v
        mag = np.abs(f0) + np.abs(g0)
        for k in range(n):
            qk = qh + eta * I[k]
            gks[k] = Y(qk, Z, Z)
            fk[k] = Y(qk, vh, Z)
            Jq[k] = (fk[k] - f0) / eta
            for b in range(n):
                Mk[k, b] = Y(qk, Z, I[b])
                dJv[k, b] = (0.5 * (Y(qk, vh + I[b], Z) - Y(qk, vh - I[b], Z)) - Jh[b]) / eta
        flt = 4 * _PIN_REL / eta
        dM, eps, HB0 = (x[0] for x in mass_derivatives(Mc[None], Mk[None], gks[None], Mab[None], gab[None], qh[None],
                                                        geo))
        # the Lagrangian form: c2 = Mdot(qh, vh) vh (matrix Gc, the symmetric part of dM), f2 = g + h - c2
        Gc = 0.5 * (dM + np.swapaxes(dM, 0, 1))
        gam2 = gam - Gc
        Jv = 2 * np.einsum("abic,b->aic", gam2, vh)
        c2 = np.einsum("abic,a,b->ic", Gc, vh, vh)
        c2mag = np.einsum("abic,a,b->ic", np.abs(Gc), np.abs(vh), np.abs(vh))
        epsG = 0.5 * (eps + np.swapaxes(eps, 0, 1))
        # bounds on the true derivatives (forward-difference truncation by Bernstein, pinocchio's float error)
        vs = float(np.sum(np.abs(vh)))
        JqB = np.abs(Jq) + eta / 2 * 4 * (geo["gamma"] * vs**2 + geo["g"]) + flt * (mag + np.abs(Jq) * eta)
        dMB = np.abs(dM) + eps
        dJvB = np.abs(dJv) + 4 * eta * geo["gamma"] * (vs + 1) + flt * (2 * mag + np.abs(dJv) * eta)
        # speeds and position boxes of the step (true motion)
        ebar = self.ebar[j]
        e0, e1 = self.e[j], self.e[j + 1]
        ev_max = self.ev_mot_max + self.ev_pos[j]
        vmax = np.abs(vh) + ev_max
        qddm = self.qddm
        dq_mean, dq_max = (x[0] for x in step_displacements(self.dq[j][None], e0[None], e1[None], ebar[None], qddm,
                                                            dt))
        mbar = geo["M"]
        # -k' int_step M(q) qd against -k' M(qh) dq (the path against its mid-step value): first order with dM at
        # the true mid-chord (the chord's part integrates to 0), second order by Bernstein
        st = (np.abs(self.dq[j]) + e0 + e1) / dt * (1 + 4 * 2.0**-53)
        P1 = np.outer(st, qddm * (3 * dt**3 / 32)) + np.outer(qddm * (dt**3 / 12), st + qddm * (dt / 2))
        dqx = st * (dt / 2) + qddm * (dt * dt / 8)
        HB = mass_hessian_bound(HB0[None], dq_max[None], mbar)[0]
        L_mot = (np.einsum("kbic,kb->ic", dMB, P1) + 4 * mbar * float(ebar.sum()) * float(P1.sum())
                 + 0.5 * hessian_quadratic(HB[None], dqx[None], (st * dt + qddm * (dt * dt / 3))[None])[0])
        # f2(q(t), qd(t)) against f2(qh, vh): g + h to first order in q (local), the q-q remainder with the local
        # q-Hessian (q_remainder), the q-v one with local d/dq of dh/dv and Bernstein; c2's q-variation by Bernstein;
        # dM's forward-difference error in c2; the v-quadratic part exactly (matrix gam - Gc: Gq, Q_pos)
        absG2 = np.abs(gam2)
        mot = self.ev_mot_max
        Gq = np.einsum("abic,a,b->ic", absG2, qddm, qddm)  # the speed deviation's quadratic term, per kernel weight
        dvs, dqs = float(ev_max.sum()), float(dq_max.sum())
        c2p, c2m, c2k = (x[0] for x in c2_terms(HB[None], vmax[None], st[None], ebar[None], dq_max[None], qddm, mbar,
                                                  dt))
        L_mot = L_mot + c2k
        rem = (q_remainder(fab[None], fk[None], f0[None], qh[None], vh[None], ev_max[None], dq_max[None], geo)[0]
               + np.einsum("kaic,k,a->ic", dJvB, dq_max, ev_max) + 2 * geo["gamma"] * dvs * dvs * dqs + c2m)
        Cfd = np.einsum("abic,a,b->ic", epsG, vmax, vmax)
        H_mot = np.einsum("kic,k->ic", JqB, dq_mean) + rem + Cfd
        # the speed's linear term Jv (v - vh) integrated at the true step speeds (speed_linear): the centre term "Jc",
        # "Jk" times |k'|, the measurement error through the row's exact gradient (window loop, "Jv")
        Ya = np.stack([Y(qh, I[a], Z) for a in range(n)])
        gmag = np.abs(np.stack([[Y(qh, I[a] + I[b], Z) if a < b else (Y(qh, I[b] + I[a], Z) if b < a else 0 * g0)
                                 for b in range(n)] for a in range(n)]))
        gmag = gmag + np.abs(Ya)[:, None] + np.abs(Ya)[None, :] + 3 * np.abs(g0)
        lin = {k_: v_[0] for k_, v_ in speed_linear(Jv[None], (np.abs(gam) + np.abs(Gc))[None], gmag[None], vh[None],
                                                      self.dq[j][None], e0[None], e1[None], qddm, dt).items()}
        lin["Jf"] = lin["Jf"] + 4 * (n + 2) * 2.0**-53 * c2mag
        pos = self.ev_pos[j]  # Q_all - Q_mm as a sum of non-negative products (no cancellation)
        Q_pos = (np.einsum("abic,a,b->ic", absG2, mot, pos) + np.einsum("abic,a,b->ic", absG2, pos, mot)
                 + np.einsum("abic,a,b->ic", absG2, pos, pos))
        H_pos = np.einsum("kic,k->ic", JqB, ebar) + Q_pos + c2p
        # |M(true mid) - M(qh)| per column b
        dlt = np.einsum("kbic,k->bic", dMB, ebar) + 2 * mbar * float(ebar.sum()) ** 2
        out = {"g0": g0, "Mc": Mc, "c2": c2, "c2mag": c2mag, "L_mot": L_mot, "H_mot": H_mot, "Gq": Gq,
               "H_pos": H_pos, "Dloc": np.einsum("bic,b->ic", dlt, np.abs(self.dq[j]) + e0 + e1),
               "Ecur": np.einsum("bic,b->ic", np.abs(Mc), e0), "mag": np.abs(g0), "Jv": Jv, **lin}
        # sample j (between steps j-1 and j)
        prev = self.cache.get(j - 1)
        if prev is None and with_prev and j - 1 >= self.m - 1:
            prev = self._compute(j - 1, with_prev=False)
        if prev is not None:
            out["Eknot"] = np.einsum("bic,b->ic", np.abs(prev["Mc"]), self.e[j])
            out["Ediff"] = np.einsum("bic,b->ic", np.abs(prev["Mc"] - Mc), self.e[j])
        return out


def inertial_rows_reference(robot, geo, q, e, spec, m, kern, starts, progress=None):
    """The inertial columns' window sums, window by window (arguments and returns as
    :func:`ident.robots.serial_steps.inertial_rows`; ``recon`` is 0: the regressor is evaluated at the window's
    arguments, not rebuilt)."""
    nj = robot.n_joints
    N = q.shape[0]
    dt = spec.sample_period
    st_ = _Steps(robot, geo, q, e, dt, spec.qd_max, spec.qdd_max, m)
    k, K1 = kern.knots, kern.integrals
    L = k.size - 1
    kp = np.diff(k) / dt
    cq = quadratic_speed_weights(kern, m)
    dkp = np.abs(np.diff(np.concatenate([[0.0], kp, [0.0]])))
    R_ = len(starts)
    ni = 10 * nj
    Wi = np.zeros((R_, nj, ni))
    mag = np.zeros((R_, nj, ni))
    recon = np.zeros((R_, nj, ni))  # the speed_linear centre term's own error bound (the regressor evaluated)
    parts_i = {name: np.zeros((R_, nj, ni)) for name in PARTS}
    vh, dq = st_.vh, st_.dq
    for r, s in enumerate(starts):
        st = slice(s, s + L)  # steps of the window
        st_.evict(s - 1)
        u = -kp[:, None] * dq[st]  # (L, n): the mass term of the Lagrangian form, -k'_w M_w dq_w
        vs = np.sqrt(K1)[:, None] * vh[st]
        acc = np.zeros((nj, ni))
        ab = np.zeros((nj, ni))
        jf = np.zeros((nj, ni))
        part = {name: np.zeros((nj, ni)) for name in PARTS}
        for jj in range(L):
            j = s + jj
            d = st_.get(j)
            Yj = regressor_one(robot, st_.qbar[j], vs[jj], u[jj])
            acc += Yj + (K1[jj] - 1.0) * d["g0"] + K1[jj] * (d["Jc"] - d["c2"])
            ab += np.abs(Yj) + abs(K1[jj] - 1.0) * d["mag"] + K1[jj] * (d["aJc"] + d["c2mag"])
            jf += K1[jj] * d["Jf"]
            part["mass_motion"] += abs(kp[jj]) * d["L_mot"]
            part["coriolis_motion"] += K1[jj] * d["H_mot"] + abs(kp[jj]) * d["Jk"] + cq[jj] * d["Gq"]
            part["mass_position"] += abs(kp[jj]) * d["Dloc"]
            part["coriolis_position"] += K1[jj] * d["H_pos"]
            # measurement through the exact gradient of sum_j k'_j M_j dq_j (sample jj of the window)
            part["gradient_position"] += (dkp[jj] * (d["Ecur"] if jj == 0 else d["Eknot"])
                                          + (abs(kp[jj]) * d["Ediff"] if jj else 0.0))
        # the speed's linear term at the true step speeds: sum_j K1_j Jv_j (delta_{j+1} - delta_j) / dt, by parts
        Wt = K1[:, None, None, None] * np.stack([st_.get(s + jj)["Jv"] for jj in range(L)])  # (L, a, i, c)
        G = np.zeros((L + 1,) + Wt.shape[1:])
        G[1:] += Wt  # sample offset jj + 1
        G[:L] -= Wt  # sample offset jj
        part["coriolis_position"] += np.einsum("oaic,oa->ic", np.abs(G), e[s: s + L + 1]) / dt
        d_end = st_.get(s + L)  # sample s + L: the last boundary term |k'_{L-1}| |M_{L-1}| e_L
        part["gradient_position"] += dkp[L] * d_end["Eknot"]
        Wi[r], mag[r], recon[r] = acc, ab, np.nextafter(jf * (1 + 2 * (L + 2) * 2.0**-53), np.inf)
        for name in PARTS:
            parts_i[name][r] = part[name]
        if progress is not None:
            progress(r + 1, R_)
    st_.evict(N)

    return Wi, mag, recon, parts_i
