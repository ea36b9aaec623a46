//! A recursive-descent parser of infix expressions into a [`Graph`].
//!
//! Grammar (`^` binds tighter than unary minus and is right-associative, so `-x^2` is
//! −(x²) and `2^-1` is ½):
//!
//! ```text
//! sum     := product (("+" | "-") product)*
//! product := unary (("*" | "/") unary)*
//! unary   := ("-" | "+") unary | power
//! power   := atom ("^" unary)?
//! atom    := NUMBER | NAME | NAME "(" sum ("," sum)* ")" | "(" sum ")"
//! ```

use super::graph::{Func, Graph, Id};

/// A problem in an expression at a byte offset of its text.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ParseError {
    /// Byte offset in the expression.
    pub offset: usize,
    /// What is wrong and what was expected.
    pub message: String,
}

/// What a name in an expression stands for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Symbol {
    /// Input i of the graph (0 = t, then x, z, θ).
    Input(u32),
    /// A named constant (`pi`, or a constant of the model file).
    Value(f64),
}

/// The names a parser resolves, and whether a name is allowed where it is used.
pub(crate) trait Symbols {
    /// The symbol called `name`, or an error message (e.g. "unknown symbol … (known: …)").
    fn resolve(&self, name: &str) -> Result<Symbol, String>;
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Token<'a> {
    Number(f64),
    Name(&'a str),
    Op(char),
    End,
}

struct Lexer<'a> {
    text: &'a str,
    pos: usize,
}

impl<'a> Lexer<'a> {
    /// The next token and its offset.
    fn next(&mut self) -> Result<(Token<'a>, usize), ParseError> {
        let bytes = self.text.as_bytes();
        while self.pos < bytes.len() && bytes[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        let start = self.pos;
        let Some(&c) = bytes.get(start) else { return Ok((Token::End, start)) };
        if c.is_ascii_digit() || c == b'.' {
            let mut end = start;
            while end < bytes.len() && (bytes[end].is_ascii_digit() || bytes[end] == b'.') {
                end += 1;
            }
            if end < bytes.len() && (bytes[end] == b'e' || bytes[end] == b'E') {
                let mut e = end + 1;
                if e < bytes.len() && (bytes[e] == b'+' || bytes[e] == b'-') {
                    e += 1;
                }
                if e < bytes.len() && bytes[e].is_ascii_digit() {
                    while e < bytes.len() && bytes[e].is_ascii_digit() {
                        e += 1;
                    }
                    end = e;
                }
            }
            let s = &self.text[start..end];
            let v = s
                .parse::<f64>()
                .map_err(|_| ParseError { offset: start, message: format!("`{s}` is not a number") })?;
            self.pos = end;
            return Ok((Token::Number(v), start));
        }
        if c.is_ascii_alphabetic() || c == b'_' {
            let mut end = start;
            while end < bytes.len() && (bytes[end].is_ascii_alphanumeric() || bytes[end] == b'_') {
                end += 1;
            }
            self.pos = end;
            return Ok((Token::Name(&self.text[start..end]), start));
        }
        let ch = self.text[start..].chars().next().unwrap_or(' ');
        if "+-*/^(),".contains(ch) {
            self.pos += 1;
            return Ok((Token::Op(ch), start));
        }
        let hint = match ch {
            '−' => " (use the ASCII minus `-`)",
            '×' | '·' => " (use `*`)",
            _ => "",
        };
        Err(ParseError {
            offset: start,
            message: format!("unexpected character `{ch}`{hint}; expected a number, a name, an operator + - * / ^ or parentheses"),
        })
    }
}

/// Parses `text` into `graph`, resolving names through `symbols`; returns the root node.
pub(crate) fn parse(text: &str, graph: &mut Graph, symbols: &dyn Symbols) -> Result<Id, ParseError> {
    let mut p = Parser { lexer: Lexer { text, pos: 0 }, peeked: None, graph, symbols, depth: 0 };
    if p.peek()?.0 == Token::End {
        return Err(ParseError { offset: 0, message: "empty expression".into() });
    }
    let root = p.sum()?;
    match p.next()? {
        (Token::End, _) => Ok(root),
        (tok, at) => Err(ParseError {
            offset: at,
            message: format!(
                "unexpected {}; expected an operator or the end of the expression",
                describe(tok)
            ),
        }),
    }
}

fn describe(tok: Token<'_>) -> String {
    match tok {
        Token::Number(v) => format!("number `{v}`"),
        Token::Name(n) => format!("name `{n}`"),
        Token::Op(c) => format!("`{c}`"),
        Token::End => "end of the expression".into(),
    }
}

struct Parser<'a, 'g> {
    lexer: Lexer<'a>,
    peeked: Option<(Token<'a>, usize)>,
    graph: &'g mut Graph,
    symbols: &'g dyn Symbols,
    /// Nesting of the unary expressions being parsed (parentheses, function arguments, signs,
    /// exponents), at most [`MAX_DEPTH`].
    depth: usize,
}

/// The deepest nesting an expression may have: deeper ones are refused (the recursive descent
/// would otherwise exhaust the stack).
const MAX_DEPTH: usize = 500;

impl<'a> Parser<'a, '_> {
    fn peek(&mut self) -> Result<(Token<'a>, usize), ParseError> {
        if self.peeked.is_none() {
            self.peeked = Some(self.lexer.next()?);
        }
        Ok(self.peeked.expect("just set"))
    }

