//! Generation of the WGSL step kernel (`shaders/step.wgsl`, the twin of `crate::backend::cpu::step`).
//!
//! The shader is a template: the terms a plan leaves out are removed from the source (not
//! branched on at run time), the power `ratio^gamma`, the forcing function and the Gauss–Legendre
//! sum are generated, and the element type is f32 or f64. See the header of `shaders/step.wgsl`
//! for the markers and the bindings.

use std::fmt::Write as _;

use crate::backend::shared::control::{
    sequence_from_two, tableau_work, ENERGY_RTOL_F32, ENERGY_RTOL_F64, ENERGY_RTOL_PER_GAMMA_F32,
};
use crate::backend::shared::gaps::{
    GAP_FLOOR, GAP_FLOOR_F32, LN_GAP_FLOOR, LN_GAP_FLOOR_F32, LN_RATIO_SERIES, LOG_STORED_ROUNDING,
};
use crate::backend::Precision;
use crate::expr::{Expr, WgslFloat};
use crate::model::params::{Order, Sequence};
use crate::model::plan::MAX_INTEGER_GAMMA;
use roughlub_kernels::power::INTEGER_GAMMA_BITS;

/// The template (`shaders/step.wgsl`).
pub const STEP_TEMPLATE_WGSL: &str = include_str!("../../../shaders/step.wgsl");
/// The step control (`shaders/control.wgsl`, twin of `kernels/src/shared/control.rs`), appended
/// to the step kernel.
pub const CONTROL_WGSL: &str = include_str!("../../../shaders/control.wgsl");

/// Entry points of the generated kernel.
pub const BEGIN_ENTRY: &str = "begin_interval";
pub const ADVANCE_ENTRY: &str = "advance";
pub const GATHER_ENTRY: &str = "gather";
/// Workgroup size of the generated kernel (one invocation per member).
pub const STEP_WORKGROUP_SIZE: u32 = 64;

/// Binding numbers (all in group 0); see the header of `shaders/step.wgsl`. `DSTAR` exists
/// only with repulsion and `BONDED` (u32 per gap) only with clusters.
pub mod binding {
    pub const CONFIG: u32 = 0;
    pub const GAP_SETS: u32 = 1;
    pub const VEL_SETS: u32 = 2;
    pub const PARAMS: u32 = 3;
    pub const CONTROLS: u32 = 4;
    pub const SCRATCH: u32 = 5;
    pub const RUNNING: u32 = 6;
    pub const GATHERED_GAPS: u32 = 7;
    pub const DSTAR: u32 = 8;
    pub const BONDED: u32 = 9;
    pub const GATHERED_VEL: u32 = 10;
    pub const FORCING_PARAMS: u32 = 11;
    /// The partitioned kernel's (shaders/partitioned.wgsl): its cut (uniform), per-member
    /// trial-step state, per-segment values, and (clusters only) the bodies glued to the left wall.
    pub const PARTS: u32 = 12;
    pub const PSTATE: u32 = 13;
    pub const SEGS: u32 = 14;
    pub const GLUED: u32 = 15;
}

/// The time scheme compiled into the kernel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SchemeSpec {
    /// Rows of the extrapolation tableau a trial step computes at most: 0 for one plain Euler
    /// step (order 1, fixed steps), else max(columns, 2).
    pub rows: u32,
    /// The result is the tableau's T_kk (orders >= 2), else row k itself (order 1, adaptive).
    pub extrapolates: bool,
    /// Adaptive steps from the error estimate.
    pub adaptive: bool,
    /// Order chosen per member and step (`order = "auto"`).
    pub auto_order: bool,
    /// The extrapolated steps keep the exact Jacobian (`Plan::exact_jacobian`).
    pub exact_jacobian: bool,
    /// The tableau's rows take 2, 3, … substeps, not 1, 2, … (`sequence_from_two`; `of` takes
    /// 1, 2, …, `with_sequence` sets it).
    pub sequence_from_two: bool,
}

