//! Expressions as a hash-consed graph: equal subexpressions are one node, constants are
//! folded on construction (operands keep the order they are written in: with dual numbers,
//! a·b and b·a round differently), and derivatives are nodes of the same graph (so that the values, the
//! divergence and every first and second derivative of a model share their common parts when
//! compiled into one [`Tape`](super::tape::Tape)).

use std::collections::HashMap;

/// A node of a [`Graph`], by index. Children always have smaller indices than their parents.
pub(crate) type Id = u32;

/// The smooth functions of one argument an expression may call.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(crate) enum Func {
    Exp,
    Ln,
    Sqrt,
    Sin,
    Cos,
    Tan,
    Sinh,
    Cosh,
    Tanh,
    Atan,
    Ln1p,
    ExpM1,
    Erf,
    Phi,
}

impl Func {
    /// The functions of one argument with their names in expressions.
    pub(crate) const ALL: [(&'static str, Func); 15] = [
        ("exp", Func::Exp),
        ("log", Func::Ln),
        ("ln", Func::Ln),
        ("sqrt", Func::Sqrt),
        ("sin", Func::Sin),
        ("cos", Func::Cos),
        ("tan", Func::Tan),
        ("sinh", Func::Sinh),
        ("cosh", Func::Cosh),
        ("tanh", Func::Tanh),
        ("atan", Func::Atan),
        ("log1p", Func::Ln1p),
        ("expm1", Func::ExpM1),
        ("erf", Func::Erf),
        ("Phi", Func::Phi),
    ];

    /// The value in `f64` (for constant folding): the tape's evaluation, for one scalar type.
    pub(crate) fn apply(self, a: f64) -> f64 {
        super::tape::apply(self, a)
    }
}

/// One node: a constant, an input (0 = t, then the model's x, z, θ), or an operation on
/// earlier nodes. Constants are stored as bits so that nodes hash.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(crate) enum Node {
    Const(u64),
    Input(u32),
    Add(Id, Id),
    Sub(Id, Id),
    Mul(Id, Id),
    Div(Id, Id),
    Neg(Id),
    /// a^n for an integer constant n.
    Powi(Id, i32),
    /// a^p for a constant p that is not an integer (bits).
    Powf(Id, u64),
    /// a^b, b not constant.
    Pow(Id, Id),
    Atan2(Id, Id),
    Func(Func, Id),
}

/// A hash-consed expression graph with constant folding.
#[derive(Debug, Clone, Default)]
pub(crate) struct Graph {
    nodes: Vec<Node>,
    index: HashMap<Node, Id>,
    derivatives: HashMap<(Id, u32), Id>,
}

impl Graph {
    pub(crate) fn node(&self, id: Id) -> Node {
        self.nodes[id as usize]
    }

    pub(crate) fn len(&self) -> usize {
        self.nodes.len()
    }

    fn intern(&mut self, node: Node) -> Id {
        if let Some(&id) = self.index.get(&node) {
            return id;
        }
        let id = self.nodes.len() as Id;
        self.nodes.push(node);
        self.index.insert(node, id);
        id
    }

    /// The constant of a node, if it is one.
    pub(crate) fn constant(&self, id: Id) -> Option<f64> {
        match self.node(id) {
            Node::Const(bits) => Some(f64::from_bits(bits)),
            _ => None,
        }
    }

    fn is(&self, id: Id, v: f64) -> bool {
        self.constant(id) == Some(v)
    }

    pub(crate) fn num(&mut self, v: f64) -> Id {
        // −0 and 0 are one constant (and simplify alike).
        let v = if v == 0.0 { 0.0 } else { v };
        self.intern(Node::Const(v.to_bits()))
    }

    pub(crate) fn input(&mut self, i: u32) -> Id {
        self.intern(Node::Input(i))
    }

    pub(crate) fn add(&mut self, a: Id, b: Id) -> Id {
        match (self.constant(a), self.constant(b)) {
            (Some(x), Some(y)) => self.num(x + y),
            (Some(0.0), _) => b,
            (_, Some(0.0)) => a,
            _ => match self.node(b) {
                Node::Neg(c) => self.sub(a, c),
                _ => self.intern(Node::Add(a, b)),
            },
        }
    }

    pub(crate) fn sub(&mut self, a: Id, b: Id) -> Id {
        match (self.constant(a), self.constant(b)) {
            (Some(x), Some(y)) => self.num(x - y),
            (Some(0.0), _) => self.neg(b),
            (_, Some(0.0)) => a,
            _ if a == b => self.num(0.0),
            _ => match self.node(b) {
                Node::Neg(c) => self.add(a, c),
                _ => self.intern(Node::Sub(a, b)),
            },
        }
    }

    pub(crate) fn mul(&mut self, a: Id, b: Id) -> Id {
        match (self.constant(a), self.constant(b)) {
            (Some(x), Some(y)) => self.num(x * y),
            (Some(0.0), _) | (_, Some(0.0)) => self.num(0.0),
            (Some(1.0), _) => b,
            (_, Some(1.0)) => a,
            (Some(-1.0), _) => self.neg(b),
            (_, Some(-1.0)) => self.neg(a),
            _ => self.intern(Node::Mul(a, b)),
        }
    }

