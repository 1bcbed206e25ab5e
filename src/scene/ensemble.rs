//! The `[ensemble]` section: many members per sweep point, differing by random roughness and
//! perturbed initial data, summarised by statistics (see `crate::study`).

use std::path::Path;

use super::checks::{check_non_empty, check_range, check_within, Range};
use super::file::EnsembleSection;
use super::{InitialSpec, MAX_ROUGHNESS_RADIUS};
use crate::ensemble::{RoughnessKind, RoughnessSpec};
use crate::error::{Error, Result};

/// The validated `[ensemble]` section.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct EnsembleSpec {
    /// Members per sweep point; the study has `members × (sweep points)` members, member m at
    /// sweep point m mod (sweep points).
    pub members: u64,
    pub seed: u64,
    /// Members solved (and kept in memory) at once.
    pub chunk: usize,
    #[serde(skip)]
    pub roughness: Option<RoughnessSpec>,
    /// Roughness radius when the scene has no rho* profile.
    pub mean_radius: Option<f64>,
    pub velocity_amplitude_spread: f64,
    pub velocity_phase_spread: f64,
    pub jitter: f64,
    /// Density threshold of the first-hitting-time observable.
    pub threshold: f64,
    pub store_members: bool,
    pub quantiles: Vec<f64>,
    /// Histogram bins of the field quantile bands.
    pub bins: usize,
    pub u_range: Option<[f64; 2]>,
    /// How many sweep points (the first ones) keep statistics per output time (scalars at every
    /// time and the field bands); `None`: every point of a grid design, the first
    /// [`DEFAULT_DETAILED_SAMPLED_POINTS`] of a sampled one whose points hold several members,
    /// none of a sampled one of one member a point. Every point keeps its members' responses
    /// (peak density, first hit, smallest gap, final energy).
    pub detailed_points: Option<u64>,
}

/// Points of a sampled design (random, Latin hypercube, Sobol, Saltelli) with several members a
/// point that keep per-time statistics by default: as many as get their own plots. A point of
/// one member keeps none by default: its "bands" would be that member's own profile (which
/// `store_members` keeps), and the design's information is in the responses per point.
pub const DEFAULT_DETAILED_SAMPLED_POINTS: u64 = 4;