impl SchemeSpec {
    /// The scheme of a plan.
    pub fn of(order: Order, adaptive: bool) -> SchemeSpec {
        let plain = order == Order::Fixed(1) && !adaptive;
        SchemeSpec {
            rows: if plain {
                0
            } else {
                u32::from(order.columns()).max(2)
            },
            extrapolates: order != Order::Fixed(1),
            adaptive,
            auto_order: order == Order::Auto,
            exact_jacobian: false,
            sequence_from_two: false,
        }
    }

    /// The same scheme with the rows of `sequence`.
    pub fn with_sequence(self, sequence: Sequence) -> SchemeSpec {
        SchemeSpec {
            sequence_from_two: sequence_from_two(sequence == Sequence::FromTwo, self.extrapolates),
            ..self
        }
    }

    /// Whether a trial step builds the tableau (else it is one Euler step).
    pub fn tableau(&self) -> bool {
        self.rows > 0
    }

    /// Euler substeps of a trial step at most (the tableau's rows 1..=rows).
    pub fn substeps(&self) -> u32 {
        if self.tableau() {
            tableau_work(self.rows as u8, self.sequence_from_two) as u32
        } else {
            1
        }
    }
}

/// How G = ratio^gamma is evaluated in the kernel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum GammaSpec {
    /// The same integer gamma (<= `MAX_INTEGER_GAMMA`) for every member: a fixed chain of
    /// multiplications.
    Integer(u32),
    /// gamma read per member from the `gamma` field of the member parameters.
    PerMember,
}

/// What the generated kernel contains.
#[derive(Debug, Clone)]
pub struct KernelSpec {
    pub precision: Precision,
    /// Present iff the model has repulsion (d* and G).
    pub repulsion: Option<GammaSpec>,
    /// Whether some member has clusters (bonded gaps).
    pub clusters: bool,
    /// The forcing f(x, t) and the Gauss–Legendre nodes and weights on [-1, 1]; its symbolic
    /// parameters (`forcing_param(k)`) are read per member from binding 11.
    pub forcing: Option<(Expr, Vec<f64>, Vec<f64>)>,
    pub scheme: SchemeSpec,
}

fn wgsl_float(precision: Precision) -> WgslFloat {
    match precision {
        Precision::F32 => WgslFloat::F32,
        Precision::F64 => WgslFloat::F64,
    }
}

/// A finite literal of the given precision (`1.5lf`, `(-0.25f)`).
fn literal(v: f64, float: WgslFloat) -> String {
    assert!(v.is_finite(), "non-finite constant {v} in the step kernel");
    let (digits, suffix) = match float {
        WgslFloat::F64 => (format!("{:?}", v.abs()), "lf"),
        WgslFloat::F32 => (format!("{:?}", (v as f32).abs()), "f"),
    };
    if v.is_sign_negative() {
        format!("(-{digits}{suffix})")
    } else {
        format!("{digits}{suffix}")
    }
}

/// Straight-line `ratio^n` in the sequence of `crate::model::plan::powi_by_squaring` (the leading
/// `1.0 * base` is exact and left out), as statements ending in `return`.
fn integer_power_body(n: u32, out: &mut String) {
    if n == 0 {
        out.push_str("    return 1.0;\n");
        return;
    }
    out.push_str("    var base: real = r;\n");
    let mut have_result = false;
    let mut e = n;
    while e > 0 {
        if e & 1 == 1 {
            if have_result {
                out.push_str("    result = result * base;\n");
            } else {
                out.push_str("    var result: real = base;\n");
                have_result = true;
            }
        }
        e >>= 1;
        if e > 0 {
            out.push_str("    base = base * base;\n");
        }
    }
    out.push_str("    return result;\n");
}

