//! The batch layout both backends share: structure of arrays interleaved by member.

/// Interleaves per-member vectors of equal length: element i of member b at i·B + b (the layout
/// of a CPU block of B = L lanes and of the whole GPU batch).
pub fn interleave<T: Copy>(per_member: &[&[T]]) -> Vec<T> {
    let len = per_member.first().map_or(0, |v| v.len());
    let mut out = Vec::with_capacity(len * per_member.len());
    for i in 0..len {
        for member in per_member {
            out.push(member[i]);
        }
    }
    out
}
