"""Central differences, the independent reference of the tests' closed-form Jacobians."""

import numpy as np


def central_differences(f, x, h: float = 1e-7) -> np.ndarray:
    """d f / d x at ``x`` (an array of any shape; ``f`` returns an array of any shape):
    (f's size, x's size), column j from (f(x + h e_j) - f(x - h e_j)) / 2h."""
    x = np.asarray(x, dtype=float)
    columns = []
    for j in range(x.size):
        step = np.zeros(x.size)
        step[j] = h
        step = step.reshape(x.shape)
        columns.append((np.asarray(f(x + step)) - np.asarray(f(x - step))).ravel() / (2.0 * h))
    return np.column_stack(columns)


def worst_column(numeric, analytic) -> tuple[float, int]:
    """The largest difference between two Jacobians and the column it is in."""
    error = np.abs(np.asarray(numeric) - np.asarray(analytic)).max(axis=0)
    return float(error.max()), int(np.argmax(error))
