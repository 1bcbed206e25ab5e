//! The numbers that define one member's run: its physical parameters, how it steps, and which
//! observables are kept.

/// Per-member physical parameters.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MemberParams {
    pub mu: f64,
    pub gamma: f64,
}

/// How steps are chosen. Fixed: every member steps with `dt` (shortened to land on output times,
/// halved and retried when a step would close a gap). Adaptive: each member its own dt from a
/// local error estimate.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Stepping {
    Fixed {
        dt: f64,
        dt_min: f64,
    },
    Adaptive {
        tolerance: f64,
        dt_initial: f64,
        dt_min: f64,
    },
}

impl Stepping {
    pub fn dt_min(&self) -> f64 {
        match *self {
            Stepping::Fixed { dt_min, .. } | Stepping::Adaptive { dt_min, .. } => dt_min,
        }
    }

    /// The tolerance of adaptive steps; `None` for fixed steps.
    pub fn tolerance(&self) -> Option<f64> {
        match *self {
            Stepping::Fixed { .. } => None,
            Stepping::Adaptive { tolerance, .. } => Some(tolerance),
        }
    }
}

pub use roughlub_kernels::shared::control::MAX_ORDER;

/// The highest fixed order a run may ask for in f32. The Aitken–Neville weights of columns 7
/// and 8 carry about 1e-3 of f32 rounding into their error estimates (order 6: 1e-4): on the
/// N = 200 chain of docs/accuracy.md order 8 in f32 failed at tolerances 1e-4 (after a million
/// steps) to 1e-6 where order 6 completed at 1e-4 in 34 steps. (`auto` in f32 took the same
/// steps up to 8 as up to 6 there.)
pub const MAX_ORDER_F32: u8 = 6;

/// The matrix of the extrapolated steps (`[solver] jacobian`). In the variables (ln d, u) the
/// gap equation d(ln d_i)/dt = (u_i - u_{i-1})/d_i has the derivative -r_i in ln d_i. `Frozen`
/// drops it (a W-method: ln d_i' = ln d_i + h r_i'); `Exact` keeps it, as the factor
/// k_i = 1/(1 + h r_i) on opening gaps and a bounded form of it on closing ones
/// (`roughlub_kernels::step`'s `jacobian_factor`). Measured on the N = 200 random chain of
/// docs/accuracy.md: `Exact` takes 4 to 6 times fewer steps at tolerance 1e-10 (auto: 149
/// against 683) and restores order 2, but the paper's scenes at an error of 1e-3 need 1.3 to 3
/// times more work with it, and with repulsion its steps are never certified (each row's end
/// computes its energy). `Auto` (the default) takes `Exact` for adaptive steps at
/// tolerances up to [`EXACT_JACOBIAN_TOLERANCE`], else `Frozen`. Order 1 always keeps the
/// frozen matrix and its energy certificate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Jacobian {
    #[default]
    Auto,
    Exact,
    Frozen,
}

/// The tolerance at and below which `jacobian = "auto"` keeps the exact Jacobian. Away from
/// contact the two matrices cost about the same above it (the N = 200 chain: auto at 1e-6
/// 0.003 s either way, at 1e-7 0.006 s and 9.6e-8 exact against 0.005 s and 1.3e-7 frozen)
/// and `Exact` pays below it (1e-10: 0.022 s against 0.083 s). Near contact (a random N = 300
/// chain with gaps to ln d = -27, checked against scipy's Radau) `Exact`'s errors add up over
/// the steps to 3 to 16 times the tolerance from 1e-4 to 3.16e-8 (its local estimates are
/// honest: their sum bounds the error) while `Frozen`'s stay within 2 times; at 1e-8 and below
/// `Exact` is within 2 times as well and `Frozen` needs 3.5 to 9.4 times its steps. With the
/// switch at 1e-7 the error there rose from 3.3e-7 at 3.16e-7 to 5.6e-7 at 1e-7. Deeper in
/// contact (the same chain at mu 1e-3) `Exact` errs by up to 10 times the tolerance down to
/// 1e-9 and the rise moves to 1e-8 (2.5e-8 at 3.16e-8, 9.2e-8 at 1e-8): docs/accuracy.md says
/// to set `Frozen` there (docs/scipy_comparison/tolerance_check.py measures all of this).
pub const EXACT_JACOBIAN_TOLERANCE: f64 = 1e-8;

