"""An independent check of the order loss (issue 22): the extrapolated linearly implicit Euler
method written from the textbook in numpy/scipy, with nothing of roughlub in it, on the same
chain as docs/scipy_comparison/compare.py. If this plain implementation loses order on the
random chain as roughlub does, and keeps it on the chain with every d* equal, the loss is a
property of the method on this ODE (stiff order reduction), not a defect of roughlub.

    python3 docs/order_loss/independent_extrapolation.py [options]   (from the repository root)

The chain and its model (`rhs`, `jac`) are compare.py's (../scipy_comparison/chain_model.py):
N particles, rho = 0.7, eps = rho / (2N), u0 = 0.5 sin(2 pi x), state y = (gaps d_1..d_N,
interior velocities u_1..u_{N-1}), roughness r uniform within +-30 % (numpy default_rng(seed 1))
or all r = gap / 2 (`--roughness uniform`: every d* equal to the gap). The gaps are advanced as d, or as ln d with `--log-gaps` (as roughlub
keeps closing gaps; the order loss is stronger in that form).

The method (Hairer & Wanner II, IV.9; Deuflhard's SEULEX without order or step control): one
macro step H from y_n; row j takes n_j substeps h = H / n_j of
    (I - h J) (y_{i+1} - y_i) = h f(y_i),
J the exact Jacobian at y_n (or at y_i with `--jacobian-each-substep`); n_j = 1, 2, 3, ... (or
2, 3, 4, ... with `--sequence from_2`); Aitken-Neville
    T_{j,l} = T_{j,l-1} + (T_{j,l-1} - T_{j-1,l-1}) / (n_j / n_{j-l+1} - 1),
and order p takes T_{p,p}. Fixed steps H = T 2^-k, k = K0..K1-1. The linear systems are solved
banded: in the interleaved order (d_1, u_1, d_2, u_2, ..., u_{N-1}, d_N) the Jacobian has two
diagonals either side.

Printed: the differences of successive halvings at t = T, max(max |ln d_a - ln d_b|,
max |u_a - u_b| / max |u_b|), and the observed orders log2 of successive ratios of them.
`--linear` instead integrates the frozen problem y' = f(y0) + J0 (y - y0) and prints errors
against its exact solution (scipy.sparse.linalg.expm_multiply) with the gaps' part
max |d - d_exact| / d_exact, and their orders.

Options: --N 200 --mu 0.01 --gamma 2 --end 0.3 --roughness both|random|uniform --orders 2,3,4,6
--sequence from_1|from_2 --jacobian-each-substep --k 4 12 --linear --log-gaps --extrapolate-other
(the gaps' tableau in the other form), --roughlub BIN (roughlub's own differences on the same
chain, printed below each of this script's: exact matrix, its default sequence for fixed steps,
from_1). The default prints
the random and the uniform chains' orders 2, 3, 4, 6 (about 50 s on one core)."""
import argparse, os, subprocess, sys, tempfile, time
import numpy as np
import scipy.sparse as sp
from scipy.linalg import solve_banded
from scipy.sparse.linalg import expm_multiply

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..",
                                "scipy_comparison"))
import chain_model  # noqa: E402

a = argparse.ArgumentParser()
a.add_argument("--N", type=int, default=200)
a.add_argument("--mu", type=float, default=0.01)
a.add_argument("--gamma", type=float, default=2.0)
a.add_argument("--end", type=float, default=0.3)
a.add_argument("--roughness", choices=["both", "random", "uniform"], default="both")
a.add_argument("--orders", default="2,3,4,6")
a.add_argument("--sequence", choices=["from_1", "from_2"], default="from_1")
a.add_argument("--jacobian-each-substep", action="store_true")
a.add_argument("--k", type=int, nargs=2, default=[4, 12], help="k = K0..K1-1, H = end 2^-k")
a.add_argument("--linear", action="store_true")
a.add_argument("--log-gaps", action="store_true", help="advance ln d instead of d (as roughlub)")
a.add_argument("--roughlub", metavar="BIN",
               help="also run roughlub (order p, fixed dt, exact matrix) on the same chain")
