// f64 elementary functions for WGSL compute kernels (needs wgpu::Features::SHADER_F64).
//
// Why this file exists: naga accepts sin/cos/exp/log/pow on f64, but the Vulkan backend lowers
// them to GLSL.std.450 instructions that are only defined for 16/32-bit floats; on lavapipe
// (wgpu 30) they return garbage (sin(4.0) -> 0, exp(4.0) -> 9e-315, log(4.0) -> -88). Only the
// correctly rounded f64 core (+ - * / sqrt floor abs min max select) and ldexp (exact scaling by
// 2^k) are used below. Two further traps, both measured on lavapipe:
//  - frexp(f64) cannot be used: naga types its exponent as i64, which needs SHADER_INT64;
//  - WGSL `fma` on f64 is NOT fused (it is evaluated as a*b + c with two roundings), and the
//    driver compiler (Mesa NIR) applies value-unsafe algebra to float ops that naga does not mark
//    NoContraction (it never does): (a + b) - a -> b, a - a -> 0, ... This silently turns
//    error-free transformations (TwoSum, Fast2Sum, fma residuals, Kahan sums) into zeros.
//    `opaque_f64` below hides a value from that algebra; `two_sum_f64` and `two_prod_f64`
//    (Dekker, no fma) use it and are exact on such drivers.

// The algorithms are ports of FreeBSD msun / fdlibm (e_exp.c, s_expm1.c, e_log.c, k_sin.c,
// k_cos.c, e_rem_pio2.c), whose polynomial constants are written here in decimal with enough
// digits to round to the exact fdlibm bit patterns. Accuracy against Rust's std f64 functions is
// checked by tests/gpu_f64_math.rs (measured on lavapipe: <= 1 ulp for exp/expm1/log/sin/cos,
// <= 2 ulp for tan/tanh, <= 3 ulp for pow).
//
// The file has no entry point and no bindings: prepend (concatenate) it to a kernel's source.
// Public functions: exp_f64, expm1_f64, log_f64, sin_f64, cos_f64, tan_f64, tanh_f64,
// pow_f64, and the building blocks opaque_f64, two_sum_f64, two_prod_f64. Private helpers and
// constants start with `f64m_`/`F64M_`.
//
// Compilers may also contract a*b + c into an fma; the algorithms stay correct when that
// happens: the range-reduction and Dekker partial products are exact, and the error-free
// transformations go through opaque_f64.

// ---------------------------------------------------------------------------------------------
// Constants (fdlibm bit patterns in comments).

const F64M_LN2_HI: f64 = 6.93147180369123816490e-01; // 0x3fe62e42fee00000: 32 significant bits
const F64M_LN2_LO: f64 = 1.90821492927058770002e-10; // 0x3dea39ef35793c76: ln2 - LN2_HI
const F64M_INV_LN2: f64 = 1.44269504088896338700e+00; // 0x3ff71547652b82fe
const F64M_HALF_LN2: f64 = 3.46573590279972654709e-01; // 0.5 * ln2
const F64M_EXP_OVER: f64 = 7.09782712893383973096e+02; // 0x40862e42fefa39ef: ln(DBL_MAX)
const F64M_EXP_UNDER: f64 = -7.45133219101941108420e+02; // 0xc0874910d52d3051: ln(min subnormal)
const F64M_MAX: f64 = 1.7976931348623157e308; // DBL_MAX
const F64M_SQRT2: f64 = 1.41421356237309504880;

// exp: Remez polynomial for R(r^2) ~ r*(e^r+1)/(e^r-1) on [0, 0.347^2] (|error| < 2^-59).
const F64M_P1: f64 = 1.66666666666666019037e-01; // 0x3fc555555555553e
const F64M_P2: f64 = -2.77777777770155933842e-03; // 0xbf66c16c16bebd93
const F64M_P3: f64 = 6.61375632143793436117e-05; // 0x3f11566aaf25de2c
const F64M_P4: f64 = -1.65339022054652515390e-06; // 0xbebbbd41c5d26bf1
const F64M_P5: f64 = 4.13813679705723846039e-08; // 0x3e66376972bea4d0

