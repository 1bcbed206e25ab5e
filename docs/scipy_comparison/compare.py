"""roughlub against scipy's Radau on a realistic chain (issue 22, item 4), per member.

The chain (chain_model.py): N = 200, rho = 0.7, u0 = 0.5 sin(2 pi x), roughness r_i uniform
within +-30 % (so d*_i = r_{i-1} + r_i within +-30 % of the gap), gamma = 2, mu = 0.01, to
t = 0.3, 11 outputs, no forcing; written as a particle file so that both solvers start from the same numbers. The
reference is roughlub at order auto, sequence from_1, tolerance 1e-12 (checked against 1e-11). Both solvers run
on a half-decade tolerance grid; the error is max over outputs of |ln d - ln d_ref| and
max |u - u_ref| / max |u_ref|, as `roughlub accuracy` measures it. roughlub's time is that of
`roughlub run` on a batch of 64 copies of the member (best of 3) divided by 64, three ways: the
solve as the work-precision bench (benches/work_precision.rs) times it (the manifest's
solve_seconds: building the solver and advancing it through the output times), in process (the
manifest's wall_seconds, adding reading the scene and the particle file and writing the
outputs) and as the process's wall time (adding the program's start, ~7 ms); Radau's is one
solve_ivp call with the model's exact sparse Jacobian (best of 3 as well, each call alternating
with one of roughlub's). The three ratios are printed, for
roughlub's default (`[solver] sequence` left out: auto, which for order auto with adaptive steps
in f64 takes rows of 2, 3, 4, ... substeps) and for `[solver] sequence = "from_1"` (rows of 1,
2, 3, ..., the default before 2026-11-30).

    python3 docs/scipy_comparison/compare.py [path/to/roughlub]   (from the repository root)

Writes out/scipy_comparison/ (the chain, the scenes, radau.json, roughlub.json: per sequence,
[tolerance, error, solve, in process, process] per member)."""
import json, os, subprocess, sys, time
import numpy as np
from scipy.integrate import solve_ivp

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import chain_model  # noqa: E402

BIN = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else "target/release/roughlub")
OUT = os.path.abspath("out/scipy_comparison")
os.makedirs(OUT, exist_ok=True)
os.chdir(OUT)

N, MU, GAMMA, END, T = 200, 0.01, 2.0, 0.3, 11
CHAIN = chain_model.chain(N, MU, GAMMA)
EPS, d0, y0, rhs, jac = CHAIN.eps, CHAIN.d0, CHAIN.y0, CHAIN.rhs, CHAIN.jac
chain_model.write_particles(CHAIN, "chain.csv")

def scene(tolerance, batch=False, sequence=None):
    s = f"""name = "scipy_comparison"
[model]
mu = {MU}
gamma = {GAMMA}
radius = {EPS!r}
[initial]
particles = "chain.csv"
[time]
end = {END}
outputs = {T}
tolerance = {tolerance:.4e}
[solver]
order = "auto"
backend = "cpu"
{'sequence = "%s"' % sequence if sequence else ""}
[output]
plots = false
fields = ["gaps", "velocities"]
"""
    if batch:
        s += "[batch]\nmu = [%s]\n" % ", ".join([str(MU)] * 64)
    return s

def run(tolerance, out, batch=False, sequence=None):
    """(the solve's time and the wall time in process, both from the manifest, and the wall time
    of the process)."""
    open("scene.toml", "w").write(scene(tolerance, batch, sequence))
    t0 = time.perf_counter()
    subprocess.run([BIN, "run", "scene.toml", "--out", out, "--quiet"], check=True)
    process = time.perf_counter() - t0
    manifest = json.load(open(os.path.join(out, "manifest.json")))
    return manifest["solve_seconds"], manifest["wall_seconds"], process

run(1e-12, "ref", sequence="from_1")
run(1e-11, "ref11", sequence="from_1")
ref_g = np.load("ref/gaps.npy").reshape(T, N)
ref_u = np.load("ref/velocities.npy").reshape(T, N - 1)

def error(g, v):
    return max(np.abs(np.log(g) - np.log(ref_g)).max(axis=None),
               np.abs(v - ref_u).max() / np.abs(ref_u).max())

print("reference (auto, 1e-12) against 1e-11: %.1e" % error(
    np.load("ref11/gaps.npy").reshape(T, N), np.load("ref11/velocities.npy").reshape(T, N - 1)))

assert np.allclose(ref_g[0], d0, rtol=1e-12), "roughlub's initial gaps differ from the file's"
times = np.linspace(0, END, T)
grid = [10 ** -e for e in np.arange(3, 10.51, 0.5)]
radau, rl, rl2 = [], [], []
def radau_solve(tol):
    atol = np.concatenate((tol * d0, tol * np.ones(N - 1)))
    t0 = time.perf_counter()
    s = solve_ivp(rhs, (0, END), y0, method="Radau", t_eval=times, rtol=tol, atol=atol, jac=jac)
    return s, time.perf_counter() - t0
# Each tolerance's Radau and roughlub runs alternate (best of 3 each), so that a busy spell of
# this shared machine slows both rather than one side of the ratio.
for tol in grid:
    wall_radau = float("inf")
    walls = {seq: [float("inf")] * 3 for seq in ("default", "from_1")}
    for _ in range(3):
        s, w = radau_solve(tol)
        wall_radau = min(wall_radau, w)
        for seq, best in walls.items():
            taken = run(tol, "batch64_" + seq, batch=True,
                        sequence=None if seq == "default" else seq)
            best[:] = [min(b, t / 64) for b, t in zip(best, taken)]
    if s.success:
        radau.append((tol, error(s.y[:N].T, s.y[N:].T), wall_radau))
        print("Radau    rtol %.1e  error %.2e  %.4f s" % radau[-1], flush=True)
    for seq, points in (("default", rl), ("from_1", rl2)):
        g = np.load("batch64_%s/gaps.npy" % seq).reshape(T, 64, N)
        v = np.load("batch64_%s/velocities.npy" % seq).reshape(T, 64, N - 1)
        err = max(error(g[:, b], v[:, b]) for b in range(64))
        points.append((tol, err, *walls[seq]))
        print("roughlub tol  %.1e  error %.2e  %.5f s per member solving (%.5f s in process, "
              "%.5f s with the start)" % points[-1], seq, flush=True)
json.dump(radau, open("radau.json", "w"))
json.dump({"default": rl, "from_1": rl2}, open("roughlub.json", "w"))

def cost_at(points, target, column=2):
    """Least time (that column) among settings whose error is at most target (None if none)."""
    ok = [p[column] for p in points if p[1] <= target]
    return min(ok) if ok else None

def show(value, form):
    return form % value if value else "-"

for seq, points in (("default sequence (auto: from_2 here)", rl), ('sequence = "from_1"', rl2)):
    print("\nroughlub auto, %s" % seq)
    print("error at most | Radau (s) | roughlub solving, per member of 64 (s) | ratio"
          " | in process (s) | ratio | with roughlub's start (s) | ratio")
    for target in (1e-4, 1e-6, 3e-8, 1e-8, 1e-9, 1e-10):
        a = cost_at(radau, target)
        row = ["%.0e" % target, show(a, "%.4f")]
        for column in (2, 3, 4):
            b = cost_at(points, target, column)
            row += [show(b, "%.5f"), show(a and b and a / b, "%.0fx")]
        print(" | ".join(row))
