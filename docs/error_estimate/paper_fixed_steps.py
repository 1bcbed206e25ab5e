"""The fixed-step estimate of the paper's runs (order 2, dt = 1e-3, N = 4000, to t = 3:
docs/paper/scenes/<case>_N.toml) against their error, measured against the same scene at dt/4
(<case>_dt4.toml), in the estimate's norm (chain_runs.error), with 31 outputs of gaps and
velocities in place of the scenes' fields. The estimate adds |T_22 - T_21|, order 1's local
error, over 3000 steps: it falls like dt, as order 1's error does, and stands far above order
2's.

    python3 docs/error_estimate/paper_fixed_steps.py target/release/roughlub   (about 2 minutes)"""
import os, re, sys, tempfile
import numpy as np
from chain_runs import run

BIN = sys.argv[1] if len(sys.argv) > 1 else "target/release/roughlub"
SCENES = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "paper", "scenes")


def paper_run(tmp, case, variant):
    """The paper's scene <case>_<variant> with 31 outputs of gaps and velocities."""
    text = open(os.path.join(SCENES, f"{case}_{variant}.toml")).read()
    text = re.sub(r"outputs = \d+", "outputs = 31", text)
    text = re.sub(r"fields = \[.*\]", 'fields = ["gaps", "velocities"]', text)
    return run(BIN, tmp, text)


with tempfile.TemporaryDirectory() as tmp:
    for case in ["case2a", "case3", "case1_gamma_sweep"]:
        m, g, v = paper_run(tmp, case, "N")
        m4, G, V = paper_run(tmp, case, "dt4")
        for b, member in enumerate(m["members"]):
            error = max(np.abs(np.log(g[:, b]) - np.log(G[:, b])).max(),
                        (np.abs(v[:, b] - V[:, b]) / (1 + np.abs(V[:, b]))).max())
            estimate = max(map(float, member["error_estimate"]))
            estimate4 = max(map(float, m4["members"][b]["error_estimate"]))
            print(f"{case} gamma {member['gamma']}: error {error:.2e}, estimate {estimate:.3g} "
                  f"({estimate / error:.0f} times), at dt/4 {estimate4:.3g}", flush=True)