/// The WGSL functions `power(r, gamma)` (G = r^gamma, evaluated as
/// `crate::model::plan::Power::of(gamma).apply(r)` does on the CPU) and `gamma_of(gamma)` for
/// `gamma`, in the element type `real` (which the caller declares, e.g. `alias real = f64;`).
/// With [`GammaSpec::PerMember`] in f64 they call `pow_f64` from `super::F64_MATH_WGSL`, which
/// the caller includes.
pub fn power_wgsl(gamma: GammaSpec, precision: Precision) -> String {
    let float = wgsl_float(precision);
    let mut out = String::new();
    match gamma {
        GammaSpec::Integer(n) => {
            let _ = writeln!(
                out,
                "// G = ratio^{n}: square and multiply (powi_by_squaring).\n\
                 fn power(r: real, gamma: real) -> real {{"
            );
            integer_power_body(n, &mut out);
            out.push_str("}\n\n");
            let _ = writeln!(
                out,
                "fn gamma_of(gamma: real) -> real {{\n    return {};\n}}\n",
                literal(n as f64, float)
            );
        }
        GammaSpec::PerMember => {
            // Power::of: integer 0 <= gamma <= MAX_INTEGER_GAMMA by square and multiply, else
            // exp(gamma ln r).
            let unrolled = "                 \
                 result = select(result, result * base, (e & 1u) == 1u);\n\
                 e = e >> 1u;\n\
                 base = select(base, base * base, e > 0u);\n"
                .repeat(INTEGER_GAMMA_BITS as usize);
            let real_pow = match precision {
                Precision::F32 => "exp(gamma * log(r))",
                Precision::F64 => "pow_f64(r, gamma)",
            };
            let max = literal(MAX_INTEGER_GAMMA as f64, float);
            let bits = INTEGER_GAMMA_BITS;
            let _ = writeln!(
                out,
                "// G = ratio^gamma with a per-member gamma, as Power::of(gamma).apply(ratio).\n\
                 fn power(r: real, gamma: real) -> real {{\n\
                 \x20   if gamma == floor(gamma) && gamma >= 0.0 && gamma <= {max} {{\n\
                 \x20       // The same multiplications as powi_by_squaring, unrolled over the {bits} bits of\n\
                 \x20       // gamma <= {MAX_INTEGER_GAMMA} with selects: no data-dependent loop (members with different\n\
                 \x20       // gammas do not diverge, and lavapipe's per-invocation loop budget is spared).\n\
                 \x20       var result: real = 1.0;\n\
                 \x20       var base: real = r;\n\
                 \x20       var e: u32 = u32(gamma);\n\
{unrolled}                 \x20       return result;\n\
                 \x20   }}\n\
                 \x20   return {real_pow};\n\
                 }}\n\n\
                 fn gamma_of(gamma: real) -> real {{\n    return gamma;\n}}\n"
            );
        }
    }
    out
}

