"""Does roughlub's error follow its tolerance? An independent check against scipy's Radau
(issue 22, item 2; the tables of docs/accuracy.md that name this script).

Seven random chains (radii r_i uniform within +-30 % of half the mean gap, so d*_i = r_{i-1} + r_i
varies from particle to particle), away from contact and driven towards it:

  A_g1        N = 200, rho 0.7, mu 0.01, gamma 1,  u0 = 0.5 sin(2 pi x), to t = 0.3
  B_g20       N = 200, rho 0.7, mu 0.01, gamma 20, u0 = 0.5 sin(2 pi x), to t = 0.3
  C2_contact  N = 300, rho 0.7, mu 0.01, gamma 5,  u0 = 2 sin(2 pi x),   to t = 0.2 (ln d to -27)
  D_dense     N = 150, rho 0.9, mu 0.1,  gamma 5,  u0 = 0.5 sin(2 pi x), to t = 0.5
  E_mu1_N400  N = 400, rho 0.7, mu 1,    gamma 2,  u0 = 2 sin(2 pi x),   to t = 0.1
  F_randu     N = 100, rho 0.8, mu 1e-3, gamma 5,  u0 random in [-1, 1],  to t = 0.2, jittered gaps
  C_deep      C2_contact with mu 1e-3: its collisions take ln d to -220, where Radau does not
              complete; the check covers its first output interval only (t <= 0.025, ln d to -18)

The reference: scipy's solve_ivp(method="Radau") in the variables (ln d, u) with the model's
exact sparse Jacobian, rtol 1e-12 and atol 1e-13, checked against rtol 1e-11 (both cached in
out/tolerance_check/<chain>/). roughlub runs the same chain from a particle file at each half
decade of tolerance from 1e-4 to 1e-10 (order auto; `--jacobian`, `--sequence` set them); the
error is the largest over output times of max |ln d - ln d_ref| and max |u - u_ref| / max |u_ref|.
Printed per tolerance: the error, error / tolerance, the matrix that ran, accepted + rejected
steps, and where the error did not fall from the looser tolerance.

    python3 docs/scipy_comparison/tolerance_check.py target/release/roughlub [CHAIN ...]
        [--jacobian auto|exact|frozen] [--sequence auto|from_1|from_2] [--tolerances 1e-11,1e-12]
        (from the repository root)
"""
import argparse, json, os, subprocess, time
import numpy as np
import scipy.sparse as sp
from scipy.integrate import solve_ivp

CHAINS = {
    "A_g1": dict(N=200, rho=0.7, mu=0.01, gamma=1, u="sin", amp=0.5, end=0.3, T=11, seed=11, jit=0.0),
    "B_g20": dict(N=200, rho=0.7, mu=0.01, gamma=20, u="sin", amp=0.5, end=0.3, T=11, seed=12, jit=0.0),
    "C2_contact": dict(N=300, rho=0.7, mu=0.01, gamma=5, u="sin", amp=2.0, end=0.2, T=9, seed=13, jit=0.0),
    "D_dense": dict(N=150, rho=0.9, mu=0.1, gamma=5, u="sin", amp=0.5, end=0.5, T=11, seed=14, jit=0.0),
    "E_mu1_N400": dict(N=400, rho=0.7, mu=1.0, gamma=2, u="sin", amp=2.0, end=0.1, T=6, seed=15, jit=0.0),
    "F_randu": dict(N=100, rho=0.8, mu=1e-3, gamma=5, u="rand", amp=1.0, end=0.2, T=5, seed=16, jit=0.3),
    "C_deep": dict(N=300, rho=0.7, mu=1e-3, gamma=5, u="sin", amp=2.0, end=0.2, T=9, seed=13, jit=0.0, checked=2),
}
TOLERANCES = [10 ** (-k / 2) for k in range(8, 21)]


