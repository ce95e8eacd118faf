"""Finite-difference helpers shared by the derivative tests."""
import numpy as np


def fd_gradient(f, x, h=1e-7):
    g = np.zeros_like(x)
    for i in range(len(x)):
        e = np.zeros_like(x)
        e[i] = h
        g[i] = (f(x + e) - f(x - e)) / (2 * h)
    return g


def fd_jacobian(F, x, h=1e-7):
    cols = []
    for i in range(len(x)):
        e = np.zeros_like(x)
        e[i] = h
        cols.append((F(x + e) - F(x - e)) / (2 * h))
    return np.array(cols).T


def rel_err(a, b):
    return np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-300)
