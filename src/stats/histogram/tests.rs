use super::*;

/// `occupied_slots` is the range from the first non-empty slot to the last, as a plain scan
/// finds it, for every placement of the values (runs of 16 and their edges included).
#[test]
fn occupied_slots_are_first_to_last_non_empty() {
    let naive = |slots: &[u32]| -> std::ops::Range<usize> {
        match slots.iter().position(|&c| c > 0) {
            None => 0..0,
            Some(first) => first..slots.len() - slots.iter().rev().position(|&c| c > 0).unwrap(),
        }
    };
    for len in [0, 1, 15, 16, 17, 33, 402] {
        let mut slots = vec![0u32; len];
        assert_eq!(occupied_slots(&slots), naive(&slots), "empty, len {len}");
        for first in 0..len {
            for last in (first..len).step_by(7) {
                slots.fill(0);
                slots[first] = 1;
                slots[last] = 3;
                assert_eq!(
                    occupied_slots(&slots),
                    naive(&slots),
                    "{first}..={last} of {len}"
                );
                assert_eq!(occupied_slots(&slots), first..last + 1);
            }
        }
    }
}