a.add_argument("--extrapolate-other", action="store_true",
               help="extrapolate the gaps in the other form than the one advanced (ln d or d)")
args = a.parse_args()


# Interleaved order (d_1, u_1, ..., u_{N-1}, d_N): P[q] is the natural index of interleaved q.
N = args.N
P = np.empty(2 * N - 1, dtype=int)
P[0::2] = np.arange(N)
P[1::2] = N + np.arange(N - 1)
Q = np.argsort(P)  # natural index -> interleaved index
KL = KU = 2


def banded(J):
    """LAPACK banded storage (solve_banded's) of the sparse J in interleaved order; the Python
    loop of `jac` is paid once per Jacobian, the rest is vectorised."""
    c = J.tocoo()
    r, k = Q[c.row], Q[c.col]
    assert np.all(np.abs(r - k) <= KL), "not banded in the interleaved order"
    ab = np.zeros((KL + KU + 1, 2 * N - 1))
    ab[KU + r - k, k] = c.data
    return ab


def macro_step(f, jac_b, y, H, p, seq):
    """One extrapolated step of order p from y (natural order in and out, interleaved inside)."""
    ns = [j + 1 for j in range(p)] if seq == "from_1" else [j + 2 for j in range(p)]
    J0 = jac_b(y)
    T = []
    for j, n in enumerate(ns):
        h = H / n
        z = y.copy()
        for i in range(n):
            Jb = J0 if (i == 0 or not args.jacobian_each_substep) else jac_b(z)
            M = -h * Jb
            M[KU] += 1.0
            z = z + solve_banded((KL, KU), M, h * f(z)[P], overwrite_ab=True,
                                 check_finite=False)[Q]
        # Aitken-Neville: row j's T_{j,1..j+1} from row j-1's.
        row = [to_tableau(z)]
        for l in range(1, j + 1):
            row.append(row[l - 1] + (row[l - 1] - T[l - 1]) / (n / ns[j - l] - 1))
        T = row
    return from_tableau(T[p - 1])


def to_tableau(z):
    """The gaps in the form they are extrapolated in: as advanced, or the other one."""
    if not args.extrapolate_other:
        return z
    g = np.exp(z[:N]) if args.log_gaps else np.log(z[:N])
    return np.concatenate((g, z[N:]))


def from_tableau(x):
    if not args.extrapolate_other:
        return x
    g = np.log(x[:N]) if args.log_gaps else np.exp(x[:N])
    return np.concatenate((g, x[N:]))


def integrate(f, jac_b, y0, p, seq, k):
    steps = 2**k
    H = args.end / steps
    y = y0.copy()
    for _ in range(steps):
        y = macro_step(f, jac_b, y, H, p, seq)
    return y


def difference(a, b, d_exact=None):
    """compare.py's / `roughlub accuracy`'s norm: ln d and velocities over max |u|."""
    ua, ub = a[N:], b[N:]
    if d_exact is None:
        with np.errstate(invalid="ignore"):
            dd = np.abs(np.log(a[:N]) - np.log(b[:N])).max()
    else:  # the frozen linear problem's gaps may not stay positive: relative difference
        dd = (np.abs(a[:N] - b[:N]) / np.abs(d_exact)).max()
    return max(dd, np.abs(ua - ub).max() / np.abs(ub).max())


def roughlub_end(binary, c, p, H):
    """roughlub's state at t = end from the same numbers (a particle file), fixed steps H."""
    with tempfile.TemporaryDirectory() as tmp:
        chain_model.write_particles(c, os.path.join(tmp, "chain.csv"))
        with open(os.path.join(tmp, "scene.toml"), "w") as f:
            f.write(f"""name = "independent_extrapolation"
[model]
mu = {args.mu!r}
gamma = {args.gamma!r}
radius = {c.eps!r}
[initial]
particles = "chain.csv"
[time]
end = {args.end!r}
outputs = 2
dt = {H!r}
[solver]
order = {p}
backend = "cpu"
jacobian = "exact"
[output]
plots = false
fields = ["gaps", "velocities"]
""")
        out = os.path.join(tmp, "out")
        subprocess.run([binary, "run", os.path.join(tmp, "scene.toml"), "--out", out, "--quiet"],
                       check=True)
        g = np.load(os.path.join(out, "gaps.npy")).reshape(2, N)[-1]
        v = np.load(os.path.join(out, "velocities.npy")).reshape(2, N - 1)[-1]
    return np.concatenate((g, v))


