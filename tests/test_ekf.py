"""The pure EKF functions against an independent plain-numpy implementation of eqs. 24-34."""

import math
from functools import partial

import numpy as np
import pytest
import torch

from dockingrl.transforms.ekf import (
    MEASUREMENT_NOISE_STD,
    PROCESS_NOISE_STD,
    ekf_predict,
    ekf_step,
    ekf_update,
    initial_covariance,
    measurement_covariance,
    measurement_function,
    measurement_jacobian,
    motion_jacobian,
    motion_model,
    state_from_observation,
)

DT, K_V, K_W = 0.2, 2.5, 2.5


def numpy_ekf_step(x, P, u, oc, z, Q, R):
    """Eqs. 24-34 written out independently, one filter, joint update, Joseph form."""
    px, py, a, nu, w = x
    # eq. 24 / 28
    x_pred = np.array(
        [
            px + (math.cos(a) * nu + oc[0]) * DT,
            py + (math.sin(a) * nu + oc[1]) * DT,
            a + w * DT,
            nu + K_V * (u[0] - nu) * DT,
            w + K_W * (u[1] - w) * DT,
        ]
    )
    x_pred[2] = (x_pred[2] + math.pi) % (2 * math.pi) - math.pi
    # eq. 25 / 29
    A = np.array(
        [
            [1, 0, -math.sin(a) * nu * DT, math.cos(a) * DT, 0],
            [0, 1, math.cos(a) * nu * DT, math.sin(a) * DT, 0],
            [0, 0, 1, 0, DT],
            [0, 0, 0, 1 - K_V * DT, 0],
            [0, 0, 0, 0, 1 - K_W * DT],
        ]
    )
    P_pred = A @ P @ A.T + Q
    # eq. 26 / 27
    px, py, a, nu, w = x_pred
    rho = math.hypot(px, py)
    h = np.array(
        [
            rho,
            math.atan2(-py, -px) - a,
            a,
            nu + oc[0] * math.cos(a) + oc[1] * math.sin(a),
            oc[1] * math.cos(a) - oc[0] * math.sin(a),
            w,
        ]
    )
    H = np.array(
        [
            [px / rho, py / rho, 0, 0, 0],
            [-py / rho**2, px / rho**2, -1, 0, 0],
            [0, 0, 1, 0, 0],
            [0, 0, -oc[0] * math.sin(a) + oc[1] * math.cos(a), 1, 0],
            [0, 0, -oc[1] * math.sin(a) - oc[0] * math.cos(a), 0, 0],
            [0, 0, 0, 0, 1],
        ]
    )
    # eqs. 30-34
    y = z - h
    y[1:3] = (y[1:3] + math.pi) % (2 * math.pi) - math.pi
    S = H @ P_pred @ H.T + R
    K = P_pred @ H.T @ np.linalg.inv(S)
    x_new = x_pred + K @ y
    x_new[2] = (x_new[2] + math.pi) % (2 * math.pi) - math.pi
    M = np.eye(5) - K @ H
    P_new = M @ P_pred @ M.T + K @ R @ K.T
    return x_new, P_new


def random_case(rng, n):
    x = np.stack(
        [
            rng.uniform(-30, -2, n),
            rng.uniform(-8, 8, n),
            rng.uniform(-math.pi, math.pi, n),
            rng.uniform(-0.3, 0.8, n),
            rng.uniform(-0.3, 0.3, n),
        ],
        -1,
    )
    B = rng.normal(size=(n, 5, 5)) * 0.1
    P = B @ B.transpose(0, 2, 1) + 0.01 * np.eye(5)
    u = np.stack([rng.uniform(-0.4, 0.8, n), rng.uniform(-0.3, 0.3, n)], -1)
    oc = rng.uniform(-0.3, 0.3, (n, 2))
    z_true = measurement_function(torch.from_numpy(x), torch.from_numpy(oc)).numpy()
    z = z_true + rng.normal(size=(n, 6)) * np.array([0.5, 0.03, 0.05, 0.02, 0.02, 0.004])
    z[:, 1:3] = (z[:, 1:3] + math.pi) % (2 * math.pi) - math.pi
    return x, P, u, oc, z


