//! The reference of an accuracy run: auto with a tight tolerance, checked against a second
//! run, loosened where a member fails near contact.

use super::members::{errors, solve, MeasuredGroup};
use super::{AccuracyOptions, Run, Setting};
use crate::backend::{Backend, Precision};
use crate::error::{Error, Result};
use crate::model::params::{Order, Sequence, Stepping};
use crate::scene::Scene;

/// The reference of an accuracy run: order auto, adaptive, at `tolerance`.
/// The reference: auto with `from_1` whatever the scene's (the reference the measurements of
/// docs/accuracy.md were taken against, independent of the sequence auto takes by default).
pub(super) fn reference_setting(scene: &Scene, tolerance: f64) -> Setting {
    Setting {
        order: Order::Auto,
        stepping: Stepping::Adaptive {
            tolerance,
            dt_initial: 1e-6 * scene.end,
            dt_min: scene.stepping.dt_min().min(1e-14 * scene.end),
        },
        sequence: Sequence::FromOne,
        jacobian: scene.jacobian,
        backend: Backend::Cpu,
        precision: Precision::F64,
    }
}

/// The reference and its error against a check run (printed, and warned about when above a
/// tenth of the target). The reference is tried at `tolerance` and, where a member fails there
/// (near contact a tight tolerance can need steps below the time resolution of t), at ten and a
/// hundred times it, up to a tenth of the target; the check at a tenth of the reference's
/// tolerance, or ten times it where that fails (a looser check overstates the reference's error,
/// so the warning errs on the safe side). Fails, naming every tolerance tried and why, when none
/// runs.
pub(super) fn solve_reference(
    scene: &Scene,
    groups: &[MeasuredGroup],
    tolerance: f64,
    options: &AccuracyOptions,
) -> Result<(Run, f64, f64)> {
    let mut tried: Vec<String> = Vec::new();
    // Tolerances already found to fail (a check may be asked for one of them again).
    let mut failed: Vec<f64> = Vec::new();
    let mut attempt = |tolerance: f64, role: &str| -> Result<Option<Run>> {
        // Within rounding: the candidates and their checks are products of ten.
        if failed.iter().any(|t| (t / tolerance - 1.0).abs() < 1e-9) {
            return Ok(None);
        }
        let run = solve(groups, &reference_setting(scene, tolerance))?;
        Ok(match &run.failure {
            Some(why) => {
                tried.push(format!("tolerance {}{role}: {why}", round_e(tolerance)));
                failed.push(tolerance);
                None
            }
            None => Some(run),
        })
    };
    let candidates = [tolerance, tolerance * 10.0, tolerance * 100.0];
    let mut found = None;
    for (k, &tolerance) in candidates.iter().enumerate() {
        if k > 0 && tolerance > options.target / 10.0 * 1.001 {
            break;
        }
        let Some(reference) = attempt(tolerance, "")? else {
            continue;
        };
        let mut check_tolerance = tolerance / 10.0;
        let mut check = attempt(check_tolerance, " (the check)")?;
        if check.is_none() {
            check_tolerance = tolerance * 10.0;
            check = attempt(check_tolerance, " (the check)")?;
        }
        if let Some(check) = check {
            found = Some((reference, check, tolerance, check_tolerance));
            break;
        }
    }
    let Some((reference, check, tolerance, check_tolerance)) = found else {
        return Err(Error::missing(
            "accuracy",
            format!(
                "no reference (order auto, adaptive, at tolerance {} and up to a hundred times it, no looser than a tenth of the target) completed every measured member: {}; `roughlub run` of the scene at such a tolerance shows the failure",
                round_e(tolerance),
                tried.join("; ")
            ),
        ));
    };
    let reference_error = errors(&reference.snapshots, &check.snapshots).worst();
    if !options.quiet {
        for failure in &tried {
            eprintln!("note: the reference failed at {failure}");
        }
        eprintln!(
            "reference: order auto (sequence from_1), tolerance {} ({} steps, {:.2} s); against tolerance {}: error {reference_error:.2e}",
            round_e(tolerance),
            reference.accepted,
            reference.wall,
            round_e(check_tolerance),
        );
    }
    if reference_error > options.target / 10.0 {
        eprintln!(
            "warning: the reference is only accurate to {reference_error:.1e}, more than a tenth of the target {}: errors below about {reference_error:.0e} are not resolved",
            round_e(options.target)
        );
    }
    Ok((reference, reference_error, tolerance))
}

/// A tolerance as a user writes it: rounded to 12 significant digits, then shortest (1e-11 for
/// 1e-8 · 1e-3, which is 1.0000000000000001e-11).
fn round_e(x: f64) -> String {
    let rounded: f64 = format!("{x:.11e}").parse().unwrap_or(x);
    format!("{rounded:e}")
}
