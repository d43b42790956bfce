"""The EKF's batch-last layout: ``mean`` as ``(5, N)``, ``cov`` as ``(5, 5, N)``.

Thousands of 5 x 5 filters are small matrices, for which batched matrix kernels and
broadcasting over a size-5 innermost dimension are slow on a CPU. The filter of
:mod:`dockingrl.transforms.ekf` therefore runs with every matrix entry a contiguous vector over
the envs, and converts at its boundary with these functions. Written with the operations of
:mod:`dockingrl.env.arrays`, :func:`stack_matrix` and :func:`symmetric` also build one env's
matrices of Python floats (tuples of rows).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from dockingrl.env.arrays import ops


def stack_matrix(rows: Sequence[Sequence[torch.Tensor]], batch_last: bool) -> torch.Tensor:
    """The matrix of the given rows of entries: ``(r, c, N)`` batch-last, else ``(..., r, c)``."""
    if batch_last:
        xp = ops(rows[0][0])
        return xp.stack([xp.stack(row, dim=0) for row in rows], dim=0)
    return torch.stack([torch.stack(list(row), dim=-1) for row in rows], dim=-2)


def vector_to_last(v: torch.Tensor) -> torch.Tensor:
    """``(..., k)`` -> ``(k, N)``, contiguous."""
    return v.reshape(-1, v.shape[-1]).T.contiguous()


def matrix_to_last(m: torch.Tensor, batch_shape: torch.Size) -> torch.Tensor:
    """``(..., r, c)`` (broadcastable to ``batch_shape``) -> ``(r, c, N)`` or ``(r, c, 1)``."""
    if m.dim() == 2:
        return m.unsqueeze(-1)
    m = m.expand(*batch_shape, *m.shape[-2:])
    return m.reshape(-1, *m.shape[-2:]).permute(1, 2, 0).contiguous()


def vector_from_last(v: torch.Tensor, batch_shape: torch.Size) -> torch.Tensor:
    """``(k, N)`` -> ``(*batch_shape, k)``."""
    return v.T.contiguous().reshape(*batch_shape, v.shape[0])


def matrix_from_last(m: torch.Tensor, batch_shape: torch.Size) -> torch.Tensor:
    """``(r, c, N)`` -> ``(*batch_shape, r, c)``."""
    return m.permute(2, 0, 1).contiguous().reshape(*batch_shape, *m.shape[:2])


def symmetric(matrix: torch.Tensor, batch_last: bool = False) -> torch.Tensor:
    """``(M + M^T) / 2``, of a batch-last matrix or of ``(..., n, n)`` ones."""
    if batch_last:
        return ops(matrix).symmetric(matrix)
    return 0.5 * (matrix + matrix.transpose(-1, -2))
