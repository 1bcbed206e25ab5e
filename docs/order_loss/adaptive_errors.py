"""Error and cost of roughlub's adaptive steps on the chain of docs/scipy_comparison/compare.py
(N = 200, roughness within +-30 %, gamma 2, mu 0.01, to t = 0.3, 11 outputs), per matrix: for
comparing a change of the substep (docs/order_loss/d_form_experiment.patch) with main.

    python3 docs/order_loss/adaptive_errors.py ROUGHLUB [--jacobian exact,frozen,auto]
        [--tolerances 1e-6,3.16e-7,...] [--reference DIR]

Per setting: order auto, the default sequence, a batch of 64 copies; the error as compare.py
measures it (max over outputs of |ln d - ln d_ref| and max |u - u_ref| / max |u_ref|, first
member) against roughlub at order auto, sequence from_1, tolerance 1e-12 (computed once into
out/adaptive_errors/ref, or taken from --reference: build it with main when the binary under
test is an experiment); the wall time per member (the manifest's, best of 3) and the accepted
steps per member."""
import argparse, json, os, subprocess, sys
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..",
                                "scipy_comparison"))
import chain_model  # noqa: E402

a = argparse.ArgumentParser()
a.add_argument("roughlub")
a.add_argument("--jacobian", default="exact,frozen,auto")
a.add_argument("--tolerances", default="1e-6,3.16e-7,1e-7,3.16e-8,1e-8,3.16e-9,1e-9,1e-10")
a.add_argument("--reference", help="a directory with gaps.npy and velocities.npy of the reference")
args = a.parse_args()
BIN = os.path.abspath(args.roughlub)
REF = os.path.abspath(args.reference) if args.reference else None
os.makedirs("out/adaptive_errors", exist_ok=True)
os.chdir("out/adaptive_errors")

# compare.py's chain, the same numbers.
N, MU, GAMMA, END, T = 200, 0.01, 2.0, 0.3, 11
CHAIN = chain_model.chain(N, MU, GAMMA)
EPS = CHAIN.eps
chain_model.write_particles(CHAIN, "chain.csv")


def run(out, tolerance, jacobian=None, sequence=None, batch=64):
    lines = [f'name = "adaptive_errors"', "[model]", f"mu = {MU}", f"gamma = {GAMMA}",
             f"radius = {EPS!r}", "[initial]", 'particles = "chain.csv"', "[time]",
             f"end = {END}", f"outputs = {T}", f"tolerance = {tolerance:.4e}", "[solver]",
             'order = "auto"', 'backend = "cpu"', "[output]", "plots = false",
             'fields = ["gaps", "velocities"]']
    at = lines.index("[output]")
    lines[at:at] = [f'jacobian = "{jacobian}"'] * bool(jacobian) + \
        [f'sequence = "{sequence}"'] * bool(sequence)
    if batch > 1:
        lines += ["[batch]", "mu = [%s]" % ", ".join([str(MU)] * batch)]
    open("scene.toml", "w").write("\n".join(lines) + "\n")
    subprocess.run([BIN, "run", "scene.toml", "--out", out, "--quiet", "--force"], check=True)
    return json.load(open(os.path.join(out, "manifest.json")))


if REF is None:
    REF = "ref"
    run(REF, 1e-12, sequence="from_1", batch=1)
ref_g = np.load(os.path.join(REF, "gaps.npy")).reshape(T, N)
ref_u = np.load(os.path.join(REF, "velocities.npy")).reshape(T, N - 1)
for jacobian in args.jacobian.split(","):
    for tolerance in [float(t) for t in args.tolerances.split(",")]:
        best = float("inf")
        for _ in range(3):
            m = run("batch", tolerance, jacobian)
            best = min(best, m["wall_seconds"] / 64)
        g = np.load("batch/gaps.npy").reshape(T, 64, N)[:, 0]
        v = np.load("batch/velocities.npy").reshape(T, 64, N - 1)[:, 0]
        err = max(np.abs(np.log(g) - np.log(ref_g)).max(),
                  np.abs(v - ref_u).max() / np.abs(ref_u).max())
        print(f"jacobian {jacobian:6s} tolerance {tolerance:.2e}  error {err:.2e}  "
              f"{best * 1e3:.3f} ms per member  {m['steps_accepted_total'] // 64} steps", flush=True)
