"""How the error estimate of fixed-step runs compares with their error on coarse steps (the
warning's threshold for fixed steps rests on it).

    python3 docs/error_estimate/coarse_fixed_steps.py target/release/roughlub

Three chains not among the shipped scenes (N = 40 compressed toward contact, mu 1e-3; N = 20
with gamma 3.5 and a rho* varying in x; N = 50 with gamma 20), orders 1, 2, 4, 6 and 8 with fixed
steps dt = 0.05 ... 0.005; each run's error against the same chain at order auto, tolerance
1e-11, in the estimate's norm: the largest over output times of |ln d - ln d_ref| and
|u - u_ref| / (1 + |u_ref|). Printed per run: the error, the manifest's `error_estimate.largest`,
their ratio and whether the run warned."""
import sys, tempfile
from chain_runs import error, run, scene

BIN = sys.argv[1] if len(sys.argv) > 1 else "target/release/roughlub"
CHAINS = [
    dict(N=40, mu=0.001, gamma=1.0, rho="0.5", vel="sin(2*pi*x)", rs="0.6", end=0.3, outputs=7),
    dict(N=20, mu=0.01, gamma=3.5, rho="0.7", vel="0.5*sin(2*pi*x)", rs="0.7+0.1*sin(10*pi*x)",
         end=0.3, outputs=7),
    dict(N=50, mu=0.01, gamma=20.0, rho="0.8", vel="0.5*sin(2*pi*x)", rs="0.85", end=0.3,
         outputs=7),
]

with tempfile.TemporaryDirectory() as tmp:
    for c in CHAINS:
        _, G, V = run(BIN, tmp, scene(c, "tolerance = 1e-11", 'order = "auto"'))
        print(f"N = {c['N']}, mu = {c['mu']}, gamma = {c['gamma']}, rho* = {c['rs']}")
        for order in [1, 2, 4, 6, 8]:
            for dt in [0.05, 0.025, 0.01, 0.005]:
                m, g, v = run(BIN, tmp, scene(c, f"dt = {dt}", f"order = {order}"))
                if m["members"][0]["status"] != "ok":
                    print(f"  order {order} dt {dt}: {m['members'][0]['status']}")
                    continue
                err = error(g, v, G, V)
                est = float(m["error_estimate"]["largest"])
                warned = "warns" if m["error_estimate"].get("warning") else "-"
                print(f"  order {order} dt {dt}: error {err:.2e} estimate {est:.2e} "
                      f"estimate/error {est / err:.3g} {warned}")
