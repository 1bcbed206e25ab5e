//! The extrapolation tableau of a block's trial step: where each substep reads and writes. The
//! Aitken–Neville combination of the rows with its error estimates is `extrapolate` in the
//! kernels crate (`roughlub_kernels::tableau`, twin of the same function in
//! `shaders/step.wgsl`).

/// The source and destination of substep s (0-based) of a tableau row of `substeps`: the
/// current state for the first, the row's slot for the last, the two substep buffers in turn
/// between.
#[allow(clippy::type_complexity)]
pub(super) fn substep_buffers<'a, T>(
    current: (&'a [T], &'a [T]),
    subs: (&'a mut [Vec<T>; 2], &'a mut [Vec<T>; 2]),
    row: (&'a mut [T], &'a mut [T]),
    s: usize,
    substeps: usize,
) -> (&'a [T], &'a [T], &'a mut [T], &'a mut [T]) {
    let (sub_g, sub_v) = subs;
    let [g0, g1] = sub_g;
    let [v0, v1] = sub_v;
    // Substep s writes buffer s % 2 (or the row) and reads buffer (s - 1) % 2.
    let (read_g, write_g, read_v, write_v) = if s % 2 == 1 {
        (&*g0, g1, &*v0, v1)
    } else {
        (&*g1, g0, &*v1, v0)
    };
    let (src_g, src_v) = if s == 0 {
        current
    } else {
        (read_g.as_slice(), read_v.as_slice())
    };
    if s + 1 == substeps {
        (src_g, src_v, row.0, row.1)
    } else {
        (src_g, src_v, write_g.as_mut_slice(), write_v.as_mut_slice())
    }
}
