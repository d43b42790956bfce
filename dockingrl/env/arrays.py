"""The array operations the equation functions are written with, for two kinds of numbers.

The functions of :mod:`dockingrl.env.dynamics`, :mod:`dockingrl.env.reward`,
:mod:`dockingrl.env.transition` and :mod:`dockingrl.transforms.ekf` run on torch tensors (a batch
of envs: the TorchRL env) and on Python floats (one env: the fast Gymnasium env). They take
``xp = ops(x)`` from an argument and call ``xp.sin``, ``xp.stack``, ``xp.matvec``, ... instead
of ``torch.*``: :class:`TensorOps` are torch's own functions (the batched numbers do not
change), :class:`FloatOps` the same operations on floats, vectors being sequences of floats
(tuples or lists) and matrices sequences of rows. Linear algebra is batch-last as the EKF runs
it: a vector ``(k, ...)`` and a matrix ``(r, c, ...)`` hold their entries first, so that row
``i`` of a float matrix is ``P[i]`` as it is for a tensor.
"""

from __future__ import annotations

import math
import operator

import torch


class TensorOps:
    """:func:`ops` for torch tensors (any batch; vectors and matrices batch-last)."""

    sin = staticmethod(torch.sin)
    cos = staticmethod(torch.cos)
    sqrt = staticmethod(torch.sqrt)
    atan2 = staticmethod(torch.atan2)
    remainder = staticmethod(torch.remainder)
    sign = staticmethod(torch.sign)
    where = staticmethod(torch.where)
    maximum = staticmethod(torch.maximum)
    minimum = staticmethod(torch.minimum)
    clamp = staticmethod(torch.clamp)
    clamp_min = staticmethod(torch.clamp_min)
    zeros_like = staticmethod(torch.zeros_like)
    ones_like = staticmethod(torch.ones_like)
    logical_not = staticmethod(torch.logical_not)
    add = staticmethod(operator.add)
    sub = staticmethod(operator.sub)
    multiply = staticmethod(operator.mul)
    divide = staticmethod(operator.truediv)
    add_matrix = staticmethod(operator.add)

    @staticmethod
    def stack(values, dim: int = 0) -> torch.Tensor:
        return torch.stack(tuple(values), dim=dim)

    @staticmethod
    def unbind(value: torch.Tensor, dim: int = 0) -> tuple[torch.Tensor, ...]:
        return value.unbind(dim)

    @staticmethod
    def norm(vector: torch.Tensor) -> torch.Tensor:
        """Euclidean norm over the last dimension."""
        return torch.linalg.vector_norm(vector, dim=-1)

    @staticmethod
    def add_scaled(y: torch.Tensor, *terms) -> torch.Tensor:
        """``y + x1 * a1 + x2 * a2 + ...`` for ``terms = (x1, a1, x2, a2, ...)``."""
        for x, a in zip(terms[::2], terms[1::2], strict=True):
            y = y + x * a
        return y

    @staticmethod
    def divide_rows(matrix: torch.Tensor, divisor: torch.Tensor) -> torch.Tensor:
        """Row ``i`` of a batch-last ``(r, c, N)`` matrix divided by ``divisor[i]`` ``(r, N)``."""
        return matrix / divisor.unsqueeze(1)

    @staticmethod
    def matvec(matrix: torch.Tensor, vector: torch.Tensor) -> torch.Tensor:
        """``P h`` of a batch-last ``(r, c, N)`` matrix and ``(c, N)`` vector."""
        return (matrix * vector.unsqueeze(0)).sum(1)

    @staticmethod
    def dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """``a . b`` of batch-last vectors ``(k, N)``."""
        return (a * b).sum(0)

    @staticmethod
    def transpose(matrix: torch.Tensor) -> torch.Tensor:
        return matrix.transpose(0, 1)

    @staticmethod
    def symmetric(matrix: torch.Tensor) -> torch.Tensor:
        """``(P + P^T) / 2`` of a batch-last matrix."""
        return 0.5 * (matrix + matrix.transpose(0, 1))

    @staticmethod
    def rank2_sub(matrix, a, b, c, d) -> torch.Tensor:
        """``P - a b^T - c d^T`` of a batch-last matrix and vectors."""
        matrix = torch.addcmul(matrix, a.unsqueeze(1), b.unsqueeze(0), value=-1.0)
        return torch.addcmul(matrix, c.unsqueeze(1), d.unsqueeze(0), value=-1.0)


