"""How the error estimate of fixed-step runs compares with their error on coarse steps (the
warning's threshold for fixed steps rests on it).

    python3 docs/error_estimate/coarse_fixed_steps.py target/release/roughlub

Three chains not among the shipped scenes (N = 40 compressed toward contact, mu 1e-3; N = 20
with gamma 3.5 and a rho* varying in x; N = 50 with gamma 20), orders 1, 2, 4, 6 and 8 with fixed
steps dt = 0.05 ... 0.005; each run's error against the same chain at order auto, tolerance
1e-11, in the estimate's norm: the largest over output times of |ln d - ln d_ref| and
|u - u_ref| / (1 + |u_ref|). Printed per run: the error, the manifest's `error_estimate.largest`,
their ratio and whether the run warned."""
import json, os, subprocess, sys, tempfile
import numpy as np

BIN = sys.argv[1] if len(sys.argv) > 1 else "target/release/roughlub"
CHAINS = [
    dict(N=40, mu=0.001, gamma=1.0, rho="0.5", vel="sin(2*pi*x)", rs="0.6", end=0.3),
    dict(N=20, mu=0.01, gamma=3.5, rho="0.7", vel="0.5*sin(2*pi*x)", rs="0.7+0.1*sin(10*pi*x)", end=0.3),
    dict(N=50, mu=0.01, gamma=20.0, rho="0.8", vel="0.5*sin(2*pi*x)", rs="0.85", end=0.3),
]


def scene(c, timeline, solver):
    return f"""name = "x"
[model]
particles = {c['N']}
mu = {c['mu']}
gamma = {c['gamma']}
[initial]
rho = "{c['rho']}"
velocity = "{c['vel']}"
rho_star = "{c['rs']}"
[time]
end = {c['end']}
outputs = 7
{timeline}
[solver]
backend = "cpu"
{solver}
[output]
grid = 50
plots = false
"""


def run(tmp, text):
    path, out = os.path.join(tmp, "s.toml"), os.path.join(tmp, "out")
    open(path, "w").write(text)
    r = subprocess.run([BIN, "run", path, "--out", out, "--quiet", "--force"],
                       capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(r.stderr)
    m = json.load(open(os.path.join(out, "manifest.json")))
    return m, np.load(os.path.join(out, "gaps.npy")), np.load(os.path.join(out, "velocities.npy"))


with tempfile.TemporaryDirectory() as tmp:
    for c in CHAINS:
        _, G, V = run(tmp, scene(c, "tolerance = 1e-11", 'order = "auto"'))
        print(f"N = {c['N']}, mu = {c['mu']}, gamma = {c['gamma']}, rho* = {c['rs']}")
        for order in [1, 2, 4, 6, 8]:
            for dt in [0.05, 0.025, 0.01, 0.005]:
                m, g, v = run(tmp, scene(c, f"dt = {dt}", f"order = {order}"))
                if m["members"][0]["status"] != "ok":
                    print(f"  order {order} dt {dt}: {m['members'][0]['status']}")
                    continue
                err = max(np.abs(np.log(g) - np.log(G)).max(), (np.abs(v - V) / (1 + np.abs(V))).max())
                est = float(m["error_estimate"]["largest"])
                warned = "warns" if m["error_estimate"].get("warning") else "-"
                print(f"  order {order} dt {dt}: error {err:.2e} estimate {est:.2e} "
                      f"estimate/error {est / err:.3g} {warned}")
