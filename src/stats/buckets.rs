//! [`BucketStore`]: the bucket counts of one sign of a [`QuantileSketch`](super::QuantileSketch).

use std::collections::BTreeMap;

/// Widest range of bucket indices kept dense (4 KiB of counts): the values of one observable at
/// one output time usually span a few dozen buckets, and a dense store adds a value with an
/// index, where a map searched its tree (most of a study's scalar statistics, by profile).
const DENSE_SPAN: usize = 512;

/// Counts by bucket index: a count for every index of a contiguous range while that range is at
/// most [`DENSE_SPAN`] wide, the non-empty buckets in index order beyond (memory stays
/// proportional to what the store holds either way). The two forms hold the same counts: every
/// reader sees only the non-empty buckets, in ascending index order.
#[derive(Clone, Debug)]
pub(super) enum BucketStore {
    Dense {
        /// Index of `counts[0]`.
        first: i32,
        counts: Vec<u64>,
        /// How many of `counts` are non-zero.
        nonzero: usize,
    },
    /// `(index, count)` of the non-empty buckets, indices ascending: a chunk's sketch merges
    /// into a study's total in one pass over both (a tree took a search per bucket, most of
    /// the time between a study's chunks). A new bucket shifts those after it; values pushed
    /// one by one go into a chunk's sketches, and a sketch holds at most about 1150 buckets
    /// per decade its values span (alpha = 0.001).
    Sparse(Vec<(i32, u64)>),
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
            BucketStore::Sparse(buckets) => match buckets.binary_search_by_key(&k, |b| b.0) {
                Ok(at) => buckets[at].1 += c,
                Err(at) => buckets.insert(at, (k, c)),
            },
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
        let (lo, hi) = dense_union(*first, counts, (k as i64, k as i64));
        if (hi - lo + 1) as usize > DENSE_SPAN {
            let mut sparse = BucketStore::Sparse(self.iter().collect());
            sparse.add(k, c);
            *self = sparse;
            return;
        }
        widen(first, counts, (lo, hi));
        counts[(k as i64 - *first as i64) as usize] = c;
        *nonzero += 1;
    }

    /// Adds every bucket of `other`. Two dense stores whose ranges together fit
    /// [`DENSE_SPAN`] add their counts slot by slot (a study merges each chunk's sketches into
    /// the total: bucket by bucket that was most of the time between chunks); otherwise bucket
    /// by bucket, as [`add`](Self::add) does. The same counts either way.
    pub(super) fn merge_from(&mut self, other: &BucketStore) {
        if let (
            BucketStore::Dense {
                first,
                counts,
                nonzero,
            },
            BucketStore::Dense {
                first: other_first,
                counts: other_counts,
                ..
            },
        ) = (&mut *self, other)
        {
            if other_counts.is_empty() {
                return;
            }
            let other_last = *other_first as i64 + other_counts.len() as i64 - 1;
            let (lo, hi) = dense_union(*first, counts, (*other_first as i64, other_last));
            if ((hi - lo + 1) as usize) <= DENSE_SPAN {
                widen(first, counts, (lo, hi));
                let at = (*other_first as i64 - lo) as usize;
                let mut became_nonzero = 0;
                for (mine, &theirs) in counts[at..at + other_counts.len()]
                    .iter_mut()
                    .zip(other_counts)
                {
                    became_nonzero += usize::from(*mine == 0 && theirs > 0);
                    *mine += theirs;
                }
                *nonzero += became_nonzero;
                return;
            }
        }
        if let BucketStore::Sparse(mine) = self {
            // Both in index order: one pass over the two.
            let mut merged = Vec::with_capacity(mine.len() + other.len());
            let mut theirs = other.iter().peekable();
            for &(k, c) in mine.iter() {
                while let Some(&(j, d)) = theirs.peek().filter(|b| b.0 < k) {
                    merged.push((j, d));
                    theirs.next();
                }
                match theirs.peek() {
                    Some(&(j, d)) if j == k => {
                        merged.push((k, c + d));
                        theirs.next();
                    }
                    _ => merged.push((k, c)),
                }
            }
            merged.extend(theirs);
            *mine = merged;
            return;
        }
        for (k, c) in other.iter() {
            self.add(k, c);
        }
    }

    /// Number of non-empty buckets.
    pub(super) fn len(&self) -> usize {
        match self {
            BucketStore::Dense { nonzero, .. } => *nonzero,
            BucketStore::Sparse(buckets) => buckets.len(),
        }
    }

    /// The non-empty buckets `(index, count)` in ascending index order.
    pub(super) fn iter(&self) -> impl DoubleEndedIterator<Item = (i32, u64)> + '_ {
        let (dense, sparse) = match self {
            BucketStore::Dense { first, counts, .. } => (Some((*first, counts)), None),
            BucketStore::Sparse(buckets) => (None, Some(buckets)),
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
            .flat_map(|buckets| buckets.iter().copied());
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

/// The smallest range holding a dense store's counts (none if empty) and `lo..=hi`.
fn dense_union(first: i32, counts: &[u64], (lo, hi): (i64, i64)) -> (i64, i64) {
    match counts.is_empty() {
        true => (lo, hi),
        false => (
            lo.min(first as i64),
            hi.max(first as i64 + counts.len() as i64 - 1),
        ),
    }
}

/// Widens a dense store's counts with zeros to the range `lo..=hi`, which holds its own.
fn widen(first: &mut i32, counts: &mut Vec<u64>, (lo, hi): (i64, i64)) {
    if counts.is_empty() {
        *first = lo as i32;
    }
    if lo < *first as i64 {
        let grow = (*first as i64 - lo) as usize;
        counts.splice(0..0, std::iter::repeat_n(0, grow));
        *first = lo as i32;
    }
    counts.resize((hi - lo + 1) as usize, 0);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_rng::integer_stream;

    /// Whatever the order of the additions and however wide their range, the store holds what a
    /// map holds (the form the sketch had before, and its serialized form).
    #[test]
    fn holds_what_a_map_holds_dense_and_sparse() {
        let mut next = integer_stream(0x2545_F491_4F6C_DD1Du64);
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

    /// Merging two stores, dense or not, in either order, holds the sum of their maps (what
    /// adding the other's buckets one by one gave).
    #[test]
    fn a_merge_holds_the_sum_of_both() {
        let mut next = integer_stream(0x9E37_79B9_7F4A_7C15u64);
        let mut store_of = |span: u64, offset: i32| {
            let mut store = BucketStore::default();
            let mut map = BTreeMap::new();
            for _ in 0..400 {
                let k = (next() % span) as i32 + offset;
                let c = 1 + next() % 3;
                store.add(k, c);
                *map.entry(k).or_insert(0u64) += c;
            }
            (store, map)
        };
        // Dense and dense (overlapping, apart, too wide together), sparse on either side.
        let cases = [
            ((100, 0), (100, 50)),
            ((100, 0), (100, 400)),
            ((100, 0), (100, 600)),
            ((3000, -1500), (100, 20)),
            ((100, 20), (3000, -1500)),
            ((3000, 0), (3000, 1000)),
            ((1, 0), (1, 0)),
        ];
        for ((span_a, at_a), (span_b, at_b)) in cases {
            let (mut a, mut sum) = store_of(span_a, at_a);
            let (b, map_b) = store_of(span_b, at_b);
            for (k, c) in map_b {
                *sum.entry(k).or_insert(0) += c;
            }
            a.merge_from(&b);
            assert_eq!(
                a.to_map(),
                sum,
                "{span_a} at {at_a} with {span_b} at {at_b}"
            );
            assert_eq!(a.len(), sum.len());
            let width = sum.keys().last().unwrap() - sum.keys().next().unwrap() + 1;
            if matches!(a, BucketStore::Dense { .. }) {
                assert!(width as usize <= DENSE_SPAN);
            }
        }
        let mut empty = BucketStore::default();
        let (b, map_b) = store_of(50, 7);
        empty.merge_from(&b);
        assert_eq!(empty.to_map(), map_b);
    }
}
