//! Scalar expressions of `x` (position) and `t` (time), as written in scene files for initial
//! profiles and forcing, e.g. `"0.3*sin(2*pi*x)*cos(3*t)"` or
//! `"0.6+0.2*exp(-(x-0.5)^2/(2*0.1^2))"`.
//!
//! One parsed [`Expr`] serves both backends: [`Expr::eval`] on the CPU and [`Expr::to_wgsl`] for a
//! generated WGSL function on the GPU.
//!
//! Grammar (whitespace is ignored):
//!
//! ```text
//! expr    := term (('+' | '-') term)*
//! term    := unary (('*' | '/') unary)*
//! unary   := ('-' | '+') unary | power
//! power   := primary ('^' unary)?          -- right-associative, binds tighter than unary minus
//! primary := number | 'x' | 't' | 'pi' | 'e' | func '(' expr (',' expr)* ')' | '(' expr ')'
//! func    := sin | cos | tan | exp | log | sqrt | abs | tanh      (1 argument)
//!          | min | max                                             (2 arguments)
//! number  := digits ['.' digits] [('e' | 'E') ['+' | '-'] digits]   (also "5." and ".5")
//! ```
//!
//! so `-x^2` is `-(x^2)`, `2^3^2` is `2^9` and `2^-1` is `0.5`. `log` is the natural logarithm.
//! Sub-trees that depend on neither `x` nor `t` are folded into [`Node::Num`] while parsing, with
//! the same f64 operations that [`Expr::eval`] uses, so folding never changes a value.
//!
//! The lexer and parser are in `parse`, the WGSL emission in `wgsl`.

mod parse;
mod wgsl;

use std::fmt;

pub use wgsl::WgslFloat;

/// A parsed expression of `x` and `t`: the (constant-folded) tree and the text it came from.
///
/// Named parameters (`[parameters]` of a scene, e.g. `A` in `"A*sin(2*pi*x)"`) are replaced by
/// their values while parsing ([`Expr::parse_with`]), so an expression with a parameter folds and
/// evaluates exactly like the one with the literal value, on the CPU and in the generated WGSL.
/// A study that sweeps a parameter rebinds the expression to each point's values
/// ([`Expr::rebind`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Expr {
    root: Node,
    source: String,
    /// The named parameters it uses, in order of first use.
    params_used: Vec<String>,
}

/// Binary operators.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BinOp {
    Add,
    Sub,
    Mul,
    Div,
    Pow,
}

/// Built-in functions. `Min` and `Max` take two arguments, the others one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Func {
    Sin,
    Cos,
    Tan,
    Exp,
    Log,
    Sqrt,
    Abs,
    Tanh,
    Min,
    Max,
}

/// A node of the expression tree.
#[derive(Debug, Clone, PartialEq)]
pub enum Node {
    Num(f64),
    X,
    T,
    Neg(Box<Node>),
    Bin(BinOp, Box<Node>, Box<Node>),
    /// A function call; the argument count always equals [`Func::arity`] for trees built by
    /// [`Expr::parse`].
    Call(Func, Vec<Node>),
    /// Parameter k of the member, read at run time ([`Expr::parse_symbolic`]): a study sweeping a
    /// forcing parameter keeps members of many points in one batch.
    Param(usize),
}

/// A parse error, with the 0-based character offset of the offending token in the source.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("at position {position}: {message}")]
pub struct ExprError {
    pub position: usize,
    pub message: String,
}

impl Func {
    /// All functions, in declaration order.
    pub const ALL: [Func; 10] = [
        Func::Sin,
        Func::Cos,
        Func::Tan,
        Func::Exp,
        Func::Log,
        Func::Sqrt,
        Func::Abs,
        Func::Tanh,
        Func::Min,
        Func::Max,
    ];

