//! exp and ln as `shaders/f64_math.wgsl` computes them (`exp_f64`, `log_f64`: fdlibm's e_exp.c
//! and e_log.c), operation for operation, so that the CPU step and the f64 GPU kernel round
//! alike. The step's gap update is e^{h r} every step; with the libm exp the two backends differ
//! by an ulp now and then, which hard collisions amplify to 1e-6 over a run. Keep in sync with
//! the WGSL (the constants carry the same names without the `F64M_` prefix; fdlibm's digits as
//! published).
#![allow(clippy::excessive_precision)]

const LN2_HI: f64 = 6.931_471_803_691_238_164_90e-1;
const LN2_LO: f64 = 1.908_214_929_270_587_700_02e-10;
const INV_LN2: f64 = std::f64::consts::LOG2_E;
const EXP_OVER: f64 = 7.097_827_128_933_839_730_96e2;
const EXP_UNDER: f64 = -7.451_332_191_019_411_084_20e2;
const SQRT2: f64 = std::f64::consts::SQRT_2;
const P1: f64 = 1.666_666_666_666_660_190_37e-1;
const P2: f64 = -2.777_777_777_701_559_338_42e-3;
const P3: f64 = 6.613_756_321_437_934_361_17e-5;
const P4: f64 = -1.653_390_220_546_525_153_90e-6;
const P5: f64 = 4.138_136_797_057_238_460_39e-8;
const LG1: f64 = 6.666_666_666_666_735_130e-1;
const LG2: f64 = 3.999_999_999_940_941_908e-1;
const LG3: f64 = 2.857_142_874_366_239_149e-1;
const LG4: f64 = 2.222_219_843_214_978_396e-1;
const LG5: f64 = 1.818_357_216_161_805_012e-1;
const LG6: f64 = 1.531_383_769_920_937_332e-1;
const LG7: f64 = 1.479_819_860_511_658_591e-1;

/// 2^k for k in the normal range (exact).
#[inline(always)]
fn two_to(k: i32) -> f64 {
    f64::from_bits(((k + 1023) as u64) << 52)
}

/// `f64m_scale2`: y 2^k in two exact power-of-two factors.
#[inline(always)]
fn scale2(y: f64, k: i32) -> f64 {
    let k1 = k >> 1;
    let k2 = k - k1;
    y * two_to(k1) * two_to(k2)
}

/// `exp_f64` (= `f64m_exp_dd(x, 0)`).
#[inline(always)]
pub fn exp(x: f64) -> f64 {
    if x > EXP_OVER {
        return f64::INFINITY;
    }
    if x < EXP_UNDER {
        return 0.0;
    }
    if x.is_nan() {
        return x;
    }
    let kf = (x * INV_LN2 + 0.5).floor();
    let hi = x - kf * LN2_HI;
    let lo = kf * LN2_LO - 0.0;
    let r = hi - lo;
    let t = r * r;
    let c = r - t * (P1 + t * (P2 + t * (P3 + t * (P4 + t * P5))));
    let y = 1.0 - ((lo - (r * c) / (2.0 - c)) - hi);
    scale2(y, kf as i32)
}

/// floor(y) for |y| < 2^51 without a libm call or a branch (baseline x86-64 has no rounding
/// instruction, and a call would keep the lane loops out of SIMD registers).
#[inline(always)]
fn floor_in_range(y: f64) -> f64 {
    const ROUND: f64 = 6_755_399_441_055_744.0; // 1.5 * 2^52: adding it rounds to an integer
    let r = (y + ROUND) - ROUND;
    if r > y {
        r - 1.0
    } else {
        r
    }
}

/// [`exp`] for x in [-700, 700], bit for bit, without branches (the back sweep's gap update).
/// 2^k is built from the bits of k + 1023 + 2^52, which holds k + 1023 in its low bits.
#[inline(always)]
pub fn exp_in_range(x: f64) -> f64 {
    let kf = floor_in_range(x * INV_LN2 + 0.5);
    let hi = x - kf * LN2_HI;
    let lo = kf * LN2_LO - 0.0;
    let r = hi - lo;
    let t = r * r;
    let c = r - t * (P1 + t * (P2 + t * (P3 + t * (P4 + t * P5))));
    let y = 1.0 - ((lo - (r * c) / (2.0 - c)) - hi);
    let biased = (kf + (1023.0 + 4_503_599_627_370_496.0)).to_bits();
    y * f64::from_bits(biased << 52)
}

