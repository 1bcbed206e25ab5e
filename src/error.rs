//! The crate's one error type. Every message names what was wrong and, where there is one, the
//! allowed range, so that a researcher can fix a scene without reading the source.

use std::path::PathBuf;

use crate::backend::GpuError;
use crate::expr::ExprError;
use crate::plot::PlotError;

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// TOML syntax, unknown keys, wrong value types (the message from toml names line and key).
    #[error("scene file {path}: {message}")]
    SceneSyntax { path: PathBuf, message: String },

    /// A value outside its allowed range, or a combination of keys that does not make sense.
    #[error("{field} = {value}: {message} (allowed: {allowed})")]
    InvalidField {
        field: String,
        value: String,
        message: String,
        allowed: String,
    },

    /// A key that must be present is missing (or two keys exclude each other).
    #[error("{field}: {message}")]
    MissingField { field: String, message: String },

    #[error("{field} = \"{source_text}\": cannot parse expression {source}")]
    Expression {
        field: String,
        source_text: String,
        source: ExprError,
    },

    /// A profile expression evaluates outside its allowed range somewhere on [0, 1].
    #[error("{field} = \"{expression}\": value {value} at x = {x} is outside the allowed range {allowed}")]
    ProfileRange {
        field: String,
        expression: String,
        value: f64,
        x: f64,
        allowed: String,
    },

    #[error("particle file {path}, line {line}: {message}")]
    ParticleFile {
        path: PathBuf,
        line: usize,
        message: String,
    },

    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },

    #[error("{path}: {message}")]
    Output { path: PathBuf, message: String },

    #[error(transparent)]
    Plot(#[from] PlotError),

    /// An ensemble or design setting out of range (the message names the key).
    #[error(transparent)]
    Ensemble(#[from] crate::ensemble::EnsembleError),

    #[error(transparent)]
    Gpu(#[from] GpuError),

    /// A GPU error with what was being done (`context`, e.g. `solver.backend = "gpu"`) and what
    /// the user can do about it (`advice`, empty or starting with "; ").
    #[error("{context}: {source}{advice}")]
    GpuBackend {
        context: String,
        source: GpuError,
        advice: String,
    },
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    pub fn invalid(
        field: impl Into<String>,
        value: impl std::fmt::Display,
        message: impl Into<String>,
        allowed: impl Into<String>,
    ) -> Self {
        Error::InvalidField {
            field: field.into(),
            value: value.to_string(),
            message: message.into(),
            allowed: allowed.into(),
        }
    }

    pub fn missing(field: impl Into<String>, message: impl Into<String>) -> Self {
        Error::MissingField {
            field: field.into(),
            message: message.into(),
        }
    }

    pub fn gpu(context: impl Into<String>, source: GpuError, advice: impl Into<String>) -> Self {
        Error::GpuBackend {
            context: context.into(),
            source,
            advice: advice.into(),
        }
    }

    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }
}