def write_chain(c, path):
    """The particle file (x, u, r) of chain c; returns eps and the radii."""
    n, rho = c["N"], c["rho"]
    eps = rho / (2 * n)
    rng = np.random.default_rng(c["seed"])
    gap = 1 / n - 2 * eps
    g = gap * np.ones(n)
    if c["jit"] > 0:
        g = g * rng.uniform(1 - c["jit"], 1 + c["jit"], n)
        g *= (1 - 2 * eps * n) / g.sum()
    x = np.concatenate(([0.0], np.cumsum(g + 2 * eps)))
    x[-1] = 1.0
    r = 0.5 * gap * rng.uniform(0.7, 1.3, n + 1)
    u = c["amp"] * (np.sin(2 * np.pi * x) if c["u"] == "sin" else rng.uniform(-1, 1, n + 1))
    u[0] = u[-1] = 0.0
    with open(path, "w") as f:
        f.write("x,u,r\n")
        for row in zip(x, u, r):
            f.write("%r,%r,%r\n" % tuple(float(v) for v in row))
    return eps, r


def model(c, eps, r):
    """The right-hand side and sparse Jacobian in (ln d_1..N, u_1..N-1): d(ln d_i)/dt = r_i,
    m du_i/dt = mu (r_{i+1} - r_i) - (G_{i+1} - G_i), r_i = (u_i - u_{i-1})/d_i, m = 2 eps,
    G_i = ((d*_i + 2 eps)/(d_i + 2 eps))^gamma, d*_i = r_{i-1} + r_i (u_0 = u_N = 0)."""
    n, mu, gam, m = c["N"], c["mu"], c["gamma"], 2 * eps
    dstar = r[:-1] + r[1:]
    diff = sp.diags([-np.ones(n - 1), np.ones(n - 1)], [0, 1], shape=(n - 1, n)).tocsr()
    rates = sp.diags([np.ones(n - 1), -np.ones(n - 1)], [0, -1], shape=(n, n - 1)).tocsr()

    def parts(y):
        d = np.exp(y[:n])
        rate = (rates @ y[n:]) / d
        return d, rate, ((dstar + 2 * eps) / (d + 2 * eps)) ** gam

    def rhs(t, y):
        d, rate, g = parts(y)
        return np.concatenate((rate, (mu * (diff @ rate) - diff @ g) / m))

    def jac(t, y):
        d, rate, g = parts(y)
        rate_s, rate_u = sp.diags(-rate), sp.diags(1 / d) @ rates
        g_s = sp.diags(-gam * g * d / (d + 2 * eps))
        bottom = sp.hstack([(mu / m) * (diff @ rate_s) - (diff @ g_s) / m, (mu / m) * (diff @ rate_u)])
        return sp.vstack([sp.hstack([rate_s, rate_u]), bottom]).tocsc()

    return rhs, jac


def scene(c, eps, tolerance, jacobian, sequence):
    return f"""name = "tolerance_check"
[model]
mu = {c["mu"]!r}
gamma = {c["gamma"]}
radius = {eps!r}
[initial]
particles = "chain.csv"
[time]
end = {c["end"]}
outputs = {c["T"]}
tolerance = {tolerance:.4e}
[solver]
order = "auto"
backend = "cpu"
precision = "f64"
jacobian = "{jacobian}"
sequence = "{sequence}"
[output]
plots = false
fields = ["gaps", "velocities"]
"""


def run(binary, directory, c, eps, tolerance, jacobian, sequence):
    with open(os.path.join(directory, "scene.toml"), "w") as f:
        f.write(scene(c, eps, tolerance, jacobian, sequence))
    out = os.path.join(directory, "run")
    subprocess.run([binary, "run", "scene.toml", "--out", out, "--quiet", "--force"], cwd=directory, check=True)
    m = json.load(open(os.path.join(out, "manifest.json")))
    member = m["members"][0]
    gaps = np.load(os.path.join(out, "gaps.npy")).reshape(c["T"], c["N"])
    vel = np.load(os.path.join(out, "velocities.npy")).reshape(c["T"], c["N"] - 1)
    steps = "%d+%d" % (member["steps_accepted"], member["steps_rejected"])
    return gaps, vel, m["plan"]["jacobian"], steps, member["status"]