/// `two_sum_f64`: (s, e) with s = a + b rounded and e = a + b - s exactly (Knuth's TwoSum, no
/// condition on the sizes of a and b). Also the step control's time (`control::StepControl`) and
/// the moments' double-double mean (`roughlub::stats`).
#[inline(always)]
pub fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    let bb = s - a;
    let e = (a - (s - bb)) + (b - bb);
    (s, e)
}

/// `f64m_split`.
#[inline(always)]
fn split(a: f64) -> (f64, f64) {
    let c = 134_217_729.0 * a;
    let hi = c - (c - a);
    (hi, a - hi)
}

/// `two_prod_f64` (Dekker, no fma).
#[inline(always)]
fn two_prod(a: f64, b: f64) -> (f64, f64) {
    let p = a * b;
    let (xh, xl) = split(a);
    let (yh, yl) = split(b);
    let e = (((xh * yh - p) + xh * yl) + xl * yh) + xl * yl;
    (p, e)
}

/// `f64m_frexp`: x = m 2^k with m in [1, 2), for finite x > 0 (the same exact scalings; any
/// order of exact power-of-two scalings gives the same m and k).
#[inline(always)]
fn frexp(x: f64) -> (f64, f64) {
    let mut m = x;
    let mut k = 0.0;
    if m < f64::MIN_POSITIVE {
        m *= two_to(54);
        k = -54.0;
    }
    let e = ((m.to_bits() >> 52) & 0x7ff) as i32 - 1023;
    (m * two_to(-e), k + e as f64)
}

/// `log_f64`: ln x, ~1 ulp (ln 0 = -inf, ln of a negative or NaN = NaN).
pub fn ln(x: f64) -> f64 {
    if x.is_nan() || x < 0.0 {
        return f64::NAN;
    }
    if x == 0.0 {
        return f64::NEG_INFINITY;
    }
    if x == f64::INFINITY {
        return x;
    }
    let (mut m, mut kf) = frexp(x);
    if m > SQRT2 {
        m *= 0.5;
        kf += 1.0;
    }
    let f = m - 1.0;
    let s = f / (2.0 + f);
    let z = s * s;
    let w = z * z;
    let t1 = w * (LG2 + w * (LG4 + w * LG6));
    let t2 = z * (LG1 + w * (LG3 + w * (LG5 + w * LG7)));
    let r = t2 + t1;
    let hf = 0.5 * f;
    let (hfsq, hfsq_lo) = two_prod(hf, f);
    let tail = s * (hfsq + r);
    let a = two_sum(kf * LN2_HI, f);
    let b = two_sum(a.0, -hfsq);
    let lo = a.1 + b.1 + ((kf * LN2_LO - hfsq_lo) + tail);
    let h = b.0 + lo;
    h + (lo - (h - b.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Within 1 ulp of the platform's correctly rounded-ish libm over the ranges the step uses.
    #[test]
    fn exp_and_ln_agree_with_libm_to_an_ulp() {
        let mut x = -740.0f64;
        while x < 709.0 {
            let (a, b) = (exp(x), x.exp());
            assert!(
                (a - b).abs() <= 1.5 * f64::EPSILON * b,
                "exp({x}) = {a} vs {b}"
            );
            x += 0.137;
        }
        for &x in &[
            1e-300, 1e-250, 1e-20, 0.001, 0.5, 0.7, 1.0, 1.0000001, 2.0, 1e10, 1e300,
        ] {
            let (a, b) = (ln(x), x.ln());
            assert!(
                (a - b).abs() <= 1.5 * f64::EPSILON * b.abs().max(f64::MIN_POSITIVE),
                "ln({x}) = {a} vs {b}"
            );
        }
        assert_eq!(exp(0.0), 1.0);
        let mut x = -700.0f64;
        while x <= 700.0 {
            assert_eq!(
                exp_in_range(x).to_bits(),
                exp(x).to_bits(),
                "exp_in_range({x})"
            );
            x += 0.0731;
        }
        for x in [
            -700.0,
            -0.5 * std::f64::consts::LN_2,
            0.0,
            1e-300,
            -1e-17,
            700.0,
        ] {
            assert_eq!(
                exp_in_range(x).to_bits(),
                exp(x).to_bits(),
                "exp_in_range({x})"
            );
        }
        assert_eq!(ln(1.0), 0.0);
    }
}
