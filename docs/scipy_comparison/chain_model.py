"""The chain of compare.py (issue 22) and its model in (d, u), numpy/scipy only, shared by
compare.py, ../order_loss/independent_extrapolation.py and ../order_loss/adaptive_errors.py.

N particles, rho = 0.7 (eps = rho / (2N)), u0 = 0.5 sin(2 pi x), roughness r_i uniform within
+-30 % of half the gap (numpy default_rng(seed 1); d*_i = r_{i-1} + r_i), or every r_i half the
gap (`roughness="uniform"`: every d* equal to the gap). State y = (d_1..d_N, u_1..u_{N-1}):
d_i' = u_i - u_{i-1}, m u_i' = mu (rate_{i+1} - rate_i) + G_i - G_{i+1}, rate_i = d_i'/d_i,
m = 2 eps, G_i = ((d*_i + 2 eps)/(d_i + 2 eps))^gamma, u_0 = u_N = 0."""
from types import SimpleNamespace
import numpy as np
import scipy.sparse as sp


def chain(N=200, mu=0.01, gamma=2.0, roughness="random"):
    """The chain's numbers (x, u0, r, eps, d0, y0) and its exact `rhs(t, y)` and sparse
    `jac(t, y)`."""
    eps = 0.7 / (2 * N)  # 2 eps over the spacing 1/N is rho
    x = np.linspace(0, 1, N + 1)
    gap = 1 / N - 2 * eps
    if roughness == "random":
        r = 0.5 * gap * np.random.default_rng(1).uniform(0.7, 1.3, N + 1)
    else:
        r = 0.5 * gap * np.ones(N + 1)
    u0 = 0.5 * np.sin(2 * np.pi * x)
    u0[0] = u0[-1] = 0.0
    d0 = np.diff(x) - 2 * eps
    dstar = r[:-1] + r[1:]
    m = 2 * eps

    def rhs(t, y):
        d, u = y[:N], np.concatenate(([0.0], y[N:], [0.0]))
        rate = (u[1:] - u[:-1]) / d
        g = ((dstar + 2 * eps) / (d + 2 * eps)) ** gamma
        return np.concatenate((u[1:] - u[:-1], (mu * (rate[1:] - rate[:-1]) + g[:-1] - g[1:]) / m))

    def jac(t, y):
        d, u = y[:N], np.concatenate(([0.0], y[N:], [0.0]))
        g = ((dstar + 2 * eps) / (d + 2 * eps)) ** gamma
        gp = -gamma * g / (d + 2 * eps)
        rows, cols, vals = [], [], []

        def add(i, j, v):
            rows.append(i); cols.append(j); vals.append(v)
        for i in range(1, N + 1):
            if i <= N - 1:
                add(i - 1, N + i - 1, 1.0)
            if i >= 2:
                add(i - 1, N + i - 2, -1.0)
        for i in range(1, N):
            k, dl, dr = N + i - 1, d[i - 1], d[i]
            if i + 1 <= N - 1:
                add(k, N + i, mu / (m * dr))
            add(k, k, -mu / m * (1 / dr + 1 / dl))
            if i - 1 >= 1:
                add(k, N + i - 2, mu / (m * dl))
            add(k, i, (-mu * (u[i + 1] - u[i]) / dr**2 - gp[i]) / m)
            add(k, i - 1, (mu * (u[i] - u[i - 1]) / dl**2 + gp[i - 1]) / m)
        return sp.csc_matrix((vals, (rows, cols)), shape=(2 * N - 1, 2 * N - 1))

    y0 = np.concatenate((d0, u0[1:-1]))
    return SimpleNamespace(x=x, u0=u0, r=r, eps=eps, d0=d0, y0=y0, rhs=rhs, jac=jac)


def write_particles(c, path):
    """The chain as a roughlub particle file (x, u, r), every digit kept."""
    with open(path, "w") as f:
        f.write("x,u,r\n" + "".join("%r,%r,%r\n" % (float(a), float(b), float(s))
                                    for a, b, s in zip(c.x, c.u0, c.r)))
