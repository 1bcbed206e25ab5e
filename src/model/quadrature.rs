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

    /// ∫_a^b f by recursive bisection until the rule and its two halves agree to 1e-15 of the
    /// larger of the integral and `scale` (b - a), `scale` being the size of f's values over its
    /// whole domain: profiles that are only Lipschitz (kinks) are integrated to rounding, while
    /// smooth ones stop after the first comparison. The `scale` floor is what lets pieces where
    /// f is far below its usual size stop: there f's rounding, relative to the size of the
    /// terms it is computed from, exceeds 1e-15 of its value (0.5 + 0.4999999 sin(2 pi x) near
    /// its minimum of 1e-7), no bisection brings the halves closer, and before the floor every
    /// piece there bisected to depth 40 (the run never started). At most `MAX_PIECES` pieces a
    /// call, so that no f can make it run for ever.
    pub fn integrate_adaptive(
        &self,
        a: f64,
        b: f64,
        scale: f64,
        f: &mut impl FnMut(f64) -> f64,
    ) -> f64 {
        let whole = self.integrate(a, b, &mut *f);
        let mut pieces = 0;
        self.refine(a, b, whole, f64::INFINITY, scale.abs(), f, 0, &mut pieces)
    }

    #[allow(clippy::too_many_arguments)]
    fn refine(
        &self,
        a: f64,
        b: f64,
        whole: f64,
        parent_difference: f64,
        scale: f64,
        f: &mut impl FnMut(f64) -> f64,
        depth: u32,
        pieces: &mut u32,
    ) -> f64 {
        let mid = 0.5 * (a + b);
        let left = self.integrate(a, mid, &mut *f);
        let right = self.integrate(mid, b, &mut *f);
        *pieces += 2;
        let halves = left + right;
        let size = halves.abs().max(scale * (b - a)).max(1e-300);
        let difference = (halves - whole).abs();
        // Rounding in f itself (sin(200 pi x) has the rounding of its argument, ~1e-13) does not
        // shrink with the piece as an error of the rule does (a kink's by ~4 a bisection): a
        // small difference that did not fall below 0.35 of its parent's is taken as rounding.
        let rounding = difference <= 1e-11 * size && difference > 0.35 * parent_difference;
        if depth >= 40
            || *pieces >= MAX_PIECES
            || difference <= 1e-15 * size
            || rounding
            || mid <= a
            || mid >= b
        {
            return halves;
        }
        self.refine(a, mid, left, difference, scale, f, depth + 1, pieces)
            + self.refine(mid, b, right, difference, scale, f, depth + 1, pieces)
    }
}

/// The most pieces [`GaussLegendre::integrate_adaptive`] integrates in one call (a kink needs
/// about 2 per bisection, ~80 to reach rounding from a panel of 1/4096).
const MAX_PIECES: u32 = 256;

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

    /// A profile far below its usual size (1e-7 at the minimum of 0.5 + 0.4999999 sin 2 pi x)
    /// integrates in a few pieces to within 1e-14 of the scale, against the exact integral; it
    /// used to bisect to depth 40 there. A kink is still integrated to rounding.
    #[test]
    fn small_values_stop_at_the_scale_and_kinks_reach_rounding() {
        let q = GaussLegendre::new(8);
        let mut calls = 0u64;
        let mut f = |x: f64| {
            calls += 1;
            0.5 + 0.4999999 * (2.0 * std::f64::consts::PI * x).sin()
        };
        let (a, b) = (0.75 - 1.0 / 4096.0, 0.75);
        let got = q.integrate_adaptive(a, b, 0.5, &mut f);
        // The exact integral, its difference of cosines as a product (no cancellation).
        let pi = std::f64::consts::PI;
        let want = 0.5 * (b - a) + 0.4999999 / pi * (pi * (a + b)).sin() * (pi * (b - a)).sin();
        assert!(
            (got - want).abs() <= 1e-14 * 0.5 * (b - a),
            "{got} vs {want}"
        );
        assert!(calls <= 8 * 64, "{calls} evaluations");
        let mut kink = |x: f64| (x - 0.3).abs();
        let got = q.integrate_adaptive(0.0, 1.0, 1.0, &mut kink);
        let want = 0.5 * (0.3f64 * 0.3 + 0.7 * 0.7);
        assert!((got - want).abs() <= 4e-16, "{got} vs {want}");
    }
}
