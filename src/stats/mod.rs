//! Mergeable summary statistics for ensembles.
//!
//! An ensemble of thousands to millions of members is never held in memory at once: each chunk
//! (and each shard, possibly on another machine) is summarized, and the summaries are merged. Every
//! type here therefore has a `push` (one observation; [`FieldBand`] takes a chunk of rows), a
//! `merge` (combine two summaries of disjoint sets of observations) and a serde representation
//! that round-trips **bit-exactly**, so that a shard written to JSON on one machine and merged on
//! another gives the same numbers as a summary computed in one place.
//!
//! One implementation of each statistic, one file each:
//!
//! * [`RunningStats`] (`moments.rs`): count, mean, sample variance, min, max (compensated Welford
//!   updates, Chan et al. pairwise combination).
//! * [`QuantileSketch`] (`sketch.rs`): a DDSketch (Masson, Rim & Lee, VLDB 2019) with a
//!   relative-error guarantee on every quantile. Its state is integer bucket counts, so merging is
//!   exact, associative and commutative: any sharding and any merge order give the identical
//!   sketch.
//! * [`Bins`] and [`Histogram`] (`histogram.rs`): fixed equal-width bins (the one binning rule)
//!   and counts in them plus underflow / overflow; quantiles as bin midpoints.
//! * [`ScalarSummary`] (`scalar.rs`): moments and sketch of one scalar observable; its histogram
//!   over the observed `[min, max]` is read from the sketch
//!   ([`QuantileSketch::range_histogram`]).
//! * [`FieldBand`] (`field.rs`): pointwise over a grid of G points, moments and a fixed-bin
//!   histogram ([`Bins`]) per point, for quantile bands within half a bin width.
//! * [`sensitivity`]: Sobol indices (first and total order) of a pick-freeze design, computed
//!   from the per-point responses of a merged study state.
//!
//! # Non-finite values
//!
//! NaN and ±infinity are never averaged, sketched or binned. Every `push` returns `true` when the
//! value was taken into the summary and `false` when it was not; the rejected values are counted in
//! a separate `non_finite` counter (reported by `non_finite()`, merged like the other counts).
//!
//! # Serialization
//!
//! `f64` state (means, sums of squares, extremes, `alpha`, histogram edges) goes through
//! [`crate::output::serde_f64`]: finite values are written as JSON numbers, non-finite ones as the
//! strings `"NaN"`, `"inf"` and `"-inf"` (e.g. the `+inf` minimum of an empty accumulator). The
//! crate enables serde_json's `float_roundtrip` feature, so every finite `f64` written as a JSON
//! number (serde_json writes the shortest representation that parses back to the same value)
//! reads back to the same bits, and a merge of deserialized shards equals the in-memory merge
//! (strings holding a number, as older files wrote them, are accepted too).
//! The plain `f64` fields of [`FieldBand`] (its range) rely on the same feature. Binary
//! (non-human-readable) formats store raw `f64`.

mod buckets;
mod field;
mod histogram;
mod moments;
mod scalar;
pub mod sensitivity;
mod sketch;

pub use field::FieldBand;
pub use histogram::{Bins, Histogram};
pub use moments::RunningStats;
pub use scalar::ScalarSummary;
pub use sketch::QuantileSketch;

/// Errors from building, merging, querying or deserializing summaries.
#[derive(Debug, thiserror::Error)]
pub enum StatsError {
    #[error("quantile sketch: relative accuracy alpha = {0} is outside the allowed range [{min}, {max}]", min = QuantileSketch::MIN_ALPHA, max = QuantileSketch::MAX_ALPHA)]
    InvalidAlpha(f64),

    #[error("cannot merge quantile sketches with different relative accuracies (alpha = {left} and alpha = {right})")]
    AlphaMismatch { left: f64, right: f64 },

    #[error("histogram: invalid binning lo = {lo}, hi = {hi}, bins = {bins} (need finite lo < hi with finite hi - lo, and 1 <= bins <= 2^32 - 1)")]
    InvalidHistogram { lo: f64, hi: f64, bins: usize },

    #[error("cannot merge histograms with different bins: [{lo_a}, {hi_a}] in {bins_a} bins and [{lo_b}, {hi_b}] in {bins_b} bins")]
    HistogramMismatch {
        lo_a: f64,
        hi_a: f64,
        bins_a: usize,
        lo_b: f64,
        hi_b: f64,
        bins_b: usize,
    },

    #[error("{what}: length {got} does not match the expected {expected}")]
    LengthMismatch {
        what: &'static str,
        expected: usize,
        got: usize,
    },

    #[error("quantile level q = {0} is outside [0, 1]")]
    InvalidQuantile(f64),

    #[error("inconsistent serialized {what}: {message}")]
    InvalidState { what: &'static str, message: String },

    #[error("{what}: more than {limit} values at one point: a sweep point of that many members is not supported")]
    CountOverflow { what: &'static str, limit: u64 },

    #[error("{what}: a value taken out that was never counted")]
    NotCounted { what: &'static str },
}