@pytest.mark.parametrize("diagonal_r", [True, False])
def test_one_step_matches_numpy_reference(diagonal_r):
    rng = np.random.default_rng(0)
    n = 64
    x, P, u, oc, z = random_case(rng, n)
    Q = np.diag(np.square(PROCESS_NOISE_STD))
    R = measurement_covariance(torch.from_numpy(z[:, 0])).numpy()
    t = torch.from_numpy
    mean, cov = ekf_predict(t(x), t(P), t(u), t(oc), t(Q), DT, k_v=K_V, k_w=K_W)
    R_arg = t(np.diagonal(R, axis1=-2, axis2=-1).copy()) if diagonal_r else t(R)
    mean, cov = ekf_update(mean, cov, t(z), t(oc), R_arg, diagonal=diagonal_r)
    for i in range(n):
        x_ref, P_ref = numpy_ekf_step(x[i], P[i], u[i], oc[i], z[i], Q, R[i])
        np.testing.assert_allclose(mean[i].numpy(), x_ref, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(cov[i].numpy(), P_ref, rtol=1e-9, atol=1e-12)
    fused_mean, fused_cov, filtered = ekf_step(
        t(x), t(P), t(u), t(z), t(oc), t(Q), R_arg, DT, diagonal=diagonal_r
    )
    torch.testing.assert_close(fused_mean, mean)
    torch.testing.assert_close(fused_cov, cov)
    torch.testing.assert_close(filtered, measurement_function(mean, t(oc)))


def test_float32_and_leading_batch_shapes():
    rng = np.random.default_rng(1)
    x, P, u, oc, z = random_case(rng, 12)
    args64 = [torch.from_numpy(a) for a in (x, P, u, oc, z)]
    Q = torch.diag(torch.tensor(PROCESS_NOISE_STD, dtype=torch.float64) ** 2)
    R = measurement_covariance(args64[4][:, 0])
    m64, c64, _ = ekf_step(args64[0], args64[1], args64[2], args64[4], args64[3], Q, R, DT)
    shaped = [a.float().reshape(3, 4, *a.shape[1:]) for a in args64]
    m32, c32, f32 = ekf_step(
        shaped[0],
        shaped[1],
        shaped[2],
        shaped[4],
        shaped[3],
        Q.float(),
        R.float().reshape(3, 4, 6, 6),
        DT,
    )
    assert m32.dtype == torch.float32 and m32.shape == (3, 4, 5) and c32.shape == (3, 4, 5, 5)
    assert f32.shape == (3, 4, 6)
    torch.testing.assert_close(m32.reshape(12, 5).double(), m64, rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(c32.reshape(12, 5, 5).double(), c64, rtol=1e-3, atol=1e-6)


def test_jacobians_match_autograd():
    rng = np.random.default_rng(2)
    x, _, _, oc, _ = random_case(rng, 5)
    u = torch.tensor([0.3, 0.1], dtype=torch.float64)
    for i in range(5):
        xi, oci = torch.from_numpy(x[i]), torch.from_numpy(oc[i])
        H = torch.autograd.functional.jacobian(partial(measurement_function, current=oci), xi)
        torch.testing.assert_close(measurement_jacobian(xi, oci), H)
        A = torch.autograd.functional.jacobian(
            partial(motion_model, action=u, current=oci, dt=DT), xi
        )
        torch.testing.assert_close(motion_jacobian(xi, DT), A)


def test_initialisation_inverts_the_measurement():
    rng = np.random.default_rng(3)
    x, _, _, oc, _ = random_case(rng, 20)
    xs, ocs = torch.from_numpy(x), torch.from_numpy(oc)
    z = measurement_function(xs, ocs)
    back = state_from_observation(z, ocs)
    # sway is not part of the state: w is measured directly, nu from vx
    torch.testing.assert_close(back, xs)
    R = measurement_covariance(z[:, 0])
    P0 = initial_covariance(z, ocs, R)
    assert torch.linalg.eigvalsh(P0[:, :3, :3]).min() > 0
    torch.testing.assert_close(P0, P0.transpose(-1, -2))
    # the position uncertainty is that of the range/bearing fix: sigma_rho^2 + (rho sigma_psi)^2
    var_xy = P0[:, 0, 0] + P0[:, 1, 1]
    sigma = torch.tensor(MEASUREMENT_NOISE_STD, dtype=torch.float64)
    expected = (sigma[0] * z[:, 0]) ** 2 + (z[:, 0] ** 2) * (sigma[1] ** 2 + sigma[2] ** 2)
    torch.testing.assert_close(var_xy, expected)


def test_rho_guard_keeps_the_update_finite_at_the_docking_station():
    mean = torch.tensor([[0.0, 0.0, 0.3, 0.2, 0.0], [1e-9, -1e-9, -3.1, 0.2, 0.1]])
    cov = torch.eye(5).expand(2, 5, 5) * 0.05
    z = torch.tensor([[0.01, 0.0, 0.3, 0.2, 0.0, 0.0], [0.0, 3.1, -3.1, 0.2, 0.0, 0.1]])
    oc = torch.zeros(2, 2)
    R = measurement_covariance(z[:, 0])
    m, c = ekf_update(mean, cov, z, oc, R)
    assert torch.isfinite(m).all() and torch.isfinite(c).all()
    assert torch.linalg.eigvalsh(c).min() > 0