    pub(crate) fn div(&mut self, a: Id, b: Id) -> Id {
        match (self.constant(a), self.constant(b)) {
            (Some(x), Some(y)) => self.num(x / y),
            (Some(0.0), _) => self.num(0.0),
            (_, Some(1.0)) => a,
            _ => self.intern(Node::Div(a, b)),
        }
    }

    pub(crate) fn neg(&mut self, a: Id) -> Id {
        match self.node(a) {
            Node::Const(bits) => self.num(-f64::from_bits(bits)),
            Node::Neg(b) => b,
            _ => self.intern(Node::Neg(a)),
        }
    }

    pub(crate) fn powi(&mut self, a: Id, n: i32) -> Id {
        match (self.constant(a), n) {
            (Some(x), _) => self.num(x.powi(n)),
            (_, 0) => self.num(1.0),
            (_, 1) => a,
            _ => self.intern(Node::Powi(a, n)),
        }
    }

    /// a^b, as [`Node::Powi`] for an integer constant b of at most 64 in magnitude, as
    /// [`Node::Powf`] for another constant.
    pub(crate) fn pow(&mut self, a: Id, b: Id) -> Id {
        match (self.constant(a), self.constant(b)) {
            (Some(x), Some(y)) => self.num(x.powf(y)),
            (_, Some(y)) if y.fract() == 0.0 && y.abs() <= 64.0 => self.powi(a, y as i32),
            (_, Some(y)) => self.intern(Node::Powf(a, y.to_bits())),
            _ => self.intern(Node::Pow(a, b)),
        }
    }

    pub(crate) fn atan2(&mut self, a: Id, b: Id) -> Id {
        match (self.constant(a), self.constant(b)) {
            (Some(y), Some(x)) => self.num(y.atan2(x)),
            _ => self.intern(Node::Atan2(a, b)),
        }
    }

    pub(crate) fn func(&mut self, f: Func, a: Id) -> Id {
        match self.constant(a) {
            Some(x) => self.num(f.apply(x)),
            None => self.intern(Node::Func(f, a)),
        }
    }

    /// The children of a node.
    pub(crate) fn children(&self, id: Id) -> [Option<Id>; 2] {
        match self.node(id) {
            Node::Const(_) | Node::Input(_) => [None, None],
            Node::Neg(a) | Node::Powi(a, _) | Node::Powf(a, _) | Node::Func(_, a) => [Some(a), None],
            Node::Add(a, b)
            | Node::Sub(a, b)
            | Node::Mul(a, b)
            | Node::Div(a, b)
            | Node::Pow(a, b)
            | Node::Atan2(a, b) => [Some(a), Some(b)],
        }
    }

    /// Whether each node depends on input `i` (one flag per node, in node order).
    pub(crate) fn depends_on(&self, i: u32) -> Vec<bool> {
        let mut flags = vec![false; self.len()];
        for id in 0..self.len() {
            flags[id] = match self.node(id as Id) {
                Node::Input(j) => j == i,
                _ => self.children(id as Id).iter().flatten().any(|&c| flags[c as usize]),
            };
        }
        flags
    }

    /// ∂(node a)/∂(input i), as a node (memoised; the chain rule on each operation).
    pub(crate) fn derivative(&mut self, a: Id, i: u32) -> Id {
        if let Some(&d) = self.derivatives.get(&(a, i)) {
            return d;
        }
        let d = self.derivative_uncached(a, i);
        self.derivatives.insert((a, i), d);
        d
    }

