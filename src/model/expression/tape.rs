//! Compiled expressions: the nodes a set of outputs needs, in evaluation order, each reading
//! earlier slots. One tape is evaluated for `f64` and for every dual number alike.

use super::graph::{Func, Graph, Id, Node};
use crate::model::{special, Scalar};

#[derive(Debug, Clone, Copy, PartialEq)]
enum Op {
    T,
    X(u32),
    Z(u32),
    Theta(u32),
    Const(f64),
    Add(u32, u32),
    Sub(u32, u32),
    Mul(u32, u32),
    Div(u32, u32),
    Neg(u32),
    Powi(u32, i32),
    Powf(u32, f64),
    Pow(u32, u32),
    Atan2(u32, u32),
    Func(Func, u32),
}

/// A list of operations over slots (one slot per operation) and the slots of the outputs.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Tape {
    ops: Vec<Op>,
    outputs: Vec<u32>,
}

impl Tape {
    /// Compiles the nodes of `graph` that `roots` need; the graph's inputs are t (0), then `nx`
    /// noisy states, `nz` clean states and the parameters.
    pub(crate) fn compile(graph: &Graph, roots: &[Id], nx: usize, nz: usize) -> Tape {
        let mut needed = vec![false; graph.len()];
        for &r in roots {
            needed[r as usize] = true;
        }
        // Children have smaller indices than their parents: one backward sweep marks them.
        for id in (0..graph.len()).rev() {
            if needed[id] {
                for c in graph.children(id as Id).into_iter().flatten() {
                    needed[c as usize] = true;
                }
            }
        }
        let mut slot = vec![u32::MAX; graph.len()];
        let mut ops = Vec::new();
        for id in (0..graph.len()).filter(|&i| needed[i]) {
            let s = |c: Id| slot[c as usize];
            let op = match graph.node(id as Id) {
                Node::Const(bits) => Op::Const(f64::from_bits(bits)),
                Node::Input(0) => Op::T,
                Node::Input(i) if (i as usize) <= nx => Op::X(i - 1),
                Node::Input(i) if (i as usize) <= nx + nz => Op::Z(i - 1 - nx as u32),
                Node::Input(i) => Op::Theta(i - 1 - (nx + nz) as u32),
                Node::Add(a, b) => Op::Add(s(a), s(b)),
                Node::Sub(a, b) => Op::Sub(s(a), s(b)),
                Node::Mul(a, b) => Op::Mul(s(a), s(b)),
                Node::Div(a, b) => Op::Div(s(a), s(b)),
                Node::Neg(a) => Op::Neg(s(a)),
                Node::Powi(a, n) => Op::Powi(s(a), n),
                Node::Powf(a, bits) => Op::Powf(s(a), f64::from_bits(bits)),
                Node::Pow(a, b) => Op::Pow(s(a), s(b)),
                Node::Atan2(a, b) => Op::Atan2(s(a), s(b)),
                Node::Func(f, a) => Op::Func(f, s(a)),
            };
            slot[id] = ops.len() as u32;
            ops.push(op);
        }
        let outputs = roots.iter().map(|&r| slot[r as usize]).collect();
        Tape { ops, outputs }
    }

    /// Number of operations.
    pub(crate) fn len(&self) -> usize {
        self.ops.len()
    }

    /// Evaluates the outputs at (t, x, z, θ) into `out` (length [`Self::outputs`]).
    #[inline]
    pub(crate) fn eval<D: Scalar>(&self, t: D, x: &[D], z: &[D], theta: &[D], out: &mut [D]) {
        with_scratch(self.ops.len(), |buf: &mut [D]| {
            self.run(t, x, z, theta, buf);
            for (o, &s) in out.iter_mut().zip(&self.outputs) {
                *o = buf[s as usize];
            }
        })
    }

    /// Evaluates every slot into `buf` (length [`Self::len`]).
    fn run<D: Scalar>(&self, t: D, x: &[D], z: &[D], theta: &[D], buf: &mut [D]) {
        for k in 0..self.ops.len() {
            let v = match self.ops[k] {
                Op::T => t,
                Op::X(i) => x[i as usize],
                Op::Z(i) => z[i as usize],
                Op::Theta(i) => theta[i as usize],
                Op::Const(c) => D::from(c),
                Op::Add(a, b) => buf[a as usize] + buf[b as usize],
                Op::Sub(a, b) => buf[a as usize] - buf[b as usize],
                Op::Mul(a, b) => buf[a as usize] * buf[b as usize],
                Op::Div(a, b) => buf[a as usize] / buf[b as usize],
                Op::Neg(a) => -buf[a as usize],
                Op::Powi(a, n) => buf[a as usize].powi(n),
                Op::Powf(a, p) => buf[a as usize].powf(p),
                Op::Pow(a, b) => buf[a as usize].powd(buf[b as usize]),
                Op::Atan2(a, b) => buf[a as usize].atan2(buf[b as usize]),
                Op::Func(f, a) => apply(f, buf[a as usize]),
            };
            buf[k] = v;
        }
    }
}

/// f(a) for a scalar of any kind.
#[inline]
pub(crate) fn apply<D: Scalar>(f: Func, a: D) -> D {
    match f {
        Func::Exp => a.exp(),
        Func::Ln => a.ln(),
        Func::Sqrt => a.sqrt(),
        Func::Sin => a.sin(),
        Func::Cos => a.cos(),
        Func::Tan => a.tan(),
        Func::Sinh => a.sinh(),
        Func::Cosh => a.cosh(),
        Func::Tanh => a.tanh(),
        Func::Atan => a.atan(),
        Func::Ln1p => a.ln_1p(),
        Func::ExpM1 => a.exp_m1(),
        Func::Erf => special::erf(a),
        Func::Phi => special::ndtr(a),
    }
}

/// Calls `f` with a scratch buffer of `len` scalars, on the stack when it is small.
#[inline]
fn with_scratch<D: Scalar, R>(len: usize, f: impl FnOnce(&mut [D]) -> R) -> R {
    let small = std::mem::size_of::<D>() <= 32;
    if len <= 16 {
        f(&mut [D::from(0.0); 16][..len])
    } else if len <= 64 && small {
        f(&mut [D::from(0.0); 64][..len])
    } else if len <= 256 && std::mem::size_of::<D>() <= 8 {
        f(&mut [D::from(0.0); 256][..len])
    } else {
        f(&mut vec![D::from(0.0); len])
    }
}