// log: Remez polynomial for (log(1+f) - 2s)/s, s = f/(2+f) (|error| < 2^-58.45).
const F64M_LG1: f64 = 6.666666666666735130e-01; // 0x3fe5555555555593
const F64M_LG2: f64 = 3.999999999940941908e-01; // 0x3fd999999997fa04
const F64M_LG3: f64 = 2.857142874366239149e-01; // 0x3fd2492494229359
const F64M_LG4: f64 = 2.222219843214978396e-01; // 0x3fcc71c51d8e78af
const F64M_LG5: f64 = 1.818357216161805012e-01; // 0x3fc7466496cb03de
const F64M_LG6: f64 = 1.531383769920937332e-01; // 0x3fc39a09d078c69f
const F64M_LG7: f64 = 1.479819860511658591e-01; // 0x3fc2f112df3e5244

// expm1: Remez polynomial for the rational kernel of s_expm1.c (|error| < 2^-61).
const F64M_Q1: f64 = -3.33333333333331316428e-02; // 0xbfa11111111110f4
const F64M_Q2: f64 = 1.58730158725481460165e-03; // 0x3f5a01a019fe5585
const F64M_Q3: f64 = -7.93650757867487942473e-05; // 0xbf14ce199eaadbb7
const F64M_Q4: f64 = 4.00821782732936239552e-06; // 0x3ed0cfca86e65239
const F64M_Q5: f64 = -2.01099218183624371326e-07; // 0xbe8afdb76e09c32d

// pi/2 reduction: pi/2 = PIO2_1 + PIO2_2 + PIO2_3 + PIO2_3T; PIO2_1..3 have 33 significant bits
// so that n * PIO2_i is exact for |n| < 2^20.
const F64M_INV_PIO2: f64 = 6.36619772367581382433e-01; // 0x3fe45f306dc9c883
const F64M_PIO2_1: f64 = 1.57079632673412561417e+00; // 0x3ff921fb54400000
const F64M_PIO2_2: f64 = 6.07710050630396597660e-11; // 0x3dd0b4611a600000
const F64M_PIO2_3: f64 = 2.02226624871116645580e-21; // 0x3ba3198a2e000000
const F64M_PIO2_3T: f64 = 8.47842766036889956997e-32; // 0x397b839a252049c1

// sin kernel on [-pi/4, pi/4]: sin(x) ~ x + S1 x^3 + ... + S6 x^13 (|error| < 2^-58).
const F64M_S1: f64 = -1.66666666666666324348e-01; // 0xbfc5555555555549
const F64M_S2: f64 = 8.33333333332248946124e-03; // 0x3f8111111110f8a6
const F64M_S3: f64 = -1.98412698298579493134e-04; // 0xbf2a01a019c161d5
const F64M_S4: f64 = 2.75573137070700676789e-06; // 0x3ec71de357b1fe7d
const F64M_S5: f64 = -2.50507602534068634195e-08; // 0xbe5ae5e68a2b9ceb
const F64M_S6: f64 = 1.58969099521155010221e-10; // 0x3de5d93a5acfd57c

// cos kernel on [-pi/4, pi/4]: cos(x) ~ 1 - x^2/2 + C1 x^4 + ... + C6 x^14 (|error| < 2^-58).
const F64M_C1: f64 = 4.16666666666666019037e-02; // 0x3fa555555555554c
const F64M_C2: f64 = -1.38888888888741095749e-03; // 0xbf56c16c16c15177
const F64M_C3: f64 = 2.48015872894767294178e-05; // 0x3efa01a019cb1590
const F64M_C4: f64 = -2.75573143513906633035e-07; // 0xbe927e4f809c52ad
const F64M_C5: f64 = 2.08757232129817482790e-09; // 0x3e21ee9ebdb4b1c4
const F64M_C6: f64 = -1.13596475577881948265e-11; // 0xbda8fae9be8838d4

// ---------------------------------------------------------------------------------------------
// Helpers.

// y * 2^k for k in [-1076, 1025], in two exact power-of-two factors so that neither 2^k1 nor
// 2^k2 leaves the normal range (y in [0.5, 2] here); only the final product rounds.
fn f64m_scale2(y: f64, k: i32) -> f64 {
    let k1 = k >> 1u;
    let k2 = k - k1;
    return y * ldexp(f64(1.0), k1) * ldexp(f64(1.0), k2);
}

