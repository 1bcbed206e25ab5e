//! Lexer and recursive-descent parser for the grammar in the module documentation of
//! [`crate::expr`]. Constant sub-trees are folded while parsing.

use super::{BinOp, ExprError, Func, Node};

/// Deepest nesting of parentheses / unary operators and deepest tree accepted by the parser
/// (keeps the recursive parser, evaluator and destructor far from any stack limit).
const MAX_DEPTH: usize = 256;

/// Listed in the message for an unknown identifier.
const KNOWN_NAMES: &str = "x, t, pi, e, sin, cos, tan, exp, log, sqrt, abs, tanh, min, max";

/// Names an expression may not use for a parameter: its variables, constants and functions.
pub(super) const RESERVED_NAMES: [&str; 14] = [
    "x", "t", "pi", "e", "sin", "cos", "tan", "exp", "log", "sqrt", "abs", "tanh", "min", "max",
];

/// Parses `src` into a constant-folded tree, with each named parameter replaced by its value
/// (so it folds exactly as the literal would); the errors are those listed on
/// [`Expr::parse`](super::Expr::parse). Returns the tree and the parameters it uses.
pub(super) fn parse_tree(
    src: &str,
    params: &[(String, f64)],
    symbolic: &[String],
) -> Result<(Node, Vec<String>), ExprError> {
    let tokens = lex(src)?;
    if tokens.len() == 1 {
        return Err(err(0, "empty expression".to_string()));
    }
    let mut p = Parser {
        tokens,
        pos: 0,
        nesting: 0,
        params,
        symbolic,
        used: Vec::new(),
    };
    let root = p.expr()?;
    let tok = p.peek();
    if tok.kind != Tok::End {
        let message = if tok.kind == Tok::RParen {
            "unmatched closing parenthesis ')'".to_string()
        } else {
            format!(
                "unexpected {} after a complete expression (expected an operator)",
                tok.kind.describe()
            )
        };
        return Err(err(tok.pos, message));
    }
    Ok((root.node, p.used))
}

fn err(position: usize, message: String) -> ExprError {
    ExprError { position, message }
}

// ---------------------------------------------------------------------------------------------
// Lexer

#[derive(Debug, Clone, PartialEq)]
enum Tok {
    Num(f64),
    Ident(String),
    Plus,
    Minus,
    Star,
    Slash,
    Caret,
    LParen,
    RParen,
    Comma,
    End,
}

impl Tok {
    fn describe(&self) -> String {
        match self {
            Tok::Num(v) => format!("number {v}"),
            Tok::Ident(s) => format!("'{s}'"),
            Tok::Plus => "'+'".to_string(),
            Tok::Minus => "'-'".to_string(),
            Tok::Star => "'*'".to_string(),
            Tok::Slash => "'/'".to_string(),
            Tok::Caret => "'^'".to_string(),
            Tok::LParen => "'('".to_string(),
            Tok::RParen => "')'".to_string(),
            Tok::Comma => "','".to_string(),
            Tok::End => "end of input".to_string(),
        }
    }
}

#[derive(Debug, Clone)]
struct Token {
    kind: Tok,
    /// 0-based character offset.
    pos: usize,
}

/// Splits `src` into tokens; the last one is always `Tok::End` at the character length.
fn lex(src: &str) -> Result<Vec<Token>, ExprError> {
    let chars: Vec<char> = src.chars().collect();
    let mut tokens = Vec::new();
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        let start = i;
        let simple = match c {
            '+' => Some(Tok::Plus),
            '-' => Some(Tok::Minus),
            '*' => Some(Tok::Star),
            '/' => Some(Tok::Slash),
            '^' => Some(Tok::Caret),
            '(' => Some(Tok::LParen),
            ')' => Some(Tok::RParen),
            ',' => Some(Tok::Comma),
            _ => None,
        };
        if let Some(kind) = simple {
            tokens.push(Token { kind, pos: start });
            i += 1;
        } else if c.is_whitespace() {
            i += 1;
        } else if c.is_ascii_digit() || c == '.' {
            let (value, end) = lex_number(&chars, start)?;
            tokens.push(Token {
                kind: Tok::Num(value),
                pos: start,
            });
            i = end;
        } else if c.is_ascii_alphabetic() || c == '_' {
            while i < chars.len() && (chars[i].is_ascii_alphanumeric() || chars[i] == '_') {
                i += 1;
            }
            tokens.push(Token {
                kind: Tok::Ident(chars[start..i].iter().collect()),
                pos: start,
            });
        } else {
            return Err(err(start, format!("unexpected character {c:?}")));
        }
    }
    tokens.push(Token {
        kind: Tok::End,
        pos: chars.len(),
    });
    Ok(tokens)
}