    /// The name used in expressions (`"sin"`, …).
    pub fn name(self) -> &'static str {
        match self {
            Func::Sin => "sin",
            Func::Cos => "cos",
            Func::Tan => "tan",
            Func::Exp => "exp",
            Func::Log => "log",
            Func::Sqrt => "sqrt",
            Func::Abs => "abs",
            Func::Tanh => "tanh",
            Func::Min => "min",
            Func::Max => "max",
        }
    }

    /// Number of arguments: 2 for `min` and `max`, 1 otherwise.
    pub fn arity(self) -> usize {
        match self {
            Func::Min | Func::Max => 2,
            _ => 1,
        }
    }

    /// Looks a function up by its expression name.
    pub fn from_name(name: &str) -> Option<Func> {
        Func::ALL.into_iter().find(|f| f.name() == name)
    }

    /// Applies the function with plain f64 semantics; `b` is ignored by one-argument functions.
    #[inline]
    pub fn apply(self, a: f64, b: f64) -> f64 {
        match self {
            Func::Sin => a.sin(),
            Func::Cos => a.cos(),
            Func::Tan => a.tan(),
            Func::Exp => a.exp(),
            Func::Log => a.ln(),
            Func::Sqrt => a.sqrt(),
            Func::Abs => a.abs(),
            Func::Tanh => a.tanh(),
            Func::Min => a.min(b),
            Func::Max => a.max(b),
        }
    }
}

impl BinOp {
    /// The operator as written in expressions.
    pub fn symbol(self) -> char {
        match self {
            BinOp::Add => '+',
            BinOp::Sub => '-',
            BinOp::Mul => '*',
            BinOp::Div => '/',
            BinOp::Pow => '^',
        }
    }

    /// Applies the operator with plain f64 semantics (`Pow` is `f64::powf`).
    #[inline]
    pub fn apply(self, a: f64, b: f64) -> f64 {
        match self {
            BinOp::Add => a + b,
            BinOp::Sub => a - b,
            BinOp::Mul => a * b,
            BinOp::Div => a / b,
            BinOp::Pow => a.powf(b),
        }
    }
}

impl Node {
    /// Evaluates the tree at (x, t) with symbolic parameters `p` (a missing one is NaN).
    /// Recursive, allocation-free.
    pub fn eval(&self, x: f64, t: f64, p: &[f64]) -> f64 {
        match self {
            Node::Num(v) => *v,
            Node::X => x,
            Node::T => t,
            Node::Param(k) => p.get(*k).copied().unwrap_or(f64::NAN),
            Node::Neg(a) => -a.eval(x, t, p),
            Node::Bin(op, a, b) => op.apply(a.eval(x, t, p), b.eval(x, t, p)),
            Node::Call(f, args) => match args.as_slice() {
                [a] => f.apply(a.eval(x, t, p), 0.0),
                [a, b] => f.apply(a.eval(x, t, p), b.eval(x, t, p)),
                _ => f64::NAN,
            },
        }
    }

    fn uses(&self, var: &Node) -> bool {
        match self {
            Node::Num(_) => false,
            Node::X | Node::T | Node::Param(_) => self == var,
            Node::Neg(a) => a.uses(var),
            Node::Bin(_, a, b) => a.uses(var) || b.uses(var),
            Node::Call(_, args) => args.iter().any(|a| a.uses(var)),
        }
    }
}

impl Expr {
    /// Parses an expression (see the module documentation for the grammar).
    ///
    /// Errors carry the 0-based character offset of the offending token: empty input, unexpected
    /// character, malformed or out-of-range number, unknown identifier, function not followed by
    /// `(`, wrong argument count, unclosed or unmatched parenthesis, missing operand, trailing
    /// input, nesting deeper than 256.
    pub fn parse(src: &str) -> Result<Expr, ExprError> {
        Expr::parse_with(src, &[])
    }

    /// Parses with named parameters: each `(name, value)` may appear in the expression and is
    /// replaced by `value` (then folded like a literal). An identifier that is neither a known
    /// name nor a parameter is an error listing both.
    pub fn parse_with(src: &str, params: &[(String, f64)]) -> Result<Expr, ExprError> {
        Expr::parse_symbolic(src, params, &[])
    }