// exp(x + xt) for |xt| <= ulp(x) (xt carries the low part of a double-double argument).
// Reduction x = k ln2 + hi - lo with hi exact (k*LN2_HI is exact for |k| < 2^21 and the
// difference cancels), then exp(r) = 1 + r + r c(r) / (2 - c(r)) (fdlibm e_exp.c).
fn f64m_exp_dd(x: f64, xt: f64) -> f64 {
    if (x > F64M_EXP_OVER) {
        return x * 1e308; // overflow to +inf at run time (a constant inf is rejected by naga)
    }
    if (x < F64M_EXP_UNDER) {
        return f64(0.0);
    }
    if (x != x) {
        return x; // NaN
    }
    let kf = floor(x * F64M_INV_LN2 + 0.5);
    let hi = x - kf * F64M_LN2_HI;
    let lo = kf * F64M_LN2_LO - xt;
    let r = hi - lo;
    let t = r * r;
    let c = r - t * (F64M_P1 + t * (F64M_P2 + t * (F64M_P3 + t * (F64M_P4 + t * F64M_P5))));
    // 1 + (hi - lo) + r c / (2 - c), summed so that hi and lo enter unrounded.
    let y = 1.0 - ((lo - (r * c) / (2.0 - c)) - hi);
    return f64m_scale2(y, i32(kf));
}

// The value x, hidden from the driver's algebraic simplifier: the comparison is data-dependent
// (false only for NaN, where -x is NaN too), so the compiler cannot prove that the result equals
// x and cannot cancel it against the expression x came from. Costs a compare and a select.
fn opaque_f64(x: f64) -> f64 {
    return select(-x, x, x == x);
}

// Knuth's TwoSum: s + e == a + b exactly (s = a + b rounded), for finite a, b. The opaque steps
// keep the compiler from folding (a + b) - a to b, which would make e = 0.
fn two_sum_f64(a: f64, b: f64) -> vec2<f64> {
    let s = opaque_f64(a + b);
    let bb = opaque_f64(s - a);
    let e = (a - (s - bb)) + (b - bb);
    return vec2<f64>(s, e);
}

// Veltkamp split: a = hi + lo with hi holding the top 26 bits; |a| < 2^996.
fn f64m_split(a: f64) -> vec2<f64> {
    let c = opaque_f64(134217729.0 * a); // 2^27 + 1
    let hi = opaque_f64(c - opaque_f64(c - a));
    return vec2<f64>(hi, a - hi);
}

// Dekker's TwoProduct without fma (WGSL fma on f64 is not fused on every device): p + e == a * b
// exactly (p = a * b rounded), for |a|, |b| < 2^996 and no underflow in the partial products.
fn two_prod_f64(a: f64, b: f64) -> vec2<f64> {
    let p = opaque_f64(a * b);
    let x = f64m_split(a);
    let y = f64m_split(b);
    let e = (((x.x * y.x - p) + x.x * y.y) + x.y * y.x) + x.y * y.y;
    return vec2<f64>(p, e);
}

// x = m 2^k with m in [1, 2), for finite x > 0; returns vec2(m, k). Binary search on the exponent
// with exact power-of-two scalings: frexp cannot be used because naga types the exponent of
// frexp(f64) as i64, which needs SHADER_INT64, and f64 -> vec2<u32> bitcasts are not allowed.
fn f64m_frexp(x: f64) -> vec2<f64> {
    var m = x;
    var k: f64 = 0.0;
    if (m < 0x1p-1022) {
        m = m * 0x1p54; // subnormal (when the device keeps them): make it normal first
        k = -54.0;
    }
    if (m >= 0x1p512) { m = m * 0x1p-512; k = k + 512.0; }
    if (m >= 0x1p256) { m = m * 0x1p-256; k = k + 256.0; }
    if (m >= 0x1p128) { m = m * 0x1p-128; k = k + 128.0; }
    if (m >= 0x1p64) { m = m * 0x1p-64; k = k + 64.0; }
    if (m >= 0x1p32) { m = m * 0x1p-32; k = k + 32.0; }
    if (m >= 0x1p16) { m = m * 0x1p-16; k = k + 16.0; }
    if (m >= 0x1p8) { m = m * 0x1p-8; k = k + 8.0; }
    if (m >= 0x1p4) { m = m * 0x1p-4; k = k + 4.0; }
    if (m >= 0x1p2) { m = m * 0x1p-2; k = k + 2.0; }
    if (m >= 0x1p1) { m = m * 0x1p-1; k = k + 1.0; }
    // m < 2^(1-s) <=> m 2^s < 2: greedy binary decomposition of the missing exponent
    if (m < 0x1p-511) { m = m * 0x1p512; k = k - 512.0; }
    if (m < 0x1p-255) { m = m * 0x1p256; k = k - 256.0; }
    if (m < 0x1p-127) { m = m * 0x1p128; k = k - 128.0; }
    if (m < 0x1p-63) { m = m * 0x1p64; k = k - 64.0; }
    if (m < 0x1p-31) { m = m * 0x1p32; k = k - 32.0; }
    if (m < 0x1p-15) { m = m * 0x1p16; k = k - 16.0; }
    if (m < 0x1p-7) { m = m * 0x1p8; k = k - 8.0; }
    if (m < 0x1p-3) { m = m * 0x1p4; k = k - 4.0; }
    if (m < 0x1p-1) { m = m * 0x1p2; k = k - 2.0; }
    if (m < 0x1p0) { m = m * 0x1p1; k = k - 1.0; }
    return vec2<f64>(m, k);
}

