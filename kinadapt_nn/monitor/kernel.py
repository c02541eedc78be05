"""The monitor's per-sample kernel: the nominal model's prediction, the noise floor and the CUSUM test.

One call per sample (``sample``), numba-compiled, no allocation: the sensor-frame kinematics from
the sample's pose and twist (world), the declared tool's Newton-Euler wrench (the model of
``kinadapt_nn.diagnostics.physical``: ``F = m (g_s - a_s) - alpha x mc - omega x (omega x mc)``,
``M = mc x (g_s - a_s) - I_O alpha - omega x (I_O omega)``), the corrections of the events found
so far (:data:`CORR`), the residual, and per channel a two-sided CUSUM on ``residual / sd``.

A sample's reading belongs to its own pose and twist (one instant's encoders and reading, as a real
robot samples them and as the simulator hands them out, ``sim.ft_sensor``), and to the acceleration
from it to the next sample: each sample is judged when the next one arrives, with its own pose,
twist and reading and the forward difference of the twist (the residual's time is that sample's,
one control period behind the latest).

Layouts (float64 vectors, indices below): ``c`` the constants (:func:`consts`), ``st`` the state,
``ring`` (RING, NCOL + 3 nj) the last samples for the event fit (``monitor.shapes``; nj arm joints' axes).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

# -- constants c ---------------------------------------------------------------------------------
C_DT, C_M, C_MC, C_IO, C_GW, C_PFS, C_RFS, C_SIGN = 0, 1, 2, 5, 14, 17, 20, 29
C_K, C_H, C_CALIB, C_ZONE, C_ENTRY, C_UP, C_ZONE_M, C_TIP, C_DETECT, C_FLOOR_N, C_FLOOR_M, C_WINDOW = (
    30, 31, 32, 33, 34, 37, 40, 41, 44, 45, 46, 47)
C_HROT = 48
#: [s] from this time on every sample is contact, at any depth (a fixture that holds the tip from a known time:
#: a socket engaged at the drive start, ``scene.socket_engage = "drive"``); inf: none
C_ENGAGE = 49
NC = 50
#: contact handling (c[C_ZONE]): 0 none declared (every sample judged); 1 a declared fixture: the nominal
#: tip within zone_m of its entrance plane or past it is contact; 2 contact by force: the force
#: beyond the model by more than detect_force_N
ZONE_NONE, ZONE_GEOMETRY, ZONE_FORCE = 0, 1, 2

# -- corrections of the events found (st[S_CORR:]) ----------------------------------------------
#: dm, dmc(3): an added tool (payload); fw(3), P(9) = p fw^T: a world force at p (s); rate(6), t0:
#: a drift from t0; const(6): a step; rot(3): the sensor frame turned (small angle)
K_DM, K_DMC, K_FW, K_P, K_RATE, K_T0, K_CONST, K_ROT = 0, 1, 4, 7, 16, 22, 23, 29
NCORR = 32

# -- state st ------------------------------------------------------------------------------------
S_N, S_HAVE, S_VPREV, S_WPREV, S_RPREV, S_PPREV = 0, 1, 2, 5, 8, 17
S_CN, S_CSUM, S_CSQ, S_OFF, S_SD = 20, 21, 27, 33, 39
S_GP, S_GM, S_TP, S_TM, S_MODE, S_TALARM, S_HEAD, S_COUNT, S_NBAD, S_FREE_N = (
    45, 51, 57, 63, 69, 70, 71, 72, 73, 74)
S_E, S_Z, S_ZONE, S_TLAST = 75, 81, 87, 88
S_CORR = 90
# -- the rotation test (``_rotation_test``): the open block's sums, the last ROT_NB blocks' -------------
#: H (9) = sum A^T A, g (3) = sum A^T z, S (9) = sum A, samples in the open block, its first time; the
#: blocks' ring (ROT_NB x ROT_W), its head and count; a fired flag and the onset it found
S_RH = S_CORR + NCORR
S_RG, S_RS, S_RN, S_RT0, S_RHEAD, S_RCOUNT, S_RFIRED, S_RTON = (S_RH + 9, S_RH + 12, S_RH + 21, S_RH + 22, S_RH + 23,
                                                                S_RH + 24, S_RH + 25, S_RH + 26)
S_RBLK = S_RH + 27
#: samples per block and blocks (the longest window the test looks back over: ROT_BLK x ROT_NB samples);
#: a block's row: H (9), g (3), S (9) = sum A, its first time
ROT_BLK, ROT_NB, ROT_W = 50, 20, 22
#: the previous sample's raw reading (6): judged when the next sample arrives
S_RAWPREV = S_RBLK + ROT_NB * ROT_W
NS = S_RAWPREV + 6
#: after NS: the previous sample's joint axes in s (3 per joint, ``new_state(nj)``), pushed with it to the ring
S_AX = NS
#: monitor modes (st[S_MODE])
MODE_CALIB, MODE_WATCH, MODE_WINDOW = 0.0, 1.0, 2.0
#: what a call reports
R_NONE, R_ALARM, R_WINDOW, R_SKIP = 0, 1, 2, 3

# -- ring rows: what the event fit needs of each sample --------------------------------------------
#: time, residual (6), R_ws (9), omega, alpha, g - a (3 each, s), the reading (6, s), free (1 / 0); then from
#: G_AX the arm's joint axes in s, ``R_ws^T z_j`` (3 per joint; ``new_state(nj)``: NCOL + 3 nj columns in all)
G_T, G_E, G_R, G_OM, G_AL, G_GA, G_RM, G_FREE, G_AX = 0, 1, 7, 16, 19, 22, 25, 31, 32
NCOL = 32
RING = 8192


def threshold(false_alarms_per_h: float, k: float, dt_s: float, sides: int = 12) -> float:
    """The CUSUM threshold h [sd] for ``false_alarms_per_h`` alarms an hour over ``sides`` one-sided
    tests (6 channels, both signs) on white Gaussian noise at the floor, sampled every ``dt_s``:
    Siegmund's approximation of a one-sided CUSUM's average run length under no change,
    ``ARL0 = (exp(2 k b) - 2 k b - 1) / (2 k^2)``, ``b = h + 1.166``, set to ``sides x samples an
    hour / rate`` (each test's share) and solved for h by bisection."""
    arl = sides * (3600.0 / dt_s) / false_alarms_per_h

    def arl0(h: float) -> float:
        b = 2.0 * k * (h + 1.166)
        return (math.exp(min(b, 700.0)) - b - 1.0) / (2.0 * k * k)

    lo, hi = 0.0, 1.0
    while arl0(hi) < arl:
        hi *= 2.0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if arl0(mid) < arl else (lo, mid)
    return hi


def rotation_threshold(false_alarms_per_h: float, dt_s: float) -> float:
    """The rotation test's threshold [nats] for ``false_alarms_per_h`` on white Gaussian noise: the test
    (``_rotation_test``) evaluates, at the end of each block of ``ROT_BLK`` samples, ``ROT_NB`` windows
    (the last 1..ROT_NB blocks); on noise each window's statistic is chi^2 with 3 degrees of freedom / 2.
    Bonferroni over the windows of an hour: P(chi^2_3 > 2 h) = rate / (windows an hour)."""
    from scipy.stats import chi2

    windows = (3600.0 / (dt_s * ROT_BLK)) * ROT_NB
    return 0.5 * float(chi2.isf(false_alarms_per_h / windows, 3))


@nb.njit(cache=True)
def _rotation_glr(t, st, head):
    """The rotation test's statistic over the windows of the last 1..ROT_NB blocks (``_rotation_test``)
    -> (its largest value [nats], that window's first time)."""
    H = np.zeros(9)
    g = np.zeros(3)
    S = np.zeros(9)
    V = np.zeros(9)
    best = 0.0
    t_on = t
    inv_ncal = 1.0 / max(st[S_CN], 1.0)
    for w in range(int(st[S_RCOUNT])):
        b = S_RBLK + ((head - w) % ROT_NB) * ROT_W
        for i in range(9):
            H[i] += st[b + i]
            S[i] += st[b + 12 + i]
        for i in range(3):
            g[i] += st[b + 9 + i]
        for j in range(3):  # V = H + S^T S / n_cal
            for l_ in range(3):
                acc = 0.0
                for i in range(3):
                    acc += S[3 * i + j] * S[3 * i + l_]
                V[3 * j + l_] = H[3 * j + l_] + acc * inv_ncal
        # g^T V^-1 g by the adjugate (V symmetric positive semi-definite; a tiny ridge)
        h00, h01, h02 = V[0] + 1e-9, V[1], V[2]
        h11, h12, h22 = V[4] + 1e-9, V[5], V[8] + 1e-9
        c00 = h11 * h22 - h12 * h12
        c01 = h02 * h12 - h01 * h22
        c02 = h01 * h12 - h02 * h11
        c11 = h00 * h22 - h02 * h02
        c12 = h01 * h02 - h00 * h12
        c22 = h00 * h11 - h01 * h01
        det = h00 * c00 + h01 * c01 + h02 * c02
        if det <= 0.0:
            continue
        q = (g[0] * (c00 * g[0] + c01 * g[1] + c02 * g[2]) + g[1] * (c01 * g[0] + c11 * g[1] + c12 * g[2])
             + g[2] * (c02 * g[0] + c12 * g[1] + c22 * g[2])) / det
        if 0.5 * q > best:
            best, t_on = 0.5 * q, st[b + 21]
    return best, t_on


@nb.njit(cache=True)
def _rotation_test(t, c, st, F, z) -> bool:
    """The sensor frame's rotation, a test of its own: a turned mount reads ``r + r x delta`` (r the
    wrench, delta the small rotation vector), so the residual of the force channels is ``[F]x delta``,
    a regressor that turns with the pose. Per sample, A = [F]x / sd_F (3, 3) and the force residual in
    sd z (3,) add to the open block's sums H = sum A^T A, g = sum A^T z, S = sum A; at the block's end
    the GLR of delta over the last 1..ROT_NB blocks, ``max_w g_w^T V_w^-1 g_w / 2``, is compared with
    ``c[C_HROT]``. V = H + S^T S / n_cal is g's covariance with no change: the noise's (H) and that of
    the offset measured at the start over n_cal samples (its error, sd / sqrt(n_cal) per channel, is a
    constant that a hanging tool's rotation looks exactly like). Only the force rows: the moment rows
    carry the declared tool's centre-of-mass error (docs/monitor.md). -> whether it fired (st[S_RTON]:
    the best window's first time)."""
    if st[S_RN] == 0.0:
        st[S_RT0] = t
    a = np.zeros((3, 3))  # [F]x, rows / sd
    a[0, 1], a[0, 2] = -F[2] / st[S_SD], F[1] / st[S_SD]
    a[1, 0], a[1, 2] = F[2] / st[S_SD + 1], -F[0] / st[S_SD + 1]
    a[2, 0], a[2, 1] = -F[1] / st[S_SD + 2], F[0] / st[S_SD + 2]
    for j in range(3):
        acc = 0.0
        for i in range(3):
            acc += a[i, j] * z[i]
            st[S_RS + 3 * i + j] += a[i, j]
        st[S_RG + j] += acc
        for l_ in range(3):
            acc = 0.0
            for i in range(3):
                acc += a[i, j] * a[i, l_]
            st[S_RH + 3 * j + l_] += acc
    st[S_RN] += 1.0
    if st[S_RN] < ROT_BLK:
        return False
    head = int(st[S_RHEAD])
    b = S_RBLK + head * ROT_W
    for i in range(21):
        st[b + i] = st[S_RH + i]
        st[S_RH + i] = 0.0
    st[b + 21] = st[S_RT0]
    st[S_RN] = 0.0
    st[S_RHEAD] = (head + 1) % ROT_NB
    st[S_RCOUNT] = min(st[S_RCOUNT] + 1.0, ROT_NB)
    best, t_on = _rotation_glr(t, st, head)
    if best > c[C_HROT]:
        st[S_RTON] = t_on
        return True
    return False


def rotation_reset(st: np.ndarray) -> None:
    """The rotation test starts afresh (after an event or a dismissed alarm)."""
    st[S_RH:S_RBLK + ROT_NB * ROT_W] = 0.0


@nb.njit(cache=True, inline="always")
def _cross(a0, a1, a2, b0, b1, b2, out, o):
    out[o] = a1 * b2 - a2 * b1
    out[o + 1] = a2 * b0 - a0 * b2
    out[o + 2] = a0 * b1 - a1 * b0


@nb.njit(cache=True)
def predict(c, st, t, R, om, al, ga, out):
    """The model's reading (6,) in s, tool on sensor [N, N m], into ``out``: the declared tool plus the
    corrections, at sensor axes ``R`` (3, 3) (s in world), omega, alpha, g - a (3,) each in s."""
    k = S_CORR
    m = c[C_M] + st[k + K_DM]
    mc0 = c[C_MC] + st[k + K_DMC]
    mc1 = c[C_MC + 1] + st[k + K_DMC + 1]
    mc2 = c[C_MC + 2] + st[k + K_DMC + 2]
    tmp = np.empty(6)
    # F = m ga - al x mc - om x (om x mc)
    _cross(al[0], al[1], al[2], mc0, mc1, mc2, tmp, 0)
    _cross(om[0], om[1], om[2], mc0, mc1, mc2, tmp, 3)
    w0, w1, w2 = tmp[3], tmp[4], tmp[5]
    _cross(om[0], om[1], om[2], w0, w1, w2, tmp, 3)
    for i in range(3):
        out[i] = m * ga[i] - tmp[i] - tmp[3 + i]
    # M = mc x ga - I_O al - om x (I_O om)   (the declared inertia)
    _cross(mc0, mc1, mc2, ga[0], ga[1], ga[2], tmp, 0)
    io = C_IO
    iw0 = c[io] * om[0] + c[io + 1] * om[1] + c[io + 2] * om[2]
    iw1 = c[io + 3] * om[0] + c[io + 4] * om[1] + c[io + 5] * om[2]
    iw2 = c[io + 6] * om[0] + c[io + 7] * om[1] + c[io + 8] * om[2]
    _cross(om[0], om[1], om[2], iw0, iw1, iw2, tmp, 3)
    for i in range(3):
        ia = c[io + 3 * i] * al[0] + c[io + 3 * i + 1] * al[1] + c[io + 3 * i + 2] * al[2]
        out[3 + i] = tmp[i] - ia - tmp[3 + i]
    # a world force fw at p: F += R^T fw, M += sum_il P_il e_i x (R^T e_l)
    for i in range(3):
        acc = 0.0
        for l_ in range(3):
            acc += R[l_, i] * st[k + K_FW + l_]
        out[i] += acc
    for i in range(3):
        for l_ in range(3):
            p = st[k + K_P + 3 * i + l_]
            if p != 0.0:
                u0, u1, u2 = R[l_, 0], R[l_, 1], R[l_, 2]  # world axis l in s
                if i == 0:
                    out[4] += -p * u2
                    out[5] += p * u1
                elif i == 1:
                    out[3] += p * u2
                    out[5] += -p * u0
                else:
                    out[3] += -p * u1
                    out[4] += p * u0
    # a step and a drift
    t0 = st[k + K_T0]
    for i in range(6):
        out[i] += st[k + K_CONST + i]
        if t > t0:
            out[i] += st[k + K_RATE + i] * (t - t0)
    # the sensor frame turned by rot: reading + reading x rot
    r0, r1, r2 = st[k + K_ROT], st[k + K_ROT + 1], st[k + K_ROT + 2]
    if r0 != 0.0 or r1 != 0.0 or r2 != 0.0:
        for b in (0, 3):
            x0, x1, x2 = out[b], out[b + 1], out[b + 2]
            out[b] += x1 * r2 - x2 * r1
            out[b + 1] += x2 * r0 - x0 * r2
            out[b + 2] += x0 * r1 - x1 * r0


@nb.njit(cache=True)
def _finite(kin, raw) -> bool:
    for i in range(6):
        if not math.isfinite(raw[i]):
            return False
    for i in range(3, 6):
        for j in range(3):
            if not math.isfinite(kin[i, j]):
                return False
    return True


@nb.njit(cache=True)
def _keep(t, kin, raw, st) -> None:
    """This sample's pose, twist and reading, the next one's previous; its joint axes (``kin`` rows 6..: z_j in
    the world) into s, ``a_j = R_ws^T z_j`` (as many as ``st`` keeps: ``new_state(nj)``)."""
    for i in range(6):
        st[S_RAWPREV + i] = raw[i]
    for i in range(3):
        st[S_VPREV + i] = kin[4, i]
        st[S_WPREV + i] = kin[5, i]
        st[S_PPREV + i] = kin[3, i]
        for j in range(3):
            st[S_RPREV + 3 * i + j] = kin[i, j]
    for j in range(min(kin.shape[0] - 6, (st.shape[0] - S_AX) // 3)):
        for i in range(3):
            st[S_AX + 3 * j + i] = kin[0, i] * kin[6 + j, 0] + kin[1, i] * kin[6 + j, 1] + kin[2, i] * kin[6 + j, 2]
    st[S_TLAST] = t


@nb.njit(cache=True)
def _sensor_kinematics(kin, dt, c, st, R, om, al, ga) -> None:
    """The previous sample's sensor axes R (3, 3) and omega (3,) in s, alpha and g - a (3,) in s from the
    finite difference of the twist (``kin`` rows 4, 5: v_w, w_w) over dt."""
    for i in range(3):
        for j in range(3):
            R[i, j] = st[S_RPREV + 3 * i + j]
    for i in range(3):  # into s: x_s = R^T x_w
        o = 0.0
        a = 0.0
        g = 0.0
        aa = 0.0
        for l_ in range(3):
            o += R[l_, i] * st[S_WPREV + l_]
            a += R[l_, i] * (kin[5, l_] - st[S_WPREV + l_]) / dt
            g += R[l_, i] * c[C_GW + l_]
            aa += R[l_, i] * (kin[4, l_] - st[S_VPREV + l_]) / dt
        om[i], al[i], ga[i] = o, a, g - aa


@nb.njit(cache=True)
def _in_contact(t, c, st, R, e) -> bool:
    """The phase of the sample at ``t`` [s]: contact is not judged (its force is unknown)."""
    if t >= c[C_ENGAGE]:  # a fixture holding the tip from a known time (``C_ENGAGE``)
        return True
    zmode = int(c[C_ZONE])
    if zmode == ZONE_GEOMETRY:
        h_tip = 0.0
        for i in range(3):
            tip_w = st[S_PPREV + i] + R[i, 0] * c[C_TIP] + R[i, 1] * c[C_TIP + 1] + R[i, 2] * c[C_TIP + 2]
            h_tip += (tip_w - c[C_ENTRY + i]) * c[C_UP + i]
        return h_tip < c[C_ZONE_M]
    if zmode == ZONE_FORCE and st[S_MODE] != MODE_CALIB:
        f2 = 0.0
        for i in range(3):
            f2 += (e[i] - st[S_OFF + i]) ** 2
        return f2 > c[C_DETECT] ** 2
    return False


@nb.njit(cache=True)
def _calibrate(c, st, e, zone) -> None:
    """At the start: the sensor's offset and noise sd per channel (floored) over ``calib_s`` of free samples."""
    if not zone:
        st[S_CN] += 1.0
        for i in range(6):
            st[S_CSUM + i] += e[i]
            st[S_CSQ + i] += e[i] * e[i]
    if st[S_CN] * c[C_DT] >= c[C_CALIB]:
        n = st[S_CN]
        for i in range(6):
            mu = st[S_CSUM + i] / n
            var = max(st[S_CSQ + i] / n - mu * mu, 0.0) * n / max(n - 1.0, 1.0)
            st[S_OFF + i] = mu
            fl = c[C_FLOOR_N] if i < 3 else c[C_FLOOR_M]
            st[S_SD + i] = max(math.sqrt(var), fl)
        st[S_MODE] = MODE_WATCH


@nb.njit(cache=True)
def _push(t, st, ring, e, raw, sgn, R, om, al, ga, zone, ax) -> None:  # noqa: PLR0913 (a numba kernel: flat arrays)
    """The sample into the ring (what an event's fit needs); ``ax`` its joint axes in s (3 nj)."""
    row = int(st[S_HEAD])
    for i in range(min(len(ax), ring.shape[1] - G_AX)):
        ring[row, G_AX + i] = ax[i]
    ring[row, G_T] = t
    for i in range(6):
        ring[row, G_E + i] = e[i]
        ring[row, G_RM + i] = sgn * raw[i] - st[S_OFF + i]
    for i in range(3):
        for j in range(3):
            ring[row, G_R + 3 * i + j] = R[i, j]
        ring[row, G_OM + i] = om[i]
        ring[row, G_AL + i] = al[i]
        ring[row, G_GA + i] = ga[i]
    ring[row, G_FREE] = 0.0 if zone else 1.0
    st[S_HEAD] = (row + 1) % ring.shape[0]
    st[S_COUNT] = min(st[S_COUNT] + 1.0, ring.shape[0])


@nb.njit(cache=True)
def _cusum(t, c, st) -> bool:
    """One step of the two-sided CUSUM per channel on z = residual / sd (st[S_Z:]); the restart times
    kept (the change's onset). -> whether a test crossed the threshold."""
    k, h = c[C_K], c[C_H]
    fired = False
    for i in range(6):
        z = st[S_Z + i]
        gp = st[S_GP + i] + z - k
        gm = st[S_GM + i] - z - k
        if gp <= 0.0:
            gp = 0.0
            st[S_TP + i] = t
        if gm <= 0.0:
            gm = 0.0
            st[S_TM + i] = t
        st[S_GP + i] = gp
        st[S_GM + i] = gm
        if gp > h or gm > h:
            fired = True
    return fired


@nb.njit(cache=True)
def sample(t, kin, raw, c, st, ring):
    """One sample at time ``t`` [s]: ``kin`` (6 + nj, 3) = [R_ws (3 rows): the sensor axes in the world; p_ws:
    its origin; v_w: its velocity; w_w: its angular velocity; the arm's joint axes z_j (nj rows, base to
    flange; a slide joint's: zero)] (world), the raw reading ``raw`` (6,) as
    logged (``c[C_SIGN]`` turns it into the tool's wrench on the sensor). -> R_NONE, R_ALARM (the test
    fired), R_WINDOW (an alarm's fit window is complete), R_SKIP (a non-finite sample: left out)."""
    if not _finite(kin, raw):
        st[S_NBAD] += 1.0
        return R_SKIP
    dt = c[C_DT]
    have = st[S_HAVE] > 0.0
    if have:
        h = t - st[S_TLAST]
        if h <= 0.0 or h > 1.5 * dt:  # time went back or samples are missing: the previous sample's
            have = False  # acceleration (to the next one) is unknown; the kinematics starts afresh
        else:
            dt = h
    if not have:  # the first sample (or after a gap): its kinematics is the next one's previous
        _keep(t, kin, raw, st)
        st[S_HAVE] = 1.0
        return R_NONE
    R = np.empty((3, 3))
    om = np.empty(3)
    al = np.empty(3)
    ga = np.empty(3)
    _sensor_kinematics(kin, dt, c, st, R, om, al, ga)
    t_now = t
    t = st[S_TLAST]  # the judged sample: the previous one (module docstring)
    prev = st[S_RAWPREV:S_RAWPREV + 6].copy()
    ax = st[S_AX:].copy()  # the judged sample's joint axes in s (``_keep`` overwrites them with this one's)
    pred = np.empty(6)
    predict(c, st, t, R, om, al, ga, pred)
    sgn = c[C_SIGN]
    e = st[S_E:S_E + 6]
    for i in range(6):
        e[i] = sgn * prev[i] - pred[i]
    zone = _in_contact(t, c, st, R, e)
    st[S_ZONE] = 1.0 if zone else 0.0
    _keep(t_now, kin, raw, st)
    raw = prev
    st[S_N] += 1.0
    mode = st[S_MODE]
    if mode == MODE_CALIB:
        _calibrate(c, st, e, zone)
        return R_NONE
    for i in range(6):
        e[i] -= st[S_OFF + i]
        st[S_Z + i] = e[i] / st[S_SD + i]
    _push(t, st, ring, e, raw, sgn, R, om, al, ga, zone, ax)
    if zone:
        return R_NONE
    if mode == MODE_WINDOW:
        st[S_FREE_N] += 1.0
        return R_WINDOW if t >= st[S_TALARM] + c[C_WINDOW] else R_NONE
    fired = _cusum(t, c, st)
    if c[C_HROT] > 0.0:
        F = np.empty(3)
        for i in range(3):
            F[i] = sgn * raw[i] - st[S_OFF + i]
        if _rotation_test(t, c, st, F, st[S_Z:S_Z + 3]):
            st[S_RFIRED] = 1.0
            fired = True
    if fired:
        st[S_MODE] = MODE_WINDOW
        st[S_TALARM] = t
        st[S_FREE_N] = 0.0
        return R_ALARM
    return R_NONE


@nb.njit(cache=True)
def loop_sample(t, inp, R_wf, p_O, J, c, st, ring):
    """``sample`` on the controller's own quantities of one control period: its input row ``inp``
    (2n+6,) = [q; qdot; raw F/T in f], the flange pose (``R_wf`` (3, 3), ``p_O`` (3,)) and Jacobian
    ``J`` (6, n) the controller computed from those encoders; the sensor is at O with the flange's
    axes (a package run: ``diagnostics.ownrun``); the joint axes are ``J``'s angular rows."""
    n = J.shape[1]
    nj = min(n, (st.shape[0] - S_AX) // 3)
    kin = np.zeros((6 + nj, 3))
    for i in range(3):
        kin[3, i] = p_O[i]
        for j in range(3):
            kin[i, j] = R_wf[i, j]
        for j in range(n):
            kin[4, i] += J[i, j] * inp[n + j]
            kin[5, i] += J[3 + i, j] * inp[n + j]
        for j in range(nj):
            kin[6 + j, i] = J[3 + i, j]
    return sample(t, kin, inp[2 * n:2 * n + 6], c, st, ring)


def new_state(nj: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(st (NS + 3 nj,), ring (RING, NCOL + 3 nj)): a monitor's state before its first sample, keeping the
    axes of ``nj`` arm joints (0: none; the ``encoder_offset`` shape then has no column)."""
    st = np.zeros(NS + 3 * nj)
    st[S_MODE] = MODE_CALIB
    st[S_CORR + K_T0] = np.inf
    return st, np.zeros((RING, NCOL + 3 * nj))


def ring_rows(st: np.ndarray, ring: np.ndarray, t_from: float) -> np.ndarray:
    """The ring's rows (in time order) from ``t_from`` [s] on -> (k, NCOL) (a copy)."""
    n, head = int(st[S_COUNT]), int(st[S_HEAD])
    idx = (head - n + np.arange(n)) % ring.shape[0]
    rows = ring[idx]
    return rows[rows[:, G_T] >= t_from]