pub(super) fn validate_ensemble(
    e: &EnsembleSection,
    initial: &InitialSpec,
    scene_path: &Path,
) -> Result<EnsembleSpec> {
    let members = check_range(
        "ensemble.members",
        e.members,
        Range::count(1, 1_000_000_000).upper_text("1e9"),
        "members per sweep point",
    )?;
    let chunk = check_range(
        "ensemble.chunk",
        e.chunk.unwrap_or(256),
        Range::count(1, 1_000_000),
        "members solved at once (memory)",
    )?;
    let roughness = roughness(e, scene_path)?;
    let has_rho_star = match initial {
        InitialSpec::Profiles { rho_star, .. } => rho_star.is_some(),
        InitialSpec::Particles { .. } => true,
    };
    if let Some(r) = e.mean_radius {
        check_range(
            "ensemble.mean_radius",
            r,
            Range::of("mean_radius").ge(0.0).lt(MAX_ROUGHNESS_RADIUS),
            "the mean roughness radius",
        )?;
    }
    // A file gives every radius itself; only random roughness is drawn around a mean profile.
    let drawn = roughness
        .as_ref()
        .is_some_and(|r| !matches!(r.kind, RoughnessKind::File(_)));
    // A mean radius that nothing draws around would be silently ignored.
    if let Some(r) = e.mean_radius {
        if has_rho_star {
            return Err(Error::invalid(
                "ensemble.mean_radius",
                r,
                "the mean roughness radius, where the mean profile is already given (initial.rho_star or the particle file's radii)",
                "absent with initial.rho_star or a particle file; give one of the two",
            ));
        }
        if !drawn {
            return Err(Error::invalid(
                "ensemble.mean_radius",
                r,
                "the mean roughness radius, which only random roughness (ensemble.roughness of a kind other than a file) is drawn around",
                "absent without a random ensemble.roughness",
            ));
        }
    }
    if drawn && !has_rho_star && e.mean_radius.is_none() {
        return Err(Error::missing(
            "ensemble.mean_radius",
            "random roughness needs a mean profile: give initial.rho_star or ensemble.mean_radius (>= 0)",
        ));
    }
    let spread = |field: &str, v: Option<f64>, max: f64| {
        let range = Range::of("value").ge(0.0).le(max);
        check_range(field, v.unwrap_or(0.0), range, "relative spread")
    };
    let velocity_amplitude_spread = spread(
        "ensemble.velocity_amplitude_spread",
        e.velocity_amplitude_spread,
        10.0,
    )?;
    let velocity_phase_spread = spread(
        "ensemble.velocity_phase_spread",
        e.velocity_phase_spread,
        1.0,
    )?;
    if velocity_phase_spread > 0.0 && matches!(initial, InitialSpec::Particles { .. }) {
        return Err(Error::missing(
            "ensemble.velocity_phase_spread",
            "a phase shift needs a velocity profile u0(x); with a particle file only the amplitude can vary",
        ));
    }
    let jitter = spread("ensemble.jitter", e.jitter, 2.0)?;
    let threshold = check_range(
        "ensemble.threshold",
        e.threshold.unwrap_or(0.9),
        Range::of("threshold").gt(0.0).le(1.0),
        "density threshold",
    )?;
    let quantiles = e
        .quantiles
        .clone()
        .unwrap_or_else(|| vec![0.05, 0.25, 0.5, 0.75, 0.95]);
    check_non_empty(
        "ensemble.quantiles",
        &quantiles,
        "no quantile",
        "a non-empty list in [0, 1]",
    )?;
    for (j, &q) in quantiles.iter().enumerate() {
        check_within(
            &format!("ensemble.quantiles[{j}]"),
            q,
            Range::of("q").ge(0.0).le(1.0),
            "a quantile level",
        )?;
    }
    let bins = check_range(
        "ensemble.bins",
        e.bins.unwrap_or(400),
        Range::count(4, 100_000),
        "histogram bins of the field bands",
    )?;
    if let Some([lo, hi]) = e.u_range {
        if !(lo.is_finite() && hi.is_finite() && lo < hi) {
            return Err(Error::invalid(
                "ensemble.u_range",
                format!("[{lo}, {hi}]"),
                "velocity range of the u band",
                "[lo, hi] with lo < hi",
            ));
        }
    }
    Ok(EnsembleSpec {
        members: members as u64,
        seed: e.seed.unwrap_or(0),
        chunk: chunk as usize,
        roughness,
        mean_radius: e.mean_radius,
        velocity_amplitude_spread,
        velocity_phase_spread,
        jitter,
        threshold,
        store_members: e.store_members.unwrap_or(false),
        quantiles,
        bins: bins as usize,
        u_range: e.u_range,
        detailed_points: match e.detailed_points {
            None => None,
            Some(n) => Some(check_range(
                "ensemble.detailed_points",
                n,
                Range::count(0, 1_000_000_000),
                "sweep points (the first ones) that keep statistics per output time",
            )? as u64),
        },
    })
}

/// The roughness model, validated, with a radii file resolved against the scene's folder (like
/// the particle file).
fn roughness(e: &EnsembleSection, scene_path: &Path) -> Result<Option<RoughnessSpec>> {
    let Some(mut r) = e.roughness.clone() else {
        return Ok(None);
    };
    // The error names its key (roughness.spread, .length) and range: under `ensemble`.
    r.validate()
        .map_err(|err| Error::missing("ensemble", err.to_string()))?;
    if let RoughnessKind::File(p) = &mut r.kind {
        if p.is_relative() {
            *p = scene_path.parent().unwrap_or(Path::new(".")).join(&*p);
        }
    }
    Ok(Some(r))
}