/// Lexes a number starting at `start` (a digit or '.'); returns its value and end offset.
fn lex_number(chars: &[char], start: usize) -> Result<(f64, usize), ExprError> {
    let text = |end: usize| -> String { chars[start..end].iter().collect() };
    let is_digit = |i: usize| chars.get(i).is_some_and(|c| c.is_ascii_digit());
    let mut i = start;
    // Mantissa: take every digit and '.', so that "1.2.3" is reported as one malformed number.
    while i < chars.len() && (chars[i].is_ascii_digit() || chars[i] == '.') {
        i += 1;
    }
    let mantissa = text(i);
    let dots = mantissa.matches('.').count();
    if dots > 1 {
        return Err(err(
            start,
            format!("invalid number '{mantissa}': more than one decimal point"),
        ));
    }
    if !mantissa.chars().any(|c| c.is_ascii_digit()) {
        return Err(err(start, "invalid number '.': no digits".to_string()));
    }
    if matches!(chars.get(i), Some('e' | 'E')) {
        let mut j = i + 1;
        if matches!(chars.get(j), Some('+' | '-')) {
            j += 1;
        }
        if !is_digit(j) {
            return Err(err(
                start,
                format!("invalid number '{}': exponent has no digits", text(j)),
            ));
        }
        while is_digit(j) {
            j += 1;
        }
        i = j;
        if chars.get(i) == Some(&'.') {
            while i < chars.len() && (chars[i].is_ascii_digit() || chars[i] == '.') {
                i += 1;
            }
            return Err(err(
                start,
                format!("invalid number '{}': fractional exponent", text(i)),
            ));
        }
    }
    let s = text(i);
    let value: f64 = s
        .parse()
        .map_err(|_| err(start, format!("invalid number '{s}'")))?;
    if !value.is_finite() {
        return Err(err(
            start,
            format!("number '{s}' is out of the range of f64"),
        ));
    }
    Ok((value, i))
}

// ---------------------------------------------------------------------------------------------
// Parser

/// A parsed sub-tree and its depth (a leaf has depth 1).
struct Sub {
    node: Node,
    depth: usize,
}

impl Sub {
    fn leaf(node: Node) -> Sub {
        Sub { node, depth: 1 }
    }

    fn num(&self) -> Option<f64> {
        match self.node {
            Node::Num(v) => Some(v),
            _ => None,
        }
    }
}

struct Parser<'a> {
    tokens: Vec<Token>,
    pos: usize,
    /// Current recursion depth through `unary` (parentheses, calls, unary operators, '^').
    nesting: usize,
    /// Named parameters and their values.
    params: &'a [(String, f64)],
    /// Parameters left symbolic ([`Node::Param`], read per member at run time); they take
    /// precedence over `params`.
    symbolic: &'a [String],
    /// The parameters used, in order of first use.
    used: Vec<String>,
}

