"""How far adaptive runs' errors and estimates lie from their tolerance, in f64 and f32, and which
runs warn that the tolerance was not met (an estimate above 100 times it): the chain of
f32_tolerances.py (N = 24, gamma 1, u0 = 2 sin 2 pi x, to a gap of 1e-13) and the paper's
cases 1, 2a and 3 as shipped (scenes/), order auto, each against itself in f64 at tolerance
1e-11, in the estimate's norm (chain_runs.error).

    python3 docs/error_estimate/tolerance_factor.py target/release/roughlub"""
import os, re, sys, tempfile
from chain_runs import error, run, scene

BIN = sys.argv[1] if len(sys.argv) > 1 else "target/release/roughlub"
HERE = os.path.dirname(os.path.abspath(__file__))
CHAIN = dict(N=24, mu=0.01, gamma=1.0, rho="0.6", vel="2*sin(2*pi*x)",
             rs="0.65+0.1*sin(6*pi*x)", end=0.2, outputs=7)
TOLERANCES = {"f64": [1e-3, 1e-4, 1e-6, 1e-8, 1e-10], "f32": [1e-2, 1e-3, 1e-4, 3e-5]}


def at(text, tolerance, precision):
    """The scene text with order auto, the CPU, `precision` and adaptive steps at `tolerance`."""
    keep = [l for l in text.splitlines()
            if not re.match(r"\s*(dt|tolerance|order|precision|backend|sequence)\s*=", l)]
    text = "\n".join(keep).replace("[time]", f"[time]\ntolerance = {tolerance}", 1)
    return text.replace("[solver]", f'[solver]\norder = "auto"\nprecision = "{precision}"\n'
                        'backend = "cpu"', 1)


chains = {"N24": scene(CHAIN, "dt = 1e-3", "")}
for case in ["case1", "case2a", "case3"]:
    chains[case] = open(os.path.join(HERE, "..", "..", "scenes", f"{case}.toml")).read()
with tempfile.TemporaryDirectory() as tmp:
    for name, text in chains.items():
        _, G, V = run(BIN, tmp, at(text, 1e-11, "f64"))
        for precision, tolerances in TOLERANCES.items():
            cells = []
            for tol in tolerances:
                m, g, v = run(BIN, tmp, at(text, tol, precision))
                estimate = float(m["error_estimate"]["largest"])
                warns = "warns" if m["error_estimate"].get("warning") else "-"
                cells.append(f"{tol:.0e}: {error(g, v, G, V) / tol:.3g}/{estimate / tol:.3g} {warns}")
            print(f"{name} {precision} (error/estimate over the tolerance): " + " | ".join(cells),
                  flush=True)