impl Jacobian {
    /// Whether a run of `order` with `stepping` keeps the exact Jacobian.
    pub fn is_exact(self, order: Order, stepping: Stepping) -> bool {
        order != Order::Fixed(1)
            && match self {
                Jacobian::Exact => true,
                Jacobian::Frozen => false,
                Jacobian::Auto => matches!(
                    stepping,
                    Stepping::Adaptive { tolerance, .. } if tolerance <= EXACT_JACOBIAN_TOLERANCE
                ),
            }
    }

    /// "auto", "exact" or "frozen", as a scene writes it (the names scenes and the command line
    /// parse).
    pub fn label(self) -> String {
        use clap::ValueEnum;
        self.to_possible_value()
            .expect("every variant has a name")
            .get_name()
            .to_string()
    }

    /// What the manifests record: the matrix the run used, "exact" or "frozen".
    pub fn record(self, order: Order, stepping: Stepping) -> &'static str {
        if self.is_exact(order, stepping) {
            "exact"
        } else {
            "frozen"
        }
    }
}

/// The substeps of the extrapolation tableau's rows, as a run takes them: 1, 2, 3, … or 2, 3,
/// 4, … (`roughlub_kernels::shared::control::sequence_from_two`). A scene asks for one with
/// [`SequenceChoice`]; a [`Plan`](crate::model::plan::Plan) holds the one that runs (`FromOne`
/// where a plan is built without a scene).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub enum Sequence {
    #[default]
    #[serde(rename = "from_1")]
    FromOne,
    #[serde(rename = "from_2")]
    FromTwo,
}

impl Sequence {
    /// The sequence a run of `order` takes: order 1 has no tableau, so always from_1.
    pub fn of(self, order: Order) -> Sequence {
        if order == Order::Fixed(1) {
            Sequence::FromOne
        } else {
            self
        }
    }

    /// What the manifests record: the rows the run's extrapolated steps took, "from_1" or
    /// "from_2" (order 1 always "from_1").
    pub fn record(self, order: Order) -> &'static str {
        match self.of(order) {
            Sequence::FromTwo => "from_2",
            Sequence::FromOne => "from_1",
        }
    }
}

/// `[solver] sequence` as a scene asks for it. `Auto` (the default) takes `FromTwo` for
/// `order = "auto"` with adaptive steps in f64 and `FromOne` otherwise. Measured
/// (docs/accuracy.md): with auto's adaptive steps in f64 the rows from 2 met an error of 3e-8
/// on the N = 200 random chain in 1.3-1.5 times less time, took fewer steps at every tolerance
/// on the near-contact chain of `tolerance_check.py` (N = 300, gaps to ln d = -27), and met
/// 1e-3 on the paper's four cases in 13 steps where from_1 took 16-20 (two shipped scenes
/// met it slightly cheaper with from_1 and name it); in collisions with little lubrication
/// (`docs/work_precision_extreme.toml`) they cost the same down to 1e-8 and 1.2 times more at
/// 1e-9, and on the extremes matrix at 1e-6 1.0-1.3 times more at the same tolerance. In f32
/// their weights amplify the rows' rounding ~3 times more (its error stopped following the
/// tolerance), and with fixed steps (or a fixed order) a step costs p(p+3)/2
/// substeps instead of p(p+1)/2 for 2.5-3.5 times less error, about even or worse at a given
/// error: there `FromOne`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum, serde::Serialize)]
pub enum SequenceChoice {
    #[default]
    #[value(name = "auto")]
    #[serde(rename = "auto")]
    Auto,
    #[value(name = "from_1")]
    #[serde(rename = "from_1")]
    FromOne,
    #[value(name = "from_2")]
    #[serde(rename = "from_2")]
    FromTwo,
}

impl SequenceChoice {
    /// The sequence a run of `order` with `stepping` in `precision` takes.
    pub fn resolve(
        self,
        order: Order,
        stepping: Stepping,
        precision: crate::backend::Precision,
    ) -> Sequence {
        let chosen = match self {
            SequenceChoice::FromOne => Sequence::FromOne,
            SequenceChoice::FromTwo => Sequence::FromTwo,
            SequenceChoice::Auto => {
                let adaptive = matches!(stepping, Stepping::Adaptive { .. });
                if order == Order::Auto && adaptive && precision == crate::backend::Precision::F64 {
                    Sequence::FromTwo
                } else {
                    Sequence::FromOne
                }
            }
        };
        chosen.of(order)
    }
}

/// The order of the time scheme: the linearly implicit Euler step (1) or its extrapolation from
/// 1, 2, …, p substeps (Aitken–Neville; order p), fixed for the run; or chosen per member and
/// step by the work per unit step (`Auto`, adaptive steps only, orders 2..=MAX_ORDER).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Order {
    Fixed(u8),
    Auto,
}