/// The generated functions: `REAL_MAX`, `power`, `gamma_of`, `forcing`, `particle_force`.
fn generated(spec: &KernelSpec) -> String {
    let float = wgsl_float(spec.precision);
    let mut out = String::new();
    // The largest finite value (f32::MAX is exactly representable as an f64 literal).
    let max = match spec.precision {
        Precision::F32 => f32::MAX as f64,
        Precision::F64 => f64::MAX,
    };
    let _ = writeln!(out, "const REAL_MAX: real = {};", literal(max, float));
    let (floor, ln_floor, energy_rtol) = match spec.precision {
        Precision::F32 => (GAP_FLOOR_F32, LN_GAP_FLOOR_F32, ENERGY_RTOL_F32),
        Precision::F64 => (GAP_FLOOR, LN_GAP_FLOOR, ENERGY_RTOL_F64),
    };
    let _ = writeln!(out, "const GAP_FLOOR: real = {};", literal(floor, float));
    let epsilon = match spec.precision {
        Precision::F32 => f32::EPSILON as f64,
        Precision::F64 => f64::EPSILON,
    };
    let _ = writeln!(
        out,
        "const REAL_EPSILON: real = {};\nconst LOG_STORED_ROUNDING: real = {};",
        literal(epsilon, float),
        literal(LOG_STORED_ROUNDING, float)
    );
    let _ = writeln!(
        out,
        "const LN_GAP_FLOOR: real = {};",
        literal(ln_floor, float)
    );
    let _ = writeln!(
        out,
        "const ENERGY_RTOL: real = {};",
        literal(energy_rtol, float)
    );
    let _ = writeln!(
        out,
        "const TIME_RESOLUTION: real = {};",
        literal(spec.precision.time_resolution(), float)
    );
    let _ = writeln!(
        out,
        "const LN_RATIO_SERIES: real = {};\nconst ONE_DIVISION_RECIPROCALS: bool = {};\nconst EXTRAPOLATES: bool = {};\nconst EXACT_JACOBIAN: bool = {};\nconst SEQUENCE_FROM_TWO: bool = {};",
        literal(LN_RATIO_SERIES, float),
        spec.precision == Precision::F64,
        spec.scheme.extrapolates,
        spec.scheme.exact_jacobian,
        spec.scheme.sequence_from_two
    );
    let per_gamma = match spec.precision {
        Precision::F32 => ENERGY_RTOL_PER_GAMMA_F32,
        Precision::F64 => 0.0,
    };
    let _ = writeln!(
        out,
        "const ENERGY_RTOL_PER_GAMMA: real = {};\n",
        literal(per_gamma, float)
    );
    // exp and ln of `real`: WGSL's f64 exp/log are wrong on Vulkan (DESIGN.md §2).
    let (exp, ln) = match spec.precision {
        Precision::F32 => ("exp(x)", "log(x)"),
        Precision::F64 => ("exp_f64(x)", "log_f64(x)"),
    };
    let _ = writeln!(
        out,
        "fn exp_real(x: real) -> real {{\n    return {exp};\n}}\n\n\
         fn ln_real(x: real) -> real {{\n    return {ln};\n}}\n"
    );

    if let Some(gamma) = spec.repulsion {
        out.push_str(&power_wgsl(gamma, spec.precision));
    }

    if let Some((expr, nodes, weights)) = &spec.forcing {
        assert_eq!(
            nodes.len(),
            weights.len(),
            "Gauss–Legendre nodes and weights"
        );
        // The member whose forcing is evaluated (set by `euler` before its loop): the symbolic
        // parameters of a parameter study are that member's.
        out.push_str("var<private> forcing_member: u32;\n");
        let k = expr.symbolic_count();
        if k > 0 {
            let _ = writeln!(
                out,
                "@group(0) @binding({}) var<storage, read> forcing_params: array<real>;\n\
                 fn forcing_param(k: u32) -> real {{\n    return forcing_params[forcing_member * {k}u + k];\n}}",
                binding::FORCING_PARAMS
            );
        }
        out.push_str(&expr.to_wgsl(float, "forcing"));
        out.push('\n');
        // F_i = eps * sum_k w_k f(q + eps xi_k, t), unrolled, summed in the CPU's order.
        out.push_str(
            "// F = integral of f over the particle by Gauss–Legendre (particle_force).\n\
             fn particle_force(eps: real, t: real, q: real) -> real {\n\
             \x20   var s: real = 0.0;\n",
        );
        for (xi, w) in nodes.iter().zip(weights) {
            let _ = writeln!(
                out,
                "    s = s + {} * forcing(q + eps * {}, t);",
                literal(*w, float),
                literal(*xi, float)
            );
        }
        out.push_str("    return eps * s;\n}\n");
    }
    out
}

/// Whether the generated code calls the f64 math library: always in f64 (the gap update is
/// exp, the log-stored gaps need ln).
fn needs_f64_math(spec: &KernelSpec) -> bool {
    spec.precision == Precision::F64
}