// log(x) as a double-double (hi, lo), about 2^-60 relative, for finite x > 0 (normal).
// x = 2^k m with m in (sqrt(1/2), sqrt(2)], f = m - 1 (exact), s = f / (2 + f);
// log(1 + f) = f - f^2/2 + s (f^2/2 + R(s^2))   (fdlibm e_log.c),
// with k ln2 + f - f^2/2 summed in double-double (f^2/2 split exactly by two_prod_f64) so that
// pow can use the ~60-bit result.
fn f64m_log_dd(x: f64) -> vec2<f64> {
    let fr = f64m_frexp(x);
    var m = fr.x; // in [1, 2)
    var kf = fr.y;
    if (m > F64M_SQRT2) {
        m = m * 0.5;
        kf = kf + 1.0;
    }
    let f = m - 1.0;
    let s = f / (2.0 + f);
    let z = s * s;
    let w = z * z;
    let t1 = w * (F64M_LG2 + w * (F64M_LG4 + w * F64M_LG6));
    let t2 = z * (F64M_LG1 + w * (F64M_LG3 + w * (F64M_LG5 + w * F64M_LG7)));
    let r = t2 + t1;
    let hf = 0.5 * f;
    let hfsq2 = two_prod_f64(hf, f); // f^2/2 exactly, as hi + lo
    let hfsq = hfsq2.x;
    let hfsq_lo = hfsq2.y;
    let tail = s * (hfsq + r);
    let a = two_sum_f64(kf * F64M_LN2_HI, f); // k*LN2_HI is exact
    let b = two_sum_f64(a.x, -hfsq);
    let lo = a.y + b.y + ((kf * F64M_LN2_LO - hfsq_lo) + tail);
    let h = opaque_f64(b.x + lo);
    return vec2<f64>(h, lo - (h - b.x)); // Fast2Sum
}

// x reduced modulo pi/2: returns (y0, y1, n mod 4) with x = n pi/2 + y0 + y1, |y0| <~ pi/4.
// Cody-Waite with pi/2 = PIO2_1 + PIO2_2 + PIO2_3 + PIO2_3T: x - n PIO2_1 is exact (n PIO2_1
// is exact and cancels against x for |x| < 2^20), the next two exact products are subtracted in
// double-double (TwoSum), so y0 + y1 carries ~100 correct bits even when x is close to a
// multiple of pi/2. Accurate for |x| < 2^19 pi/2 (~8.2e5); degrades gracefully beyond.
fn f64m_rem_pio2(x: f64) -> vec3<f64> {
    let n = floor(x * F64M_INV_PIO2 + 0.5);
    let r1 = x - n * F64M_PIO2_1; // exact
    let a = two_sum_f64(r1, -(n * F64M_PIO2_2)); // n*PIO2_2 exact
    let b = two_sum_f64(a.x, -(n * F64M_PIO2_3)); // n*PIO2_3 exact
    let lo = (a.y + b.y) - n * F64M_PIO2_3T;
    let y0 = opaque_f64(b.x + lo);
    let y1 = lo - (y0 - b.x); // Fast2Sum
    // quadrant computed in f64: exact, and no integer overflow for huge n
    let q = n - 4.0 * floor(n * 0.25);
    return vec3<f64>(y0, y1, q);
}

