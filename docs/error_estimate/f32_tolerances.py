"""f32's error against the tolerance on a chain with gamma 1 and a fast initial velocity (N = 24,
rho0 = 0.6, rho*0 = 0.65 + 0.1 sin 6 pi x, u0 = 2 sin 2 pi x, mu 0.01, to t = 0.2): auto and
order 2 in f32 at tolerances 1e-4 to 6e-7 (the f32 floor of both is 5.97e-7), each against the
same chain in f64 at order auto, tolerance 1e-11, in the estimate's norm (the largest over
output times of |ln d - ln d_ref| and |u - u_ref| / (1 + |u_ref|)).

    python3 docs/error_estimate/f32_tolerances.py target/release/roughlub"""
import json, os, subprocess, sys, tempfile
import numpy as np

BIN = sys.argv[1] if len(sys.argv) > 1 else "target/release/roughlub"


def scene(timeline, solver):
    return f"""name = "f"
[model]
particles = 24
mu = 0.01
gamma = 1.0
[initial]
rho = "0.6"
velocity = "2*sin(2*pi*x)"
rho_star = "0.65+0.1*sin(6*pi*x)"
[time]
end = 0.2
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
    subprocess.run([BIN, "run", path, "--out", out, "--quiet", "--force"], check=True,
                   capture_output=True)
    m = json.load(open(os.path.join(out, "manifest.json")))
    return m, np.load(os.path.join(out, "gaps.npy")), np.load(os.path.join(out, "velocities.npy"))


with tempfile.TemporaryDirectory() as tmp:
    _, G, V = run(tmp, scene("tolerance = 1e-11", 'order = "auto"'))
    for order in ['"auto"', "2"]:
        for tol in [1e-4, 1e-5, 3e-6, 1e-6, 6e-7]:
            m, g, v = run(tmp, scene(f"tolerance = {tol}", f'order = {order}\nprecision = "f32"'))
            err = max(np.abs(np.log(g) - np.log(G)).max(), (np.abs(v - V) / (1 + np.abs(V))).max())
            mm = m["members"][0]
            print(f"order {order} tolerance {tol:.0e}: error {err:.2e} "
                  f"estimate {float(m['error_estimate']['largest']):.2e} "
                  f"steps {mm['steps_accepted']}+{mm['steps_rejected']}")