def report(label, diffs, what="differences"):
    rates = [np.log2(x / y) for x, y in zip(diffs, diffs[1:])]
    print(f"{label}: {what} " + " ".join(f"{d:.1e}" for d in diffs))
    print("    observed orders " + " ".join(f"{r:.2f}" for r in rates), flush=True)


t_start = time.perf_counter()
print(("ln d, " if args.log_gaps else "") + f"N = {N}, mu = {args.mu}, gamma = {args.gamma}, "
      f"T = {args.end}, sequence {args.sequence}, "
      f"Jacobian {'at every substep' if args.jacobian_each_substep else 'at the macro step start'}"
      f", H = T 2^-k, k = {args.k[0]}..{args.k[1] - 1}" + (", frozen linear problem" if args.linear else ""))
for roughness in (["random", "uniform"] if args.roughness == "both" else [args.roughness]):
    c = chain_model.chain(N, args.mu, args.gamma, roughness)
    rhs, jac, y0 = c.rhs, c.jac, c.y0
    f = lambda y: rhs(0.0, y)
    jac_b = lambda y: banded(jac(0.0, y))
    exact = None
    if args.log_gaps:
        # State (ln d, u), as roughlub keeps closing gaps: F(s, u) = (f_d / d, f_u) at d = e^s.
        # Its Jacobian is D^-1 J D + diag(-f_d / d, 0), D = diag(d, 1), as f_d is d-free.
        assert not args.linear, "--log-gaps is for the nonlinear problem"
        nat = lambda y: np.concatenate((np.exp(y[:N]), y[N:]))
        def f(y, rhs=rhs):
            z = nat(y); v = rhs(0.0, z); v[:N] /= z[:N]
            return v
        def jac_b(y, rhs=rhs, jac=jac):
            z = nat(y); w = np.concatenate((z[:N], np.ones(N - 1)))
            corr = np.concatenate((-rhs(0.0, z)[:N] / z[:N], np.zeros(N - 1)))
            return banded(sp.diags(1 / w) @ jac(0.0, z) @ sp.diags(w) + sp.diags(corr))
        y0 = np.concatenate((np.log(y0[:N]), y0[N:]))
    if args.linear:
        # y' = f0 + J0 (y - y0): z = y - y0 solves z' = J0 z + f0, z(0) = 0; augmenting the state
        # with s = 1 (s' = 0) makes it w' = A w, so that z(T) is expm_multiply's.
        f0, J0 = f(y0), jac(0.0, y0)
        J0b = banded(J0)
        f = lambda y: f0 + J0 @ (y - y0)
        jac_b = lambda y: J0b
        n = 2 * N - 1
        A = sp.bmat([[J0, sp.csc_matrix(f0[:, None])], [None, sp.csc_matrix((1, 1))]]).tocsc()
        w0 = np.zeros(n + 1); w0[-1] = 1.0
        exact = y0 + expm_multiply(args.end * A, w0)[:n]
    for p in [int(o) for o in args.orders.split(",") if o]:
        t0 = time.perf_counter()
        ends = [integrate(f, jac_b, y0, p, args.sequence, k) for k in range(*args.k)]
        if args.log_gaps:
            ends = [nat(e) for e in ends]
        if args.linear:
            report(f"{roughness} d*, order {p}", [difference(e, exact, exact[:N]) for e in ends],
                   "errors")
        else:
            report(f"{roughness} d*, order {p}", [difference(x, y) for x, y in zip(ends, ends[1:])])
        print(f"    ({time.perf_counter() - t0:.1f} s)", flush=True)
        if args.roughlub and not args.linear:
            ends = [roughlub_end(args.roughlub, c, p, args.end / 2**k)
                    for k in range(*args.k)]
            report(f"roughlub, {roughness} d*, order {p}",
                   [difference(x, y) for x, y in zip(ends, ends[1:])])
print(f"total {time.perf_counter() - t_start:.1f} s")