// sin(x + y) on [-pi/4, pi/4], |y| <= ulp(x)/2 (fdlibm k_sin.c).
fn f64m_ksin(x: f64, y: f64) -> f64 {
    let z = x * x;
    let w = z * z;
    let r = F64M_S2 + z * (F64M_S3 + z * F64M_S4) + z * w * (F64M_S5 + z * F64M_S6);
    let v = z * x;
    return x - ((z * (0.5 * y - v * r) - y) - v * F64M_S1);
}

// cos(x + y) on [-pi/4, pi/4] (FreeBSD k_cos.c): 1 - x^2/2 evaluated with its rounding error
// recovered, so the result is within ~1 ulp even where x^2/2 is large.
fn f64m_kcos(x: f64, y: f64) -> f64 {
    let z = x * x;
    let w = z * z;
    let r = z * (F64M_C1 + z * (F64M_C2 + z * F64M_C3))
        + w * w * (F64M_C4 + z * (F64M_C5 + z * F64M_C6));
    let hz = 0.5 * z;
    let v = opaque_f64(1.0 - hz);
    return v + (((1.0 - v) - hz) + (z * r - x * y)); // (1 - v) - hz: rounding error of v
}

// ---------------------------------------------------------------------------------------------
// Public functions.

// e^x. Overflows to +inf above ln(DBL_MAX) ~ 709.78, 0 below ~ -745.13 (results below 2^-1022
// are subnormal and may be flushed to 0 by the device). ~1 ulp.
fn exp_f64(x: f64) -> f64 {
    return f64m_exp_dd(x, f64(0.0));
}

// e^x - 1, accurate also for tiny |x| (fdlibm s_expm1.c). ~1 ulp.
fn expm1_f64(x: f64) -> f64 {
    if (x > F64M_EXP_OVER) {
        return x * 1e308; // +inf
    }
    if (x < -38.816242111356935) {
        return f64(-1.0); // x < -56 ln2: e^x below half an ulp of 1
    }
    if (x != x) {
        return x;
    }
    let ax = abs(x);
    if (ax < 5.551115123125783e-17) {
        return x; // |x| < 2^-54
    }
    var k: i32 = 0;
    var xr = x;
    var c = f64(0.0);
    if (ax > F64M_HALF_LN2) {
        // x = k ln2 + xr + c with xr + c carried in double-double
        let kf = floor(x * F64M_INV_LN2 + 0.5);
        k = i32(kf);
        let hi = x - kf * F64M_LN2_HI;
        let lo = kf * F64M_LN2_LO;
        xr = opaque_f64(hi - lo);
        c = (hi - xr) - lo; // rounding error of xr
    }
    let hfx = 0.5 * xr;
    let hxs = xr * hfx;
    let r1 = 1.0
        + hxs * (F64M_Q1 + hxs * (F64M_Q2 + hxs * (F64M_Q3 + hxs * (F64M_Q4 + hxs * F64M_Q5))));
    let t = 3.0 - r1 * hfx;
    var e = hxs * ((r1 - t) / (6.0 - xr * t));
    if (k == 0) {
        return xr - (xr * e - hxs);
    }
    e = xr * (e - c) - c;
    e = e - hxs;
    if (k == -1) {
        return 0.5 * (xr - e) - 0.5;
    }
    if (k == 1) {
        if (xr < -0.25) {
            return -2.0 * (e - (xr + 0.5));
        }
        return 1.0 + 2.0 * (xr - e);
    }
    if (k <= -2 || k > 56) {
        // the -1 is below the rounding of 2^k (1 + ...) or dominates it exactly
        return f64m_scale2(1.0 - (e - xr), k) - 1.0;
    }
    if (k < 20) {
        // 2^k (1 - 2^-k + xr - e): 1 - 2^-k is exact
        let tk = 1.0 - ldexp(f64(1.0), -k);
        return f64m_scale2(tk - (e - xr), k);
    }
    let tk = ldexp(f64(1.0), -k);
    return f64m_scale2((xr - (e + tk)) + 1.0, k);
}

