"""The EKF's update (eqs. 31-34, with the chi-square gate and the asynchronous readings) on
batch-last entries, for a state of any size: the paper's five entries
(:mod:`dockingrl.transforms.ekf`) and the seven of the filter that estimates the current
(:mod:`dockingrl.transforms.current_filter`) share it."""

from __future__ import annotations

import torch

from dockingrl.env.arrays import ops
from dockingrl.env.realism import SENSOR_OF_ENTRY, SENSORS
from dockingrl.transforms.ekf_layout import symmetric

#: the measurement entries of each sensor, in :data:`~dockingrl.env.realism.SENSORS`' order
#: (USBL: range and bearing; DVL: the two ground velocities; IMU: heading and yaw rate)
SENSOR_ENTRIES = tuple(
    tuple(i for i, s in enumerate(SENSOR_OF_ENTRY) if s == sensor) for sensor in range(len(SENSORS))
)


def sensor_distances(P, H, y, noise, full):
    """Squared Mahalanobis distance of each sensor's two innovations, ``(3, N)``, batch-last,
    before whitening: ``S_s = H_s P H_s^T + R_s``."""
    distances = []
    for i, j in SENSOR_ENTRIES:
        Ph_i = (P * H[i].unsqueeze(0)).sum(1)
        Ph_j = (P * H[j].unsqueeze(0)).sum(1)
        if full:
            r_ii, r_ij, r_jj = ((noise[a] * noise[b]).sum(0) for a, b in ((i, i), (i, j), (j, j)))
        else:
            r_ii, r_ij, r_jj = noise[i] ** 2, torch.zeros_like(noise[i]), noise[j] ** 2
        s_ii = (H[i] * Ph_i).sum(0) + r_ii
        s_ij = (H[i] * Ph_j).sum(0) + r_ij
        s_jj = (H[j] * Ph_j).sum(0) + r_jj
        det = s_ii * s_jj - s_ij * s_ij
        distances.append((s_jj * y[i] ** 2 - 2.0 * s_ij * y[i] * y[j] + s_ii * y[j] ** 2) / det)
    return torch.stack(distances, dim=0)


def sequential_update(P, H, y, noise, full, arrived=None, gate=None):
    """Eqs. 31-34 of :func:`~dockingrl.transforms.ekf.ekf_update` on batch-last entries,
    for a state of any size ``n``: ``P`` ``(n, n, N)``, ``H`` ``(6, n, N)``, ``y`` ``(6, N)``;
    ``noise`` the ``(6, N)`` sigmas of a diagonal ``R`` or, with ``full``, the ``(6, 6, N)``
    Cholesky factor of a full one; ``arrived`` and ``gate`` as in ``ekf_update``. Returns
    ``(x - x_prior, P)``, the readings applied one at a time, each linearised at the prior."""
    xp = ops(P)
    if gate is not None:
        accepted = sensor_distances(P, H, y, noise, full) <= gate  # (3, N)
        accepted = accepted[list(SENSOR_OF_ENTRY)]
        arrived = accepted if arrived is None else arrived & accepted
    if full:  # whiten with the Cholesky factor L of R: L y' = y, L H' = H
        L = noise.permute(2, 0, 1)
        y = torch.linalg.solve_triangular(L, y.T.unsqueeze(-1), upper=False).squeeze(-1).T
        H = torch.linalg.solve_triangular(L, H.permute(2, 0, 1), upper=False).permute(1, 2, 0)
    else:
        y = xp.divide(y, noise)
        H = xp.divide_rows(H, noise)
    shift = xp.zeros_like(H[0])  # x - x_prior: every scalar update linearises at the prior
    for i in range(len(SENSOR_OF_ENTRY)):
        h = H[i]  # (n, N)
        u = xp.matvec(P, h)  # P h
        hu = xp.dot(h, u)
        K = xp.divide(u, hu + 1.0)  # eqs. 31-32 for one unit-variance measurement
        if arrived is not None:  # a zero gain leaves mean and P exactly as they are
            K = xp.where(arrived[i], K, xp.zeros_like(K))
        shift = xp.add_scaled(shift, K, y[i] - xp.dot(h, shift))  # eq. 33
        # eq. 34 in Joseph form, M P M^T + K K^T with M = I - K h^T, without forming M:
        # M P = P - K u^T and (M P) M^T = M P - w K^T, w = (M P) h = u - K (h . u);
        # so P <- P - K (u - K)^T - w K^T
        w = xp.sub(u, xp.multiply(K, hu))
        P = xp.rank2_sub(P, K, xp.sub(u, K), w, K)
    return shift, symmetric(P, batch_last=True)