/// Whether the kernel for `spec` keeps the template block `name`.
fn keeps_block(spec: &KernelSpec, name: &str) -> bool {
    match name {
        "REPULSION" => spec.repulsion.is_some(),
        "NOREPULSION" => spec.repulsion.is_none(),
        "CLUSTERS" => spec.clusters,
        "FREE" => !spec.clusters,
        "FORCING" => spec.forcing.is_some(),
        "EULER" => !spec.scheme.tableau(),
        "TABLEAU" => spec.scheme.tableau(),
        "ADAPTIVE" => spec.scheme.adaptive,
        "AUTO" => spec.scheme.auto_order,
        "FIXEDORDER" => !spec.scheme.auto_order,
        other => panic!("unknown block {other} in a step kernel template"),
    }
}

/// Keeps or removes the `//@BEGIN NAME` ... `//@END NAME` blocks of the template.
fn select_blocks(template: &str, keep: impl Fn(&str) -> bool) -> String {
    let mut out = String::with_capacity(template.len());
    // Stack of (name, kept) for the open blocks.
    let mut open: Vec<(&str, bool)> = Vec::new();
    for line in template.lines() {
        let trimmed = line.trim();
        if let Some(name) = trimmed.strip_prefix("//@BEGIN ") {
            let name = name.trim();
            open.push((name, keep(name)));
            continue;
        }
        if let Some(name) = trimmed.strip_prefix("//@END ") {
            let (open_name, _) = open.pop().expect("//@END without //@BEGIN in step.wgsl");
            assert_eq!(
                open_name,
                name.trim(),
                "mismatched block markers in step.wgsl"
            );
            continue;
        }
        if open.iter().all(|&(_, k)| k) {
            out.push_str(line);
            out.push('\n');
        }
    }
    assert!(open.is_empty(), "unterminated block in step.wgsl");
    out
}

/// The WGSL source of the step kernel for `spec` (entry points [`BEGIN_ENTRY`],
/// [`ADVANCE_ENTRY`], [`GATHER_ENTRY`]).
pub fn generate_step_wgsl(spec: &KernelSpec) -> String {
    let body = select_blocks(STEP_TEMPLATE_WGSL, |name| keeps_block(spec, name));
    let real = match spec.precision {
        Precision::F32 => "alias real = f32;",
        Precision::F64 => "alias real = f64;",
    };
    let generated = generated(spec);
    let mut out = String::with_capacity(body.len() + generated.len());
    for line in body.lines() {
        match line.trim() {
            "alias real = f64;" => out.push_str(real),
            "//@GENERATED" => out.push_str(&generated),
            _ => out.push_str(line),
        }
        out.push('\n');
    }
    out.push_str(CONTROL_WGSL);
    let body = out;
    if needs_f64_math(spec) {
        format!("{}\n{body}", super::F64_MATH_WGSL)
    } else {
        body
    }
}

/// The template of the partitioned kernel (`shaders/partitioned.wgsl`).
pub const PARTITIONED_TEMPLATE_WGSL: &str = include_str!("../../../shaders/partitioned.wgsl");

/// The WGSL source of the partitioned kernel for `spec`: the step kernel (whose functions it
/// calls) followed by `shaders/partitioned.wgsl` with the same blocks kept, and `TINY` (the
/// flush threshold of the spike: the CPU's in f64, one far above f32's smallest normal in f32).
pub fn generate_partitioned_wgsl(spec: &KernelSpec) -> String {
    let tiny = match spec.precision {
        Precision::F64 => crate::backend::shared::gaps::SPIKE_TINY,
        Precision::F32 => super::partitioned::SPIKE_TINY_F32,
    };
    format!(
        "{}\nconst TINY: real = {};\n\n{}",
        generate_step_wgsl(spec),
        literal(tiny, wgsl_float(spec.precision)),
        select_blocks(PARTITIONED_TEMPLATE_WGSL, |name| keeps_block(spec, name))
    )
}