impl Order {
    /// Rows of the tableau a step may need: the fixed order, or MAX_ORDER.
    pub fn columns(self) -> u8 {
        match self {
            Order::Fixed(p) => p,
            Order::Auto => MAX_ORDER,
        }
    }

    /// The order a member starts with. Auto starts where its tolerance will take it (the start
    /// of Hairer and Wanner's ODEX and SEULEX: about 0.6 columns per decade, clamped to
    /// [`AUTO_INITIAL_ORDERS`]): starting low made the first step fail at dt_initial and the
    /// controller spend 3 rejections and a handful of short steps climbing (on the scipy
    /// comparison's chain 40 + 3 steps at 3.16e-8, 36 + 0 from the order of the tolerance).
    pub fn initial(self, stepping: &Stepping) -> u8 {
        match (self, stepping) {
            (Order::Fixed(p), _) => p,
            (Order::Auto, Stepping::Adaptive { tolerance, .. }) => {
                let by_tolerance = (-tolerance.log10() * 0.6 + 1.5).floor();
                let (low, high) = AUTO_INITIAL_ORDERS;
                by_tolerance.clamp(f64::from(low), f64::from(high)) as u8
            }
            (Order::Auto, Stepping::Fixed { .. }) => AUTO_INITIAL_ORDERS.0,
        }
    }

    /// Whether a run in f32 may take this order (fixed orders up to [`MAX_ORDER_F32`], or auto).
    pub fn runs_in_f32(self) -> bool {
        match self {
            Order::Fixed(p) => p <= MAX_ORDER_F32,
            Order::Auto => true,
        }
    }

    /// The tightest tolerance an adaptive run in f32 may ask for with this order and sequence:
    /// where column max(k, 3) of a fixed order k (column 3 for auto) carries
    /// `F32_ROUNDING_MARGIN` = 10 times less f32 rounding than the tolerance, by the rule that
    /// caps auto's columns (`top_column`): 10 · 2^-23 times the column's rounding gain
    /// (`extrapolation_rounding_gain`), 2.63e-5 for orders 1 to 3 and auto, 1.09e-4 for order 4,
    /// 1.73e-3 for order 6 (from 2: 7.52e-5, 3.29e-4, 5.49e-3). Below it the rounding the steps
    /// leave in the state adds up to more than the tolerance: on the paper's case 2a auto at 1e-5
    /// erred 13 times the tolerance and order 2 at 1e-6 on case 3 32 times, the lower columns
    /// taking thousands of steps (docs/backends-and-precision.md). Without the margin, below the
    /// column's own rounding, the steps shrank without end (on an N = 50 chain to t = 0.05: order
    /// 1 at 1e-7, order 4 at 1e-6 and order 6 at 1e-5 had not finished after 30 s).
    pub fn f32_tolerance_floor(self, sequence: Sequence) -> f64 {
        use roughlub_kernels::shared::control::f32_column_floor;
        let column = match self {
            Order::Fixed(p) => p.max(3),
            Order::Auto => 3,
        };
        let from_two = sequence.of(self) == Sequence::FromTwo;
        f32_column_floor(column, from_two)
    }

    /// "1".."8" or "auto", as a scene writes it.
    pub fn label(self) -> String {
        match self {
            Order::Fixed(p) => p.to_string(),
            Order::Auto => "auto".into(),
        }
    }
}

/// A fixed order.
impl From<u8> for Order {
    fn from(p: u8) -> Order {
        Order::Fixed(p)
    }
}

/// The orders `order = "auto"` may start at (see [`Order::initial`]): up to 6, the largest an f32
/// run takes.
pub const AUTO_INITIAL_ORDERS: (u8, u8) = (3, MAX_ORDER_F32);

impl serde::Serialize for Order {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Order::Fixed(p) => s.serialize_u8(*p),
            Order::Auto => s.serialize_str("auto"),
        }
    }
}

/// Which observables are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct OutputFields {
    pub gaps: bool,
    pub velocities: bool,
    pub rho: bool,
    pub u: bool,
    pub rho_star: bool,
    pub energy: bool,
}

impl OutputFields {
    pub fn all() -> OutputFields {
        OutputFields::uniform(true)
    }
    pub fn none() -> OutputFields {
        OutputFields::uniform(false)
    }
    fn uniform(on: bool) -> OutputFields {
        OutputFields {
            gaps: on,
            velocities: on,
            rho: on,
            u: on,
            rho_star: on,
            energy: on,
        }
    }
}

pub const FIELD_NAMES: [&str; 6] = ["gaps", "velocities", "rho", "u", "rho_star", "energy"];
