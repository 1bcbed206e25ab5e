//! One rung of `roughlub accuracy`'s ladder: the setting a run takes, and how it is named in
//! the printed lines, the CSV, the figure's legend and the scene lines that rerun it.

use crate::backend::{Backend, Precision};
use crate::model::params::{Jacobian, Order, Sequence, Stepping};

/// One rung of the ladder.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Setting {
    pub order: Order,
    pub stepping: Stepping,
    /// The tableau's rows (`[solver] sequence`; order 1 has none).
    pub sequence: Sequence,
    /// The scene's `[solver] jacobian` (every rung keeps it; `record` says which matrix ran).
    pub jacobian: Jacobian,
    pub backend: Backend,
    pub precision: Precision,
}

impl Setting {
    /// e.g. "order 2, tolerance 1e-6, cpu f64", or "order auto from_2, tolerance 1e-6, cpu f64".
    pub fn label(&self) -> String {
        let step = match self.stepping {
            Stepping::Fixed { dt, .. } => format!("dt {dt:e}"),
            Stepping::Adaptive { tolerance, .. } => format!("tolerance {tolerance:e}"),
        };
        format!(
            "order {}, {step}, {} {}",
            self.order_label(),
            backend_name(self.backend),
            self.precision.name()
        )
    }

    /// The order, and its sequence where that is not from_1 or the order is auto (measured with
    /// both in f64, and whose default depends on the precision): "order 4", "order 4 from_2",
    /// "order auto from_1", "order auto from_2".
    fn order_label(&self) -> String {
        match self.sequence.record(self.order) {
            "from_1" if self.order != Order::Auto => self.order.label(),
            sequence => format!("{} {sequence}", self.order.label()),
        }
    }

    /// The line of the work–precision figure it belongs to.
    pub(super) fn scheme(&self) -> String {
        let kind = match self.stepping {
            Stepping::Fixed { .. } => "fixed dt",
            Stepping::Adaptive { .. } => "adaptive",
        };
        format!(
            "order {} {kind}, {} {}",
            self.order_label(),
            backend_name(self.backend),
            self.precision.name()
        )
    }

    /// The scene's settings that run it, e.g. `[time] tolerance = 1e-6; [solver] order =
    /// "auto", sequence = "from_2", jacobian = "auto", backend = "cpu", precision = "f64"`.
    pub fn scene_lines(&self) -> String {
        let step = match self.stepping {
            Stepping::Fixed { dt, .. } => format!("dt = {dt:e}"),
            Stepping::Adaptive { tolerance, .. } => format!("tolerance = {tolerance:e}"),
        };
        let order = match self.order {
            Order::Fixed(p) => p.to_string(),
            Order::Auto => "\"auto\"".into(),
        };
        format!(
            "[time] {step}; [solver] order = {order}, sequence = \"{}\", jacobian = \"{}\", backend = \"{}\", precision = \"{}\"",
            self.sequence.record(self.order),
            self.jacobian.label(),
            backend_name(self.backend),
            self.precision.name()
        )
    }
}

pub(super) fn backend_name(b: Backend) -> &'static str {
    match b {
        Backend::Cpu => "cpu",
        Backend::Gpu => "gpu",
        Backend::Auto => "auto",
    }
}