    fn next(&mut self) -> Result<(Token<'a>, usize), ParseError> {
        let t = self.peek()?;
        self.peeked = None;
        Ok(t)
    }

    fn sum(&mut self) -> Result<Id, ParseError> {
        let mut acc = self.product()?;
        loop {
            match self.peek()?.0 {
                Token::Op('+') => {
                    self.next()?;
                    let r = self.product()?;
                    acc = self.graph.add(acc, r);
                }
                Token::Op('-') => {
                    self.next()?;
                    let r = self.product()?;
                    acc = self.graph.sub(acc, r);
                }
                _ => return Ok(acc),
            }
        }
    }

    fn product(&mut self) -> Result<Id, ParseError> {
        let mut acc = self.unary()?;
        loop {
            match self.peek()?.0 {
                Token::Op('*') => {
                    self.next()?;
                    let r = self.unary()?;
                    acc = self.graph.mul(acc, r);
                }
                Token::Op('/') => {
                    self.next()?;
                    let r = self.unary()?;
                    acc = self.graph.div(acc, r);
                }
                _ => return Ok(acc),
            }
        }
    }

    fn unary(&mut self) -> Result<Id, ParseError> {
        if self.depth >= MAX_DEPTH {
            return Err(ParseError {
                offset: self.peek()?.1,
                message: format!(
                    "the expression is nested more than {MAX_DEPTH} levels deep (parentheses, function \
                     calls, signs and exponents)"
                ),
            });
        }
        self.depth += 1;
        let result = self.unary_inner();
        self.depth -= 1;
        result
    }

    fn unary_inner(&mut self) -> Result<Id, ParseError> {
        match self.peek()?.0 {
            Token::Op('-') => {
                self.next()?;
                let a = self.unary()?;
                Ok(self.graph.neg(a))
            }
            Token::Op('+') => {
                self.next()?;
                self.unary()
            }
            _ => self.power(),
        }
    }

    fn power(&mut self) -> Result<Id, ParseError> {
        let base = self.atom()?;
        if self.peek()?.0 == Token::Op('^') {
            self.next()?;
            let exponent = self.unary()?;
            return Ok(self.graph.pow(base, exponent));
        }
        Ok(base)
    }

    fn atom(&mut self) -> Result<Id, ParseError> {
        let (tok, at) = self.next()?;
        match tok {
            Token::Number(v) => Ok(self.graph.num(v)),
            Token::Op('(') => {
                let inner = self.sum()?;
                self.expect_close(at)?;
                Ok(inner)
            }
            Token::Name(name) if self.peek()?.0 == Token::Op('(') => self.call(name, at),
            Token::Name(name) => match self.symbols.resolve(name) {
                Ok(Symbol::Input(i)) => Ok(self.graph.input(i)),
                Ok(Symbol::Value(v)) => Ok(self.graph.num(v)),
                Err(message) => Err(ParseError { offset: at, message }),
            },
            other => Err(ParseError {
                offset: at,
                message: format!("unexpected {}; expected a number, a name or `(`", describe(other)),
            }),
        }
    }

    fn expect_close(&mut self, open: usize) -> Result<(), ParseError> {
        match self.next()? {
            (Token::Op(')'), _) => Ok(()),
            (Token::End, _) => {
                Err(ParseError { offset: open, message: "this `(` is not closed: missing `)`".into() })
            }
            (tok, at) => {
                Err(ParseError { offset: at, message: format!("unexpected {}; expected `)`", describe(tok)) })
            }
        }
    }

    fn call(&mut self, name: &str, at: usize) -> Result<Id, ParseError> {
        let open = self.next()?.1;
        let mut args = vec![self.sum()?];
        while self.peek()?.0 == Token::Op(',') {
            self.next()?;
            args.push(self.sum()?);
        }
        self.expect_close(open)?;
        let arity = |expected: usize| -> Result<(), ParseError> {
            if args.len() == expected {
                Ok(())
            } else {
                Err(ParseError {
                    offset: at,
                    message: format!(
                        "`{name}` takes {expected} argument{}, got {}",
                        if expected == 1 { "" } else { "s" },
                        args.len()
                    ),
                })
            }
        };
        if let Some(&(_, f)) = Func::ALL.iter().find(|(n, _)| *n == name) {
            arity(1)?;
            return Ok(self.graph.func(f, args[0]));
        }
        match name {
            "atan2" => {
                arity(2)?;
                Ok(self.graph.atan2(args[0], args[1]))
            }
            "pow" => {
                arity(2)?;
                Ok(self.graph.pow(args[0], args[1]))
            }
            _ => Err(ParseError {
                offset: at,
                message: format!("unknown function `{name}` (known: {})", function_names().join(", ")),
            }),
        }
    }
}

/// The names of the functions, for messages and the documentation.
pub(crate) fn function_names() -> Vec<&'static str> {
    let mut v: Vec<&str> = Func::ALL.iter().map(|(n, _)| *n).collect();
    v.extend(["atan2", "pow"]);
    v
}

/// Whether `name` is reserved (a function, `t` or `pi`) and so cannot name a state, a parameter
/// or a constant.
pub(crate) fn is_reserved(name: &str) -> bool {
    name == "t" || name == "pi" || function_names().contains(&name)
}

/// Whether `name` is a valid symbol name (letters, digits and `_`, not starting with a digit).
pub(crate) fn is_identifier(name: &str) -> bool {
    let mut chars = name.chars();
    matches!(chars.next(), Some(c) if c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
}
