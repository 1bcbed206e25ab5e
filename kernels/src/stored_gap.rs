//! How solvers store a gap: d itself (> 0), or ln d (< 0) for a gap too small to keep as a
//! float, or 0 for a bonded gap (a cluster's contact). The stored form keeps relative precision
//! at any size (DESIGN.md §2: near contact, accuracy means accuracy of ln d).

/// The gap a stored value stands for (0 when it is below the float range).
#[inline(always)]
pub fn decode(stored: f64) -> f64 {
    if stored > 0.0 {
        stored
    } else if stored < 0.0 {
        stored.exp()
    } else {
        0.0
    }
}

/// The stored value of a gap d >= 0 for a solver that keeps gaps below `floor` as ln d.
#[inline(always)]
pub fn encode(d: f64, floor: f64) -> f64 {
    if d > 0.0 && d < floor {
        d.ln()
    } else {
        d
    }
}

/// ln d of a stored free gap.
#[inline(always)]
pub fn ln(stored: f64) -> f64 {
    if stored > 0.0 {
        stored.ln()
    } else {
        stored
    }
}
