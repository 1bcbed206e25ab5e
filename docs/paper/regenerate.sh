#!/usr/bin/env bash
# Regenerates docs/paper/: the scenes, figures and numbers of the paper's section 6 (cases 1, 2a,
# 2b, 3 and the gamma sweep) with their convergence checks (N, 2N, 4N and dt, dt/2, dt/4).
#
#   bash docs/paper/regenerate.sh                      # builds with cargo, runs on the CPU
#   bash docs/paper/regenerate.sh path/to/roughlub     # a given binary
#   OUT=out/paper_gpu BACKEND=auto bash docs/paper/regenerate.sh
#
# Run outputs go to $OUT (default out/paper, about 700 MB); unchanged runs found there are reused.
# Needs python3 (3.11+) with numpy. About 3 minutes on 2 cores.
set -euo pipefail
cd "$(dirname "$0")/../.."
if [ $# -ge 1 ]; then
    BIN="$1"
else
    cargo build --release --quiet
    BIN="cargo run --release --quiet --"
fi
python3 -c 'import numpy' 2>/dev/null || { echo "error: needs numpy (pip install numpy)" >&2; exit 2; }
exec python3 docs/paper/paper.py --bin "$BIN" --out "${OUT:-out/paper}" --backend "${BACKEND:-cpu}"