    /// Like [`parse_with`](Self::parse_with), with the parameters named in `symbolic` left as
    /// [`Node::Param`]`(k)` (k their index there), read from the slice given to
    /// [`eval_with`](Self::eval_with) (and, in WGSL, from `forcing_param(k)`). The operations
    /// around them are those the literal would get, in the same order, so a symbolic parameter
    /// gives the literal's value bit for bit in f64.
    pub fn parse_symbolic(
        src: &str,
        params: &[(String, f64)],
        symbolic: &[String],
    ) -> Result<Expr, ExprError> {
        let (root, params_used) = parse::parse_tree(src, params, symbolic)?;
        Ok(Expr {
            root,
            source: src.to_string(),
            params_used,
        })
    }

    /// The same text with other parameter values (every parameter it uses must be in `params`).
    pub fn rebind(&self, params: &[(String, f64)]) -> Result<Expr, ExprError> {
        if self.params_used.is_empty() {
            return Ok(self.clone());
        }
        Expr::parse_with(&self.source, params)
    }

    /// The named parameters the expression uses.
    pub fn params_used(&self) -> &[String] {
        &self.params_used
    }

    /// Whether `name` is reserved (a variable, constant or function of the expression language)
    /// and so cannot name a parameter.
    pub fn is_reserved_name(name: &str) -> bool {
        parse::RESERVED_NAMES.contains(&name)
    }

    /// The text the expression was parsed from.
    pub fn source(&self) -> &str {
        &self.source
    }

    /// The root of the (constant-folded) tree.
    pub fn root(&self) -> &Node {
        &self.root
    }

    /// Evaluates at (x, t) with plain f64 semantics (`log(-1)` is NaN, `1/0` is inf, …).
    #[inline]
    pub fn eval(&self, x: f64, t: f64) -> f64 {
        self.root.eval(x, t, &[])
    }

    /// Evaluates at (x, t) with the values `p` of its symbolic parameters.
    #[inline]
    pub fn eval_with(&self, x: f64, t: f64, p: &[f64]) -> f64 {
        self.root.eval(x, t, p)
    }

    /// How many symbolic parameters the tree reads (the largest index + 1).
    pub fn symbolic_count(&self) -> usize {
        fn walk(n: &Node) -> usize {
            match n {
                Node::Param(k) => k + 1,
                Node::Num(_) | Node::X | Node::T => 0,
                Node::Neg(a) => walk(a),
                Node::Bin(_, a, b) => walk(a).max(walk(b)),
                Node::Call(_, args) => args.iter().map(walk).max().unwrap_or(0),
            }
        }
        walk(&self.root)
    }

    /// Whether the value depends on `x`.
    pub fn uses_x(&self) -> bool {
        self.root.uses(&Node::X)
    }

    /// Whether the value depends on `t`.
    pub fn uses_t(&self) -> bool {
        self.root.uses(&Node::T)
    }

    /// The value when the expression depends on neither `x` nor `t` (may be NaN or infinite,
    /// e.g. for `log(-1)`), `None` otherwise.
    pub fn constant_value(&self) -> Option<f64> {
        match self.root {
            Node::Num(v) => Some(v),
            _ if !self.uses_x() && !self.uses_t() && self.symbolic_count() == 0 => {
                Some(self.eval(0.0, 0.0))
            }
            _ => None,
        }
    }
}

impl fmt::Display for Expr {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.source)
    }
}

impl std::str::FromStr for Expr {
    type Err = ExprError;
    fn from_str(s: &str) -> Result<Expr, ExprError> {
        Expr::parse(s)
    }
}

/// Serialized as its source text.
impl serde::Serialize for Expr {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(&self.source)
    }
}

/// Deserialized from a string (parsed) or from a number (a constant expression).
impl<'de> serde::Deserialize<'de> for Expr {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct V;
        impl serde::de::Visitor<'_> for V {
            type Value = Expr;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("an expression of x and t (string) or a number")
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<Expr, E> {
                Expr::parse(v).map_err(|e| E::custom(format!("expression {v:?}: {e}")))
            }
            fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<Expr, E> {
                Ok(Expr {
                    root: Node::Num(v),
                    source: format!("{v:?}"),
                    params_used: Vec::new(),
                })
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<Expr, E> {
                Ok(Expr {
                    root: Node::Num(v as f64),
                    source: v.to_string(),
                    params_used: Vec::new(),
                })
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<Expr, E> {
                Ok(Expr {
                    root: Node::Num(v as f64),
                    source: v.to_string(),
                    params_used: Vec::new(),
                })
            }
        }
        deserializer.deserialize_any(V)
    }
}

