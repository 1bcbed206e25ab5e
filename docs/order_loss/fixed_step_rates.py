"""Observed orders of fixed steps on an N = 200 chain (issue 22, item 1): runs `roughlub run`
at dt = T 2^-k, k = K0..K1-1, and prints the differences of successive runs at t = T (max over
ln d and the velocities) and log2 of their ratios.

    python3 docs/order_loss/fixed_step_rates.py ROUGHLUB --orders 4,6 --jacobian exact \
        [--rho-star "0.7+0.1*sin(6*pi*x)" | --roughness '{ kind = "uniform", spread = 0.1732 }'] \
        [--mu 0.01] [--gamma 2] [--particles 200] [--end 0.3] [--k 4 12]

The chain: rho = 0.7, u0 = 0.5 sin(2 pi x), rho* as given (an expression: a deterministic
roughness) or 0.7 with `[ensemble] roughness` (one member, seed 1). Writes into ./rates_out/."""
import argparse, glob, os, subprocess
import numpy as np

a = argparse.ArgumentParser()
a.add_argument("roughlub")
a.add_argument("--orders", default="4,6")
a.add_argument("--jacobian", default="exact")
a.add_argument("--rho-star", default="0.7")
a.add_argument("--roughness")
a.add_argument("--mu", default="0.01")
a.add_argument("--gamma", default="2.0")
a.add_argument("--particles", default="200")
a.add_argument("--end", type=float, default=0.3)
a.add_argument("--k", type=int, nargs=2, default=[4, 12])
args = a.parse_args()
os.makedirs("rates_out", exist_ok=True)
scene = f"""name = "rates"
[model]
particles = {args.particles}
mu = {args.mu}
gamma = {args.gamma}
[initial]
rho = "0.7"
velocity = "0.5*sin(2*pi*x)"
rho_star = "{args.rho_star}"
[time]
end = {args.end!r}
outputs = 2
dt = DT
[solver]
backend = "cpu"
jacobian = "{args.jacobian}"
order = ORDER
[output]
grid = 50
plots = false
"""
if args.roughness:
    scene += f"[ensemble]\nmembers = 1\nseed = 1\nstore_members = true\nroughness = {args.roughness}\n"

def final_state(order, dt):
    path = "rates_out/scene.toml"
    with open(path, "w") as f:
        f.write(scene.replace("DT", repr(dt)).replace("ORDER", str(order)))
    subprocess.run([args.roughlub, "run", path, "--out", "rates_out/run", "--quiet", "--force"],
                   check=True)
    if args.roughness:
        g = np.load(glob.glob("rates_out/run/members/*_gaps.npy")[0])[0, -1]
        v = np.load(glob.glob("rates_out/run/members/*_velocities.npy")[0])[0, -1]
    else:
        g = np.load("rates_out/run/gaps.npy")[-1, 0]
        v = np.load("rates_out/run/velocities.npy")[-1, 0]
    return np.concatenate([np.log(g), v])

for order in [int(o) for o in args.orders.split(",")]:
    ends = [final_state(order, args.end / 2**k) for k in range(*args.k)]
    diffs = [abs(b - a).max() for a, b in zip(ends, ends[1:])]
    rates = [np.log2(a / b) for a, b in zip(diffs, diffs[1:])]
    print(f"order {order}, {args.jacobian}: differences " + " ".join(f"{d:.1e}" for d in diffs))
    print("    observed orders " + " ".join(f"{r:.2f}" for r in rates), flush=True)
