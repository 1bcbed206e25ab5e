//! The scene file as written: the serde view of the TOML, before any value is checked. Every
//! table denies unknown keys so that a typo is an error, not a silently ignored setting.

use serde::Deserialize;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct SceneFile {
    pub name: String,
    pub description: Option<String>,
    pub model: ModelSection,
    pub initial: InitialSection,
    pub time: TimeSection,
    #[serde(default)]
    pub solver: SolverSection,
    pub batch: Option<BatchSection>,
    #[serde(default)]
    pub output: OutputSection,
    pub ensemble: Option<EnsembleSection>,
    /// Named numbers usable in expressions (checked in `sweep`).
    pub parameters: Option<toml::Table>,
    /// The parameter study of an ensemble (checked in `sweep`).
    pub sweep: Option<toml::Table>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ModelSection {
    pub particles: Option<i64>,
    pub mu: f64,
    pub gamma: Option<f64>,
    pub forcing: Option<String>,
    pub radius: Option<f64>,
    pub quadrature: Option<i64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct InitialSection {
    pub rho: Option<String>,
    pub velocity: Option<String>,
    pub rho_star: Option<String>,
    pub particles: Option<String>,
}

/// `time.outputs`: a count of evenly spaced times, or the times themselves.
/// `time.outputs`: a whole number of evenly spaced times, or a list of times.
#[derive(Debug)]
pub(super) enum OutputsSpec {
    Count(i64),
    Times(Vec<f64>),
}

// Written by hand (not `#[serde(untagged)]`) so that a wrong value gets a message in the user's
// words instead of "data did not match any variant of untagged enum".
impl<'de> Deserialize<'de> for OutputsSpec {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl<'de> serde::de::Visitor<'de> for Visitor {
            type Value = OutputsSpec;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("time.outputs: a whole number of output times (2 ..= 100000) or a list of times")
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<OutputsSpec, E> {
                Ok(OutputsSpec::Count(v))
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<OutputsSpec, E> {
                Ok(OutputsSpec::Count(i64::try_from(v).unwrap_or(i64::MAX)))
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                mut seq: A,
            ) -> Result<OutputsSpec, A::Error> {
                let mut times = Vec::new();
                while let Some(t) = seq.next_element::<f64>()? {
                    times.push(t);
                }
                Ok(OutputsSpec::Times(times))
            }
        }
        d.deserialize_any(Visitor)
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct TimeSection {
    pub end: f64,
    pub outputs: OutputsSpec,
    pub dt: Option<f64>,
    pub tolerance: Option<f64>,
    pub dt_initial: Option<f64>,
    pub dt_min: Option<f64>,
}

/// `order = 3` or `order = "auto"`: either, so that a wrong value is reported with the field.
#[derive(Debug, Deserialize)]
#[serde(untagged)]
pub(super) enum OrderValue {
    Number(i64),
    Word(String),
    /// Any other value (`2.5`, `[4]`): refused with the field and the allowed values.
    Other(toml::Value),
}

#[derive(Debug, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(super) struct SolverSection {
    pub order: Option<OrderValue>,
    /// Strings, not the enums, so that an unknown name is reported with the field and the
    /// allowed names like every other scene error.
    pub backend: Option<String>,
    pub precision: Option<String>,
    /// Order 1 with fixed steps: run the companion that estimates the error (default true).
    pub error_estimate: Option<bool>,
    /// "auto", "exact" or "frozen": the matrix of the extrapolated steps.
    pub jacobian: Option<String>,
    /// "auto", "from_1" or "from_2": the substeps of the tableau's rows.
    pub sequence: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct BatchSection {
    pub mu: Option<Vec<f64>>,
    pub gamma: Option<Vec<f64>>,
}

#[derive(Debug, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(super) struct OutputSection {
    pub grid: Option<i64>,
    pub fields: Option<Vec<String>>,
    pub plots: Option<bool>,
    pub plot_members: Option<i64>,
}

/// `[ensemble]`: many members differing by random roughness and perturbed initial data, summarised
/// by statistics (see `crate::study`).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct EnsembleSection {
    pub members: i64,
    pub seed: Option<u64>,
    pub chunk: Option<i64>,
    pub roughness: Option<crate::ensemble::RoughnessSpec>,
    pub mean_radius: Option<f64>,
    pub velocity_amplitude_spread: Option<f64>,
    pub velocity_phase_spread: Option<f64>,
    pub jitter: Option<f64>,
    pub threshold: Option<f64>,
    pub store_members: Option<bool>,
    pub quantiles: Option<Vec<f64>>,
    pub bins: Option<i64>,
    pub u_range: Option<[f64; 2]>,
    pub detailed_points: Option<i64>,
}