// Natural logarithm. log(0) = -inf, log(x < 0) = NaN, log(+inf) = +inf. ~1 ulp on normal x
// (subnormal x may be flushed to 0 by the device).
fn log_f64(x: f64) -> f64 {
    if (!(x > 0.0)) {
        if (x == 0.0) {
            return -1.0 / abs(x); // -inf at run time
        }
        return (x - x) / (x - x); // NaN for x < 0 and for NaN
    }
    if (x > F64M_MAX) {
        return x; // +inf
    }
    let l = f64m_log_dd(x);
    return l.x + l.y;
}

// sin(x); ~1 ulp for |x| < 8e5 (see f64m_rem_pio2), relative accuracy kept near the zeros.
fn sin_f64(x: f64) -> f64 {
    let red = f64m_rem_pio2(x);
    let s = f64m_ksin(red.x, red.y);
    let c = f64m_kcos(red.x, red.y);
    let q = red.z;
    if (q == 0.0) {
        return s;
    }
    if (q == 1.0) {
        return c;
    }
    if (q == 2.0) {
        return -s;
    }
    return -c;
}

// cos(x); ~1 ulp for |x| < 8e5.
fn cos_f64(x: f64) -> f64 {
    let red = f64m_rem_pio2(x);
    let s = f64m_ksin(red.x, red.y);
    let c = f64m_kcos(red.x, red.y);
    let q = red.z;
    if (q == 0.0) {
        return c;
    }
    if (q == 1.0) {
        return -s;
    }
    if (q == 2.0) {
        return -c;
    }
    return s;
}

// tan(x) as the ratio of the two kernels after one shared reduction; ~2-3 ulp for |x| < 8e5.
fn tan_f64(x: f64) -> f64 {
    let red = f64m_rem_pio2(x);
    let s = f64m_ksin(red.x, red.y);
    let c = f64m_kcos(red.x, red.y);
    let q = red.z;
    if (q == 0.0 || q == 2.0) {
        return s / c;
    }
    return -c / s;
}

// tanh(x) through expm1 (fdlibm s_tanh.c): no cancellation for small |x|. ~2-3 ulp.
fn tanh_f64(x: f64) -> f64 {
    let ax = abs(x);
    var z: f64;
    if (ax >= 22.0) {
        z = f64(1.0); // tanh = 1 to within 2^-63 (also for +-inf)
    } else if (ax < 2.7755575615628914e-17) {
        return x; // |x| < 2^-55 (and NaN)
    } else if (ax >= 1.0) {
        let t = expm1_f64(2.0 * ax);
        z = 1.0 - 2.0 / (t + 2.0);
    } else {
        let t = expm1_f64(-2.0 * ax);
        z = -t / (t + 2.0);
    }
    return select(z, -z, x < 0.0);
}

// x^y for x >= 0. Computed as exp(y log x) with log x in double-double and y log x kept as
// hi + lo (two_prod_f64 recovers the product's rounding), so the result stays within a few ulp
// even when |y log x| is in the hundreds (the naive exp(y*log(x)) loses ~|y log x| ulp: 5e-14
// relative for x = 1e-3, y = 50).
// Special cases: x^0 = 1, 1^y = 1, 0^y = 0 (y > 0) or +inf (y < 0), inf^y = inf or 0,
// x < 0 -> NaN (no integer-exponent special case), overflow -> +inf, underflow -> 0.
fn pow_f64(x: f64, y: f64) -> f64 {
    if (y == 0.0 || x == 1.0) {
        return f64(1.0);
    }
    if (x != x || y != y) {
        return x + y; // NaN
    }
    if (x < 0.0) {
        return (x - x) / (x - x); // NaN
    }
    if (x == 0.0) {
        return select(f64(0.0), 1.0 / abs(x), y < 0.0); // 0^y: 0, or +inf for y < 0
    }
    if (x > F64M_MAX) {
        return select(x, f64(0.0), y < 0.0); // inf^y: inf, or 0 for y < 0
    }
    let l = f64m_log_dd(x);
    let p = y * l.x;
    if (!(abs(p) < 746.0)) {
        return f64m_exp_dd(p, f64(0.0)); // overflow to inf or underflow to 0 (NaN passes)
    }
    let z = two_prod_f64(y, l.x); // |y| < 2^996 here since |log x| > 1e-16 for x != 1
    return f64m_exp_dd(z.x, z.y + y * l.y);
}