    fn derivative_uncached(&mut self, id: Id, i: u32) -> Id {
        match self.node(id) {
            Node::Const(_) => self.num(0.0),
            Node::Input(j) => self.num(if j == i { 1.0 } else { 0.0 }),
            Node::Add(a, b) => {
                let (da, db) = (self.derivative(a, i), self.derivative(b, i));
                self.add(da, db)
            }
            Node::Sub(a, b) => {
                let (da, db) = (self.derivative(a, i), self.derivative(b, i));
                self.sub(da, db)
            }
            Node::Mul(a, b) => {
                let (da, db) = (self.derivative(a, i), self.derivative(b, i));
                let (l, r) = (self.mul(da, b), self.mul(a, db));
                self.add(l, r)
            }
            Node::Div(a, b) => {
                // (a/b)' = (a' − (a/b) b')/b
                let (da, db) = (self.derivative(a, i), self.derivative(b, i));
                let q = self.mul(id, db);
                let n = self.sub(da, q);
                self.div(n, b)
            }
            Node::Neg(a) => {
                let da = self.derivative(a, i);
                self.neg(da)
            }
            Node::Powi(a, n) => {
                let da = self.derivative(a, i);
                let p = self.powi(a, n - 1);
                let c = self.num(f64::from(n));
                let cp = self.mul(c, p);
                self.mul(cp, da)
            }
            Node::Powf(a, bits) => {
                let p = f64::from_bits(bits);
                let da = self.derivative(a, i);
                let e = self.num(p - 1.0);
                let q = self.pow(a, e);
                let c = self.num(p);
                let cq = self.mul(c, q);
                self.mul(cq, da)
            }
            Node::Pow(a, b) => {
                // (a^b)' = a^b (b' ln a + b a'/a)
                let (da, db) = (self.derivative(a, i), self.derivative(b, i));
                let ln = self.func(Func::Ln, a);
                let l = self.mul(db, ln);
                let ba = self.div(b, a);
                let r = self.mul(ba, da);
                let s = self.add(l, r);
                self.mul(id, s)
            }
            Node::Atan2(y, x) => {
                // atan2(y, x)' = (x y' − y x')/(x² + y²)
                let (dy, dx) = (self.derivative(y, i), self.derivative(x, i));
                let (l, r) = (self.mul(x, dy), self.mul(y, dx));
                let n = self.sub(l, r);
                let (x2, y2) = (self.powi(x, 2), self.powi(y, 2));
                let d = self.add(x2, y2);
                self.div(n, d)
            }
            Node::Func(f, a) => {
                let da = self.derivative(a, i);
                if self.is(da, 0.0) {
                    return da;
                }
                let outer = self.func_derivative(f, id, a);
                self.mul(outer, da)
            }
        }
    }

    /// f'(a) for the node `id` = f(a).
    fn func_derivative(&mut self, f: Func, id: Id, a: Id) -> Id {
        let one = self.num(1.0);
        match f {
            Func::Exp => id,
            Func::Ln => self.div(one, a),
            Func::Sqrt => {
                let two = self.num(2.0);
                let d = self.mul(two, id);
                self.div(one, d)
            }
            Func::Sin => self.func(Func::Cos, a),
            Func::Cos => {
                let s = self.func(Func::Sin, a);
                self.neg(s)
            }
            Func::Tan => {
                let sq = self.powi(id, 2);
                self.add(one, sq)
            }
            Func::Sinh => self.func(Func::Cosh, a),
            Func::Cosh => self.func(Func::Sinh, a),
            Func::Tanh => {
                let sq = self.powi(id, 2);
                self.sub(one, sq)
            }
            Func::Atan => {
                let sq = self.powi(a, 2);
                let d = self.add(one, sq);
                self.div(one, d)
            }
            Func::Ln1p => {
                let d = self.add(one, a);
                self.div(one, d)
            }
            Func::ExpM1 => self.add(id, one),
            Func::Erf | Func::Phi => {
                // erf' = 2/√π e^{−a²}; Φ' = e^{−a²/2}/√(2π)
                let (c, k) = if f == Func::Erf {
                    (std::f64::consts::FRAC_2_SQRT_PI, -1.0)
                } else {
                    (1.0 / (2.0 * std::f64::consts::PI).sqrt(), -0.5)
                };
                let sq = self.powi(a, 2);
                let kk = self.num(k);
                let e = self.mul(kk, sq);
                let ex = self.func(Func::Exp, e);
                let cc = self.num(c);
                self.mul(cc, ex)
            }
        }
    }

    /// The degree of a node as a polynomial in the inputs flagged in `state` (the others are
    /// coefficients), `None` when it is not a polynomial in them. A bound: cancellations are not
    /// detected.
    pub(crate) fn polynomial_degree(&self, id: Id, state: &dyn Fn(u32) -> bool) -> Option<u32> {
        let mut memo: HashMap<Id, Option<u32>> = HashMap::new();
        self.degree_memo(id, state, &mut memo)
    }

    fn degree_memo(
        &self,
        id: Id,
        state: &dyn Fn(u32) -> bool,
        memo: &mut HashMap<Id, Option<u32>>,
    ) -> Option<u32> {
        if let Some(&d) = memo.get(&id) {
            return d;
        }
        let mut deg = |c: Id| self.degree_memo(c, state, memo);
        let d = match self.node(id) {
            Node::Const(_) => Some(0),
            Node::Input(j) => Some(u32::from(state(j))),
            Node::Add(a, b) | Node::Sub(a, b) => deg(a).zip(deg(b)).map(|(x, y)| x.max(y)),
            Node::Mul(a, b) => deg(a).zip(deg(b)).map(|(x, y)| x + y),
            Node::Div(a, b) => match (deg(a), deg(b)) {
                (Some(x), Some(0)) => Some(x),
                _ => None,
            },
            Node::Neg(a) => deg(a),
            Node::Powi(a, n) => match deg(a) {
                Some(0) => Some(0),
                Some(x) if n > 0 => Some(x * n as u32),
                _ => None,
            },
            Node::Powf(a, _) | Node::Func(_, a) => deg(a).filter(|&x| x == 0),
            Node::Pow(a, b) | Node::Atan2(a, b) => match (deg(a), deg(b)) {
                (Some(0), Some(0)) => Some(0),
                _ => None,
            },
        };
        memo.insert(id, d);
        d
    }
}