def _sign(x: float) -> float:
    return float((x > 0) - (x < 0))


class FloatOps:
    """:func:`ops` for one env's Python floats: vectors are sequences (tuples or lists),
    matrices sequences of rows."""

    sin = staticmethod(math.sin)
    cos = staticmethod(math.cos)
    sqrt = staticmethod(math.sqrt)
    atan2 = staticmethod(math.atan2)
    remainder = staticmethod(operator.mod)  # floor modulo, as torch.remainder
    sign = staticmethod(_sign)
    maximum = staticmethod(max)
    minimum = staticmethod(min)
    clamp_min = staticmethod(max)
    logical_not = staticmethod(operator.not_)

    @staticmethod
    def where(condition, a, b):
        return a if condition else b

    @staticmethod
    def clamp(x: float, low: float, high: float) -> float:
        return min(max(x, low), high)

    @staticmethod
    def zeros_like(x):
        return 0.0 if isinstance(x, float | int) else (0.0,) * len(x)

    @staticmethod
    def ones_like(x):
        return 1.0 if isinstance(x, float | int) else (1.0,) * len(x)

    @staticmethod
    def stack(values, dim: int = 0) -> tuple:
        return tuple(values)

    @staticmethod
    def unbind(value, dim: int = 0) -> tuple:
        return value

    @staticmethod
    def norm(vector) -> float:
        return math.hypot(*vector)

    @staticmethod
    def add(a, b) -> list:
        return list(map(operator.add, a, b))

    @staticmethod
    def sub(a, b) -> list:
        return list(map(operator.sub, a, b))

    @staticmethod
    def multiply(a, b) -> list:
        """``a * b`` entry by entry, ``b`` a vector or a number."""
        if isinstance(b, float | int):
            return [x * b for x in a]
        return list(map(operator.mul, a, b))

    @staticmethod
    def divide(a, b) -> list:
        """``a / b`` entry by entry, ``b`` a vector or a number."""
        if isinstance(b, float | int):
            return [x / b for x in a]
        return list(map(operator.truediv, a, b))

    @staticmethod
    def add_scaled(y, *terms) -> list:
        """``y + x1 * a1 + x2 * a2 + ...`` for ``terms = (x1, a1, x2, a2, ...)``, numbers ``a``."""
        if len(terms) == 2:
            x, a = terms
            return [yi + xi * a for yi, xi in zip(y, x, strict=False)]
        x1, a1, x2, a2 = terms
        return [yi + xi * a1 + zi * a2 for yi, xi, zi in zip(y, x1, x2, strict=False)]

    @staticmethod
    def add_matrix(a, b) -> list:
        return [list(map(operator.add, r, s)) for r, s in zip(a, b, strict=False)]

    @staticmethod
    def divide_rows(matrix, divisor) -> list:
        return [[x / d for x in row] for row, d in zip(matrix, divisor, strict=False)]

    @staticmethod
    def matvec(matrix, vector) -> list:
        if len(vector) == 5:  # the EKF's state: unrolled, twice as fast
            v0, v1, v2, v3, v4 = vector
            return [r[0] * v0 + r[1] * v1 + r[2] * v2 + r[3] * v3 + r[4] * v4 for r in matrix]
        return [sum(map(operator.mul, row, vector)) for row in matrix]

    @staticmethod
    def dot(a, b) -> float:
        return sum(map(operator.mul, a, b))

    @staticmethod
    def transpose(matrix) -> list:
        return list(zip(*matrix, strict=False))

    @staticmethod
    def symmetric(matrix) -> list:
        return [
            [0.5 * (x + y) for x, y in zip(row, column, strict=False)]
            for row, column in zip(matrix, zip(*matrix, strict=False), strict=False)
        ]

    @staticmethod
    def rank2_sub(matrix, a, b, c, d) -> list:
        return [
            [x - ai * bj - ci * dj for x, bj, dj in zip(row, b, d, strict=False)]
            for row, ai, ci in zip(matrix, a, c, strict=False)
        ]


def ops(value) -> type[TensorOps] | type[FloatOps]:
    """The operations for ``value``'s kind of numbers: :class:`TensorOps` for a tensor,
    :class:`FloatOps` for a float or a sequence of them."""
    return TensorOps if isinstance(value, torch.Tensor) else FloatOps
