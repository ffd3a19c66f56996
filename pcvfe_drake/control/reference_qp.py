"""A dense, term-by-term build of the NMPC's QP: the reference of the sparse assembly.

Serves tests (the sparse ``NmpcController.qp_matrices`` must equal it) and the naive baseline
of ``benchmarks/nmpc_step.py``; the controller never uses it.
"""

from __future__ import annotations

import numpy as np

from pcvfe_drake.control.nmpc import Linearization, NmpcController
from pcvfe_drake.vehicle.single_track import BETA, DELTA, NU, NX, PSI, PSI_DOT, SX, SY, V


def dense_qp(ctrl: NmpcController, lin: Linearization):
    """Straightforward dense build of the same QP (full symmetric P), term by term in loops.

    The reference for tests and the naive baseline of ``benchmarks/nmpc_step.py``.
    """
    lay, n = ctrl.layout, ctrl.N
    cfg, p = ctrl.config, ctrl.params
    nz, m = lay.nz, lay.m
    P = np.zeros((nz, nz))
    q = np.zeros(nz)
    A = np.zeros((m, nz))
    lo = np.zeros(m)
    hi = np.zeros(m)

    def add_square(weight, coeffs: dict, offset: float):
        # weight * (sum_i c_i z_i + offset)^2 -> 1/2 z' P z + q' z
        idx = np.array(list(coeffs.keys()))
        c = np.array(list(coeffs.values()))
        P[np.ix_(idx, idx)] += 2 * weight * np.outer(c, c)
        q[idx] += 2 * weight * offset * c

    for k in range(1, n + 1):
        j = k - 1
        xb = lin.x_bar[k]
        nrm = lin.normal[j]
        add_square(ctrl.w_lat[j], {lay.ix(k, SX): nrm[0], lay.ix(k, SY): nrm[1]}, lin.e_lat[j])
        add_square(ctrl.w_course[j], {lay.ix(k, PSI): 1.0, lay.ix(k, BETA): 1.0}, lin.e_course[j])
        add_square(ctrl.w_speed[j], {lay.ix(k, V): 1.0}, xb[V] - lin.v_ref[j])
        add_square(ctrl.w_yaw[j], {lay.ix(k, PSI_DOT): 1.0}, xb[PSI_DOT] - lin.yaw_ref[j])
    for k in range(n):
        for i in range(NU):
            add_square(ctrl.w_u[i], {lay.iu(k, i): 1.0}, lin.u_bar[k, i])
            if k == 0:
                add_square(ctrl.w_du[i], {lay.iu(0, i): 1.0}, lin.u_bar[0, i] - lin.u_prev[i])
            else:
                add_square(
                    ctrl.w_du[i],
                    {lay.iu(k, i): 1.0, lay.iu(k - 1, i): -1.0},
                    lin.u_bar[k, i] - lin.u_bar[k - 1, i],
                )
    for v in range(lay.off_sf, nz):
        P[v, v] += 2 * cfg.slack_quadratic
        q[v] += cfg.slack_linear

    row = 0
    for i in range(NX):
        A[row, lay.ix(0, i)] = 1.0
        row += 1
    for k in range(n):
        for i in range(NX):
            for jj in range(NX):
                A[row, lay.ix(k, jj)] = lin.Ad[k, i, jj]
            for jj in range(NU):
                A[row, lay.iu(k, jj)] = lin.Bd[k, i, jj]
            A[row, lay.ix(k + 1, i)] = -1.0
            lo[row] = hi[row] = -lin.defect[k, i]
            row += 1
    for k in range(n):
        for i in range(NU):
            A[row, lay.iu(k, i)] = 1.0
            lo[row] = lin.u_lo[k, i] - lin.u_bar[k, i]
            hi[row] = lin.u_hi[k, i] - lin.u_bar[k, i]
            row += 1
    for k in range(1, n + 1):
        A[row, lay.ix(k, DELTA)] = 1.0
        lo[row] = p.delta_min - lin.x_bar[k, DELTA]
        hi[row] = p.delta_max - lin.x_bar[k, DELTA]
        row += 1
    for k in range(n):
        vb, rb, ab = lin.x_bar[k, V], lin.x_bar[k, PSI_DOT], lin.u_bar[k, 1]
        for c, s in zip(lay.fr_cos, lay.fr_sin, strict=True):
            A[row, lay.iu(k, 1)] = c
            A[row, lay.ix(k, V)] = s * rb
            A[row, lay.ix(k, PSI_DOT)] = s * vb
            A[row, lay.off_sf + k] = -1.0
            lo[row] = -np.inf
            hi[row] = lin.friction_radius - (c * ab + s * vb * rb)
            row += 1
    for k in range(1, n + 1):
        nrm = lin.normal[k - 1]
        for sign in (-1.0, 1.0):
            A[row, lay.ix(k, SX)] = nrm[0]
            A[row, lay.ix(k, SY)] = nrm[1]
            A[row, lay.off_sl + k - 1] = sign
            if sign < 0:
                lo[row], hi[row] = -np.inf, lin.corridor - lin.e_lat[k - 1]
            else:
                lo[row], hi[row] = -lin.corridor - lin.e_lat[k - 1], np.inf
            row += 1
    for v in range(lay.off_sf, nz):
        A[row, v] = 1.0
        lo[row], hi[row] = 0.0, np.inf
        row += 1
    return P, q, A, lo, hi
