//! A chain of particles as the solvers see it: gaps and velocities (never positions; DESIGN.md
//! §2), with the optional critical distances and cluster bonds.

/// One chain of particles 0..N; particles 0 and N are fixed at x = 0 and x = 1.
#[derive(Debug, Clone, PartialEq)]
pub struct Chain {
    /// Particle radius.
    pub eps: f64,
    /// d_1..d_N (length N): d_i = q_i - q_{i-1} - 2 eps.
    pub gaps: Vec<f64>,
    /// u_1..u_{N-1} (length N-1); u_0 = u_N = 0.
    pub velocities: Vec<f64>,
    /// d*_1..d*_N when the model has roughness (repulsion); `None` means no repulsion term.
    pub dstar: Option<Vec<f64>>,
    /// Gaps that are zero at t = 0 (Appendix A clusters); `None` when there are none.
    pub bonded: Option<Vec<bool>>,
}

impl Chain {
    pub fn particles(&self) -> usize {
        self.gaps.len()
    }

    /// Positions q_0..q_N rebuilt from the gaps (for output and forcing only).
    pub fn positions(&self) -> Vec<f64> {
        positions_from_gaps(&self.gaps, self.eps)
    }
}

pub fn positions_from_gaps(gaps: &[f64], eps: f64) -> Vec<f64> {
    let mut q = Vec::with_capacity(gaps.len() + 1);
    let mut x = 0.0;
    q.push(0.0);
    for d in gaps {
        x += d + 2.0 * eps;
        q.push(x);
    }
    q
}

pub use roughlub_kernels::stored_gap;