def reference(directory, c, eps, r, y0, rtol):
    """Radau at rtol, cached with the chain and initial state it was made from (a cache made
    from another is made again)."""
    path = os.path.join(directory, "radau_%.0e.npz" % rtol)
    made_from = np.concatenate((y0, r, [eps, c["mu"], c["gamma"], c["end"], c["T"], c.get("checked", c["T"])]))
    if os.path.exists(path) and not np.array_equal(np.load(path)["made_from"], made_from):
        os.remove(path)
    if not os.path.exists(path):
        rhs, jac = model(c, eps, r)
        times = np.linspace(0, c["end"], c["T"])[: c.get("checked", c["T"])]
        t0 = time.perf_counter()
        s = solve_ivp(rhs, (0, times[-1]), y0, method="Radau", t_eval=times, rtol=rtol, atol=rtol / 10, jac=jac)
        assert s.success, s.message
        print("  Radau rtol %.0e: %.1f s" % (rtol, time.perf_counter() - t0), flush=True)
        np.savez(path, ln_d=s.y[: c["N"]].T, u=s.y[c["N"]:].T, made_from=made_from)
    z = np.load(path)
    return z["ln_d"], z["u"]


def error(gaps, vel, ln_d, u):
    """Over the output times the reference covers (its first len(ln_d))."""
    gaps, vel = gaps[: len(ln_d)], vel[: len(ln_d)]
    return max(np.abs(np.log(gaps) - ln_d).max(), np.abs(vel - u).max() / np.abs(u).max())


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("binary")
    p.add_argument("chains", nargs="*", default=[k for k in CHAINS if k != "C_deep"])
    p.add_argument("--jacobian", default="auto", choices=["auto", "exact", "frozen"])
    # auto: roughlub's default (from_2 here: order auto, adaptive, f64); from_1 until 2026-11-30.
    p.add_argument("--sequence", default="auto", choices=["auto", "from_1", "from_2"])
    p.add_argument("--tolerances", default=",".join("%.4e" % t for t in TOLERANCES),
                   help="comma list (default: the half decades from 1e-4 to 1e-10)")
    a = p.parse_args()
    tolerances = [float(t) for t in a.tolerances.split(",")]
    binary = os.path.abspath(a.binary)
    for name in a.chains:
        c = CHAINS[name]
        directory = os.path.abspath(os.path.join("out/tolerance_check", name))
        os.makedirs(directory, exist_ok=True)
        eps, r = write_chain(c, os.path.join(directory, "chain.csv"))
        # Start the reference from roughlub's own initial gaps (the file's, to rounding).
        gaps, vel, _, _, _ = run(binary, directory, c, eps, 1e-4, a.jacobian, a.sequence)
        y0 = np.concatenate((np.log(gaps[0]), vel[0]))
        print("%s (jacobian %s, sequence %s)" % (name, a.jacobian, a.sequence), flush=True)
        ln_d, u = reference(directory, c, eps, r, y0, 1e-12)
        ln_d_11, u_11 = reference(directory, c, eps, r, y0, 1e-11)
        check = error(np.exp(ln_d_11), u_11, ln_d, u)
        print("  reference: Radau rtol 1e-12 against 1e-11: %.1e; smallest ln d %.1f" % (check, ln_d.min()))
        if len(ln_d) < c["T"]:
            print("  errors over the first %d output times (t <= %g); steps over the whole run"
                  % (len(ln_d), c["end"] * (len(ln_d) - 1) / (c["T"] - 1)))
        previous, ratios, falls = np.inf, [], True
        for tol in tolerances:
            gaps, vel, matrix, steps, status = run(binary, directory, c, eps, tol, a.jacobian, a.sequence)
            e = error(gaps, vel, ln_d, u)
            note = "" if e < previous else "  (not below the looser tolerance's)"
            falls &= e < previous
            previous = e
            ratios.append(e / tol)
            print("  tolerance %.2e  error %.2e  %5.2fx  %-6s %s steps %s%s" % (tol, e, e / tol, matrix, steps, status, note), flush=True)
        print("  error / tolerance %.2f to %.2f; falls at every half decade: %s" % (min(ratios), max(ratios), "yes" if falls else "no"))


if __name__ == "__main__":
    main()
