"""f32's error against the tolerance on a chain with gamma 1 and a fast initial velocity (N = 24,
rho0 = 0.6, rho*0 = 0.65 + 0.1 sin 6 pi x, u0 = 2 sin 2 pi x, mu 0.01, to t = 0.2): auto and
order 2 in f32 at tolerances 1e-3 to 3e-5 (the f32 floor of both is 2.63e-5), each against the
same chain in f64 at order auto, tolerance 1e-11, in the estimate's norm (the largest over
output times of |ln d - ln d_ref| and |u - u_ref| / (1 + |u_ref|)).

    python3 docs/error_estimate/f32_tolerances.py target/release/roughlub"""
import sys, tempfile
from chain_runs import error, run, scene

BIN = sys.argv[1] if len(sys.argv) > 1 else "target/release/roughlub"
CHAIN = dict(N=24, mu=0.01, gamma=1.0, rho="0.6", vel="2*sin(2*pi*x)",
             rs="0.65+0.1*sin(6*pi*x)", end=0.2, outputs=7)

with tempfile.TemporaryDirectory() as tmp:
    _, G, V = run(BIN, tmp, scene(CHAIN, "tolerance = 1e-11", 'order = "auto"'))
    for order in ['"auto"', "2"]:
        for tol in [1e-3, 1e-4, 5e-5, 3e-5]:
            m, g, v = run(BIN, tmp, scene(CHAIN, f"tolerance = {tol}",
                                          f'order = {order}\nprecision = "f32"'))
            mm = m["members"][0]
            print(f"order {order} tolerance {tol:.0e}: error {error(g, v, G, V):.2e} "
                  f"estimate {float(m['error_estimate']['largest']):.2e} "
                  f"steps {mm['steps_accepted']}+{mm['steps_rejected']}")
