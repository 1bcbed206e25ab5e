//! [`BucketStore`]: the bucket counts of one sign of a [`QuantileSketch`](super::QuantileSketch).

use std::collections::BTreeMap;

/// Widest range of bucket indices kept dense (4 KiB of counts): the values of one observable at
/// one output time usually span a few dozen buckets, and a dense store adds a value with an
/// index, where a map searched its tree (most of a study's scalar statistics, by profile).
const DENSE_SPAN: usize = 512;

/// Counts by bucket index: a count for every index of a contiguous range while that range is at
/// most [`DENSE_SPAN`] wide, a map of the non-empty buckets beyond (memory stays proportional to
/// what the store holds either way). The two forms hold the same counts: every reader sees only
/// the non-empty buckets, in ascending index order.
#[derive(Clone, Debug)]
pub(super) enum BucketStore {
    Dense {
        /// Index of `counts[0]`.
        first: i32,
        counts: Vec<u64>,
        /// How many of `counts` are non-zero.
        nonzero: usize,
    },
    Sparse(BTreeMap<i32, u64>),
}

impl Default for BucketStore {
    fn default() -> Self {
        BucketStore::Dense {
            first: 0,
            counts: Vec::new(),
            nonzero: 0,
        }
    }
}

impl BucketStore {
    /// Adds `c` (> 0) to bucket `k`.
    #[inline]
    pub(super) fn add(&mut self, k: i32, c: u64) {
        debug_assert!(c > 0);
        match self {
            BucketStore::Dense {
                first,
                counts,
                nonzero,
            } => {
                let at = k as i64 - *first as i64;
                if at >= 0 && (at as usize) < counts.len() {
                    let slot = &mut counts[at as usize];
                    *nonzero += usize::from(*slot == 0);
                    *slot += c;
                } else {
                    self.add_outside(k, c);
                }
            }
            BucketStore::Sparse(map) => *map.entry(k).or_insert(0) += c,
        }
    }

    /// [`add`](Self::add) for an index outside a dense store's range: the range grows to take
    /// it, or the store becomes a map if it would be wider than [`DENSE_SPAN`].
    #[cold]
    fn add_outside(&mut self, k: i32, c: u64) {
        let BucketStore::Dense {
            first,
            counts,
            nonzero,
        } = self
        else {
            unreachable!("called for a dense store")
        };
        if counts.is_empty() {
            *first = k;
            counts.push(c);
            *nonzero = 1;
            return;
        }
        let last = *first as i64 + counts.len() as i64 - 1;
        let (lo, hi) = ((k as i64).min(*first as i64), (k as i64).max(last));
        if (hi - lo + 1) as usize > DENSE_SPAN {
            let mut map = self.to_map();
            *map.entry(k).or_insert(0) += c;
            *self = BucketStore::Sparse(map);
            return;
        }
        if (k as i64) < *first as i64 {
            let grow = (*first as i64 - k as i64) as usize;
            counts.splice(0..0, std::iter::repeat_n(0, grow));
            *first = k;
        } else {
            counts.resize((k as i64 - *first as i64 + 1) as usize, 0);
        }
        counts[(k as i64 - *first as i64) as usize] = c;
        *nonzero += 1;
    }

    /// Number of non-empty buckets.
    pub(super) fn len(&self) -> usize {
        match self {
            BucketStore::Dense { nonzero, .. } => *nonzero,
            BucketStore::Sparse(map) => map.len(),
        }
    }

    /// The non-empty buckets `(index, count)` in ascending index order.
    pub(super) fn iter(&self) -> impl DoubleEndedIterator<Item = (i32, u64)> + '_ {
        let (dense, sparse) = match self {
            BucketStore::Dense { first, counts, .. } => (Some((*first, counts)), None),
            BucketStore::Sparse(map) => (None, Some(map)),
        };
        let dense = dense.into_iter().flat_map(|(first, counts)| {
            counts
                .iter()
                .enumerate()
                .filter(|(_, &c)| c > 0)
                .map(move |(i, &c)| (first + i as i32, c))
        });
        let sparse = sparse
            .into_iter()
            .flat_map(|map| map.iter().map(|(&k, &c)| (k, c)));
        dense.chain(sparse)
    }

    /// The non-empty buckets as a map (the serialized form).
    pub(super) fn to_map(&self) -> BTreeMap<i32, u64> {
        self.iter().collect()
    }

    /// The store of the non-empty buckets of `map` (dense if they fit).
    pub(super) fn from_map(map: &BTreeMap<i32, u64>) -> Self {
        let mut store = BucketStore::default();
        for (&k, &c) in map.iter().filter(|(_, &c)| c > 0) {
            store.add(k, c);
        }
        store
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Whatever the order of the additions and however wide their range, the store holds what a
    /// map holds (the form the sketch had before, and its serialized form).
    #[test]
    fn holds_what_a_map_holds_dense_and_sparse() {
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for span in [1u64, 40, 511, 512, 513, 5000] {
            let mut store = BucketStore::default();
            let mut map = BTreeMap::new();
            for _ in 0..3000 {
                let k = (next() % span) as i32 - (span / 2) as i32;
                let c = 1 + next() % 3;
                store.add(k, c);
                *map.entry(k).or_insert(0) += c;
            }
            assert_eq!(store.to_map(), map, "span {span}");
            assert_eq!(store.len(), map.len(), "span {span}");
            let dense = matches!(store, BucketStore::Dense { .. });
            let width = map.keys().last().unwrap() - map.keys().next().unwrap() + 1;
            assert_eq!(dense, width as usize <= DENSE_SPAN, "span {span}");
            let back: Vec<(i32, u64)> = store.iter().rev().collect();
            let expected: Vec<(i32, u64)> = map.iter().rev().map(|(&k, &c)| (k, c)).collect();
            assert_eq!(back, expected, "span {span}");
            assert_eq!(BucketStore::from_map(&map).to_map(), map, "span {span}");
        }
    }
}