impl Parser<'_> {
    fn peek(&self) -> &Token {
        &self.tokens[self.pos]
    }

    fn next(&mut self) -> Token {
        let tok = self.tokens[self.pos].clone();
        if tok.kind != Tok::End {
            self.pos += 1;
        }
        tok
    }

    fn too_deep(&self, pos: usize) -> ExprError {
        err(
            pos,
            format!("expression is nested too deeply (more than {MAX_DEPTH} levels)"),
        )
    }

    fn bin(&self, op: BinOp, a: Sub, b: Sub, pos: usize) -> Result<Sub, ExprError> {
        if let (Some(x), Some(y)) = (a.num(), b.num()) {
            return Ok(Sub::leaf(Node::Num(op.apply(x, y))));
        }
        let depth = 1 + a.depth.max(b.depth);
        if depth > MAX_DEPTH {
            return Err(self.too_deep(pos));
        }
        Ok(Sub {
            node: Node::Bin(op, Box::new(a.node), Box::new(b.node)),
            depth,
        })
    }

    fn expr(&mut self) -> Result<Sub, ExprError> {
        let mut lhs = self.term()?;
        loop {
            let op = match self.peek().kind {
                Tok::Plus => BinOp::Add,
                Tok::Minus => BinOp::Sub,
                _ => return Ok(lhs),
            };
            let pos = self.next().pos;
            let rhs = self.term()?;
            lhs = self.bin(op, lhs, rhs, pos)?;
        }
    }

    fn term(&mut self) -> Result<Sub, ExprError> {
        let mut lhs = self.unary()?;
        loop {
            let op = match self.peek().kind {
                Tok::Star => BinOp::Mul,
                Tok::Slash => BinOp::Div,
                _ => return Ok(lhs),
            };
            let pos = self.next().pos;
            let rhs = self.unary()?;
            lhs = self.bin(op, lhs, rhs, pos)?;
        }
    }

    fn unary(&mut self) -> Result<Sub, ExprError> {
        let pos = self.peek().pos;
        self.nesting += 1;
        if self.nesting > MAX_DEPTH {
            return Err(self.too_deep(pos));
        }
        let result = self.unary_inner();
        self.nesting -= 1;
        result
    }

    fn unary_inner(&mut self) -> Result<Sub, ExprError> {
        match self.peek().kind {
            Tok::Plus => {
                self.next();
                self.unary()
            }
            Tok::Minus => {
                let pos = self.next().pos;
                let a = self.unary()?;
                if let Some(v) = a.num() {
                    return Ok(Sub::leaf(Node::Num(-v)));
                }
                if a.depth + 1 > MAX_DEPTH {
                    return Err(self.too_deep(pos));
                }
                Ok(Sub {
                    depth: a.depth + 1,
                    node: Node::Neg(Box::new(a.node)),
                })
            }
            _ => self.power(),
        }
    }

    fn power(&mut self) -> Result<Sub, ExprError> {
        let base = self.primary()?;
        if self.peek().kind == Tok::Caret {
            let pos = self.next().pos;
            let exponent = self.unary()?;
            self.bin(BinOp::Pow, base, exponent, pos)
        } else {
            Ok(base)
        }
    }

    fn primary(&mut self) -> Result<Sub, ExprError> {
        let tok = self.next();
        match tok.kind {
            Tok::Num(v) => Ok(Sub::leaf(Node::Num(v))),
            Tok::LParen => {
                let inner = self.expr()?;
                self.close_paren(tok.pos, "parenthesis")?;
                Ok(inner)
            }
            Tok::Ident(name) => match name.as_str() {
                "x" => Ok(Sub::leaf(Node::X)),
                "t" => Ok(Sub::leaf(Node::T)),
                "pi" => Ok(Sub::leaf(Node::Num(std::f64::consts::PI))),
                "e" => Ok(Sub::leaf(Node::Num(std::f64::consts::E))),
                _ => match Func::from_name(&name) {
                    Some(f) => self.call(f, tok.pos),
                    None if self.symbolic.contains(&name) => {
                        let k = self.symbolic.iter().position(|p| *p == name).unwrap_or(0);
                        if !self.used.contains(&name) {
                            self.used.push(name);
                        }
                        Ok(Sub::leaf(Node::Param(k)))
                    }
                    None => match self.params.iter().find(|(p, _)| *p == name) {
                        Some(&(_, value)) => {
                            if !self.used.contains(&name) {
                                self.used.push(name);
                            }
                            Ok(Sub::leaf(Node::Num(value)))
                        }
                        None => {
                            let mut known = KNOWN_NAMES.to_string();
                            if !self.params.is_empty() {
                                let names: Vec<&str> =
                                    self.params.iter().map(|(p, _)| p.as_str()).collect();
                                known.push_str(&format!("; parameters: {}", names.join(", ")));
                            }
                            Err(err(
                                tok.pos,
                                format!("unknown identifier '{name}' (known names: {known})"),
                            ))
                        }
                    },
                },
            },
            Tok::End => Err(err(
                tok.pos,
                "unexpected end of input (expected a number, variable, function or '(')"
                    .to_string(),
            )),
            Tok::RParen => Err(err(
                tok.pos,
                "unexpected ')' (expected a number, variable, function or '(')".to_string(),
            )),
            other => Err(err(
                tok.pos,
                format!(
                    "unexpected {} (expected a number, variable, function or '(')",
                    other.describe()
                ),
            )),
        }
    }

    /// Parses `( arg, … )` after the function name at `name_pos`.
    fn call(&mut self, f: Func, name_pos: usize) -> Result<Sub, ExprError> {
        let open = self.peek().clone();
        if open.kind != Tok::LParen {
            return Err(err(
                open.pos,
                format!(
                    "function '{}' must be followed by '(' (found {})",
                    f.name(),
                    open.kind.describe()
                ),
            ));
        }
        self.next();
        let mut args = Vec::with_capacity(f.arity());
        if self.peek().kind != Tok::RParen {
            loop {
                args.push(self.expr()?);
                if self.peek().kind == Tok::Comma {
                    self.next();
                } else {
                    break;
                }
            }
        }
        self.close_paren(open.pos, &format!("parenthesis of '{}('", f.name()))?;
        if args.len() != f.arity() {
            let plural = if f.arity() == 1 { "" } else { "s" };
            return Err(err(
                name_pos,
                format!(
                    "function '{}' takes {} argument{plural}, got {}",
                    f.name(),
                    f.arity(),
                    args.len()
                ),
            ));
        }
        if args.iter().all(|a| a.num().is_some()) {
            let a = args[0].num().unwrap_or(f64::NAN);
            let b = args.get(1).and_then(Sub::num).unwrap_or(0.0);
            return Ok(Sub::leaf(Node::Num(f.apply(a, b))));
        }
        let depth = 1 + args.iter().map(|a| a.depth).max().unwrap_or(0);
        if depth > MAX_DEPTH {
            return Err(self.too_deep(name_pos));
        }
        Ok(Sub {
            node: Node::Call(f, args.into_iter().map(|a| a.node).collect()),
            depth,
        })
    }

    /// Consumes the ')' matching the '(' at `open_pos`.
    fn close_paren(&mut self, open_pos: usize, what: &str) -> Result<(), ExprError> {
        let tok = self.next();
        match tok.kind {
            Tok::RParen => Ok(()),
            Tok::End => Err(err(
                open_pos,
                format!("unclosed {what} opened here (expected ')' before the end of input)"),
            )),
            other => Err(err(
                tok.pos,
                format!(
                    "expected ')' to close the {what} at position {open_pos}, found {}",
                    other.describe()
                ),
            )),
        }
    }
}
