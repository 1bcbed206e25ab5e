//! Value checks shared by the sections: one range check (with the "allowed" text it renders),
//! finiteness, the mu/gamma checks used by `[model]` and `[batch]`, expressions and profiles.

use std::fmt::{self, Display};

use super::MAX_GAMMA;
use crate::error::{Error, Result};
use crate::expr::Expr;

/// A number a [`Range`] can bound: the integers and floats of the TOML.
pub(super) trait Number: Copy + PartialOrd + Display {
    fn is_finite(self) -> bool;
}

impl Number for i64 {
    fn is_finite(self) -> bool {
        true
    }
}

impl Number for f64 {
    fn is_finite(self) -> bool {
        f64::is_finite(self)
    }
}

/// One end of a [`Range`]; `text` is how the message writes it (the value unless a symbol such
/// as `end` reads better).
struct Limit<T> {
    value: T,
    inclusive: bool,
    text: String,
}

/// The allowed values of a field, and how an error message writes them: `lo <= name < hi` for a
/// named quantity, `lo ..= hi` for a count, `>= lo` when unnamed with only a lower bound.
pub(super) struct Range<T> {
    name: Option<&'static str>,
    lo: Option<Limit<T>>,
    hi: Option<Limit<T>>,
    /// Another accepted form, appended as ", or …".
    alternative: Option<&'static str>,
}

impl<T: Number> Range<T> {
    /// The range of the quantity `name` (bounds set by `gt`, `ge`, `lt`, `le`).
    pub fn of(name: &'static str) -> Self {
        Range {
            name: Some(name),
            ..Range::unnamed()
        }
    }

    /// A range written without a name: `>= lo`.
    pub fn unnamed() -> Self {
        Range {
            name: None,
            lo: None,
            hi: None,
            alternative: None,
        }
    }

    /// The count `lo ..= hi`.
    pub fn count(lo: T, hi: T) -> Self {
        Range::unnamed().ge(lo).le(hi)
    }

    pub fn gt(self, lo: T) -> Self {
        self.lower(lo, false)
    }

    pub fn ge(self, lo: T) -> Self {
        self.lower(lo, true)
    }

    pub fn lt(self, hi: T) -> Self {
        self.upper(hi, false)
    }

    pub fn le(self, hi: T) -> Self {
        self.upper(hi, true)
    }

    /// Writes the lower bound as `text` instead of its value.
    pub fn lower_text(mut self, text: impl Into<String>) -> Self {
        if let Some(lo) = &mut self.lo {
            lo.text = text.into();
        }
        self
    }

    /// Writes the upper bound as `text` instead of its value.
    pub fn upper_text(mut self, text: impl Into<String>) -> Self {
        if let Some(hi) = &mut self.hi {
            hi.text = text.into();
        }
        self
    }

    /// Names another accepted form of the field in the message.
    pub fn or(mut self, alternative: &'static str) -> Self {
        self.alternative = Some(alternative);
        self
    }

    fn lower(mut self, value: T, inclusive: bool) -> Self {
        let text = value.to_string();
        self.lo = Some(Limit {
            value,
            inclusive,
            text,
        });
        self
    }

    fn upper(mut self, value: T, inclusive: bool) -> Self {
        let text = value.to_string();
        self.hi = Some(Limit {
            value,
            inclusive,
            text,
        });
        self
    }

    /// Whether `v` lies within the bounds (false for NaN).
    pub fn contains(&self, v: T) -> bool {
        let above = self.lo.as_ref().is_none_or(|lo| {
            if lo.inclusive {
                v >= lo.value
            } else {
                v > lo.value
            }
        });
        let below = self.hi.as_ref().is_none_or(|hi| {
            if hi.inclusive {
                v <= hi.value
            } else {
                v < hi.value
            }
        });
        above && below
    }
}

impl<T> Display for Range<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let op = |limit: &Limit<T>| if limit.inclusive { "<=" } else { "<" };
        match (self.name, &self.lo, &self.hi) {
            (None, Some(lo), Some(hi)) => write!(f, "{} ..= {}", lo.text, hi.text)?,
            (Some(name), Some(lo), Some(hi)) => {
                write!(f, "{} {} {name} {} {}", lo.text, op(lo), op(hi), hi.text)?
            }
            (name, Some(lo), None) => {
                let ge = if lo.inclusive { ">=" } else { ">" };
                match name {
                    Some(name) => write!(f, "{name} {ge} {}", lo.text)?,
                    None => write!(f, "{ge} {}", lo.text)?,
                }
            }
            (name, None, Some(hi)) => {
                let name = name.map(|n| format!("{n} ")).unwrap_or_default();
                write!(f, "{name}{} {}", op(hi), hi.text)?
            }
            (_, None, None) => f.write_str("any value")?,
        }
        if let Some(alternative) = self.alternative {
            write!(f, ", or {alternative}")?;
        }
        Ok(())
    }
}

/// `value` if it is finite and in `range`; otherwise an error naming `field`, with `message`
/// and the range as the allowed values. Non-finite values get their own message.
pub(super) fn check_range<T: Number>(
    field: &str,
    value: T,
    range: Range<T>,
    message: &str,
) -> Result<T> {
    check_finite(field, value)?;
    check_within(field, value, range, message)
}

/// Like [`check_range`] without the finiteness check: NaN and infinities are out of range.
pub(super) fn check_within<T: Number>(
    field: &str,
    value: T,
    range: Range<T>,
    message: &str,
) -> Result<T> {
    if range.contains(value) {
        Ok(value)
    } else {
        Err(Error::invalid(field, value, message, range.to_string()))
    }
}

pub(super) fn check_finite<T: Number>(field: &str, v: T) -> Result<()> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(Error::invalid(
            field,
            v,
            "not a finite number",
            "a finite number",
        ))
    }
}

/// A sweep or list must not be empty.
pub(super) fn check_non_empty<T>(
    field: &str,
    list: &[T],
    message: &str,
    allowed: &str,
) -> Result<()> {
    if list.is_empty() {
        Err(Error::invalid(field, "[]", message, allowed))
    } else {
        Ok(())
    }
}

pub(super) fn check_mu(field: &str, mu: f64) -> Result<f64> {
    check_range(
        field,
        mu,
        Range::of("mu").gt(0.0),
        "the lubrication coefficient must be positive",
    )
}

pub(super) fn check_gamma(field: &str, gamma: f64) -> Result<f64> {
    check_range(
        field,
        gamma,
        Range::of("gamma").ge(1.0).le(MAX_GAMMA),
        "repulsion exponent out of range",
    )
}

pub(super) fn parse_expr(field: &str, text: &str) -> Result<Expr> {
    Expr::parse(text).map_err(|source| Error::Expression {
        field: field.to_string(),
        source_text: text.to_string(),
        source,
    })
}

/// Checks that a profile satisfies `ok` on [0, 1], sampled on a fine uniform grid with both ends
/// (a profile is an arbitrary expression, so sampling is the check that is possible);
/// `allowed` describes `ok` in the message.
pub(super) fn check_profile(
    field: &str,
    e: &Expr,
    allowed: &str,
    ok: impl Fn(f64) -> bool,
) -> Result<()> {
    const M: usize = 20_000;
    for x in (0..=M).map(|k| k as f64 / M as f64) {
        let v = e.eval(x, 0.0);
        if !ok(v) {
            return Err(Error::ProfileRange {
                field: field.to_string(),
                expression: e.source().to_string(),
                value: v,
                x,
                allowed: allowed.to_string(),
            });
        }
    }
    Ok(())
}