#[cfg(test)]
mod parameter_tests {
    use super::*;

    fn params(list: &[(&str, f64)]) -> Vec<(String, f64)> {
        list.iter().map(|(n, v)| (n.to_string(), *v)).collect()
    }

    /// A parameter folds exactly like its literal: the trees are equal node for node, so values
    /// agree bit for bit at every (x, t), and so does the generated WGSL.
    #[test]
    fn a_parameter_is_its_literal() {
        let p = params(&[("A", 0.37), ("k", 3.0)]);
        let with = Expr::parse_with("A*sin(k*pi*x)*exp(-t/A) + A^2", &p).unwrap();
        let literal = Expr::parse("0.37*sin(3.0*pi*x)*exp(-t/0.37) + 0.37^2").unwrap();
        assert_eq!(with.root(), literal.root());
        assert_eq!(with.params_used(), ["A", "k"]);
        for (x, t) in [(0.1, 0.0), (0.73, 0.4), (0.999, 2.5)] {
            assert_eq!(with.eval(x, t).to_bits(), literal.eval(x, t).to_bits());
        }
        for float in [WgslFloat::F32, WgslFloat::F64] {
            assert_eq!(with.to_wgsl(float, "f"), literal.to_wgsl(float, "f"));
        }
    }

    #[test]
    fn rebinding_changes_only_the_values() {
        let e = Expr::parse_with("A*x", &params(&[("A", 2.0)])).unwrap();
        let r = e.rebind(&params(&[("A", 5.0)])).unwrap();
        assert_eq!(r.eval(0.5, 0.0), 2.5);
        assert_eq!(r.source(), "A*x");
        let plain = Expr::parse("2*x").unwrap();
        assert_eq!(plain.rebind(&params(&[("A", 5.0)])).unwrap(), plain);
    }

    #[test]
    fn an_unknown_name_lists_the_parameters() {
        let e = Expr::parse_with("B*x", &params(&[("A", 1.0)])).unwrap_err();
        assert!(e.message.contains("unknown identifier 'B'"), "{e}");
        assert!(e.message.contains("parameters: A"), "{e}");
        assert!(Expr::is_reserved_name("pi") && Expr::is_reserved_name("x"));
        assert!(!Expr::is_reserved_name("A"));
    }
}

#[cfg(test)]
mod symbolic_tests {
    use super::*;

    /// A symbolic parameter, read at run time, gives the literal's value bit for bit: the same
    /// f64 operations in the same order (the literal's are folded while parsing).
    #[test]
    fn a_symbolic_parameter_is_its_literal() {
        let names = vec!["A".to_string(), "k".to_string()];
        let sym = Expr::parse_symbolic("A*sin(k*pi*x)*exp(-t/A) + 2*A", &[], &names).unwrap();
        let lit = Expr::parse("0.37*sin(3.0*pi*x)*exp(-t/0.37) + 2*0.37").unwrap();
        assert_eq!(sym.symbolic_count(), 2);
        assert_eq!(sym.params_used(), ["A", "k"]);
        for (x, t) in [(0.1, 0.0), (0.73, 0.4), (0.999, 2.5)] {
            let a = sym.eval_with(x, t, &[0.37, 3.0]);
            assert_eq!(a.to_bits(), lit.eval(x, t).to_bits(), "x = {x}, t = {t}");
        }
        assert!(
            sym.eval(0.5, 0.0).is_nan(),
            "a missing parameter is NaN, never 0"
        );
        assert!(sym.constant_value().is_none());
        let wgsl = sym.to_wgsl(WgslFloat::F64, "forcing");
        assert!(
            wgsl.contains("forcing_param(0u)") && wgsl.contains("forcing_param(1u)"),
            "{wgsl}"
        );
    }
}
