//! Gauss–Legendre rules on [-1, 1], computed by Newton iteration on the Legendre polynomial
//! (accurate to rounding for the small orders used here).

#[derive(Debug, Clone, PartialEq)]
pub struct GaussLegendre {
    pub nodes: Vec<f64>,
    pub weights: Vec<f64>,
}

impl GaussLegendre {
    pub fn new(points: usize) -> GaussLegendre {
        assert!(points >= 1, "a quadrature rule needs at least one point");
        let n = points;
        let mut nodes = vec![0.0; n];
        let mut weights = vec![0.0; n];
        for i in 0..n.div_ceil(2) {
            // Tricomi's initial guess, then Newton on P_n.
            let mut x = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
            let mut dp = 0.0;
            for _ in 0..100 {
                let (p, d) = legendre_with_derivative(n, x);
                dp = d;
                let dx = p / d;
                x -= dx;
                if dx.abs() < 1e-16 {
                    break;
                }
            }
            let (_, d) = legendre_with_derivative(n, x);
            dp = if d != 0.0 { d } else { dp };
            let w = 2.0 / ((1.0 - x * x) * dp * dp);
            nodes[i] = -x;
            nodes[n - 1 - i] = x;
            weights[i] = w;
            weights[n - 1 - i] = w;
        }
        if n % 2 == 1 {
            nodes[n / 2] = 0.0;
        }
        GaussLegendre { nodes, weights }
    }

    /// ∫_a^b f(x) dx.
    pub fn integrate(&self, a: f64, b: f64, mut f: impl FnMut(f64) -> f64) -> f64 {
        let half = 0.5 * (b - a);
        let mid = 0.5 * (a + b);
        let mut s = 0.0;
        for (x, w) in self.nodes.iter().zip(&self.weights) {
            s += w * f(mid + half * x);
        }
        s * half
    }

    /// ∫_a^b f by recursive bisection until the rule and its two halves agree to `tol`
    /// (relative to the magnitude of the integral): profiles that are only Lipschitz (kinks) are
    /// integrated to rounding, while smooth ones stop after the first comparison.
    pub fn integrate_adaptive(&self, a: f64, b: f64, f: &mut impl FnMut(f64) -> f64) -> f64 {
        let whole = self.integrate(a, b, &mut *f);
        self.refine(a, b, whole, f, 0)
    }

    fn refine(
        &self,
        a: f64,
        b: f64,
        whole: f64,
        f: &mut impl FnMut(f64) -> f64,
        depth: u32,
    ) -> f64 {
        let mid = 0.5 * (a + b);
        let left = self.integrate(a, mid, &mut *f);
        let right = self.integrate(mid, b, &mut *f);
        let halves = left + right;
        if depth >= 40
            || (halves - whole).abs() <= 1e-15 * halves.abs().max(1e-300)
            || mid <= a
            || mid >= b
        {
            return halves;
        }
        self.refine(a, mid, left, f, depth + 1) + self.refine(mid, b, right, f, depth + 1)
    }
}

fn legendre_with_derivative(n: usize, x: f64) -> (f64, f64) {
    let (mut p0, mut p1) = (1.0, x);
    for k in 2..=n {
        let p2 = ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64;
        p0 = p1;
        p1 = p2;
    }
    let d = n as f64 * (x * p1 - p0) / (x * x - 1.0);
    (p1, d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exact_for_polynomials_up_to_degree_2n_minus_1() {
        for n in 1..=8 {
            let q = GaussLegendre::new(n);
            for deg in 0..(2 * n) {
                let got = q.integrate(0.0, 1.0, |x| x.powi(deg as i32));
                let want = 1.0 / (deg as f64 + 1.0);
                assert!(
                    (got - want).abs() < 1e-14,
                    "n={n} deg={deg}: {got} vs {want}"
                );
            }
        }
    }
}
