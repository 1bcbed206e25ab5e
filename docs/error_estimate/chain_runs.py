"""What the scripts of docs/error_estimate share: a profile scene of one chain, a run of it by
roughlub (its manifest, gaps and velocities), and the error in the estimate's norm."""
import json, os, subprocess, sys
import numpy as np


def scene(c, timeline, solver):
    """`c`: N, mu, gamma, rho, vel, rs (rho*), end, outputs."""
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
outputs = {c['outputs']}
{timeline}
[solver]
backend = "cpu"
{solver}
[output]
grid = 50
plots = false
"""


def run(binary, tmp, text):
    path, out = os.path.join(tmp, "s.toml"), os.path.join(tmp, "out")
    open(path, "w").write(text)
    r = subprocess.run([binary, "run", path, "--out", out, "--quiet", "--force"],
                       capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(r.stderr)
    m = json.load(open(os.path.join(out, "manifest.json")))
    return m, np.load(os.path.join(out, "gaps.npy")), np.load(os.path.join(out, "velocities.npy"))


def error(g, v, g_ref, v_ref):
    """The largest over output times of |ln d - ln d_ref| and |u - u_ref| / (1 + |u_ref|)."""
    return max(np.abs(np.log(g) - np.log(g_ref)).max(),
               (np.abs(v - v_ref) / (1 + np.abs(v_ref))).max())
