//! The KKT (augmented) system of the interior-point method and its sparse LDLᵀ solver.
//!
//! Each Newton step of [`InteriorPoint`](super::InteriorPoint) solves
//!
//! $$\begin{pmatrix} W + \Sigma + \delta_w I & J^\top \\\\ J & -\delta_c I \end{pmatrix}
//! \begin{pmatrix} d_w \\\\ d_y \end{pmatrix} = -\begin{pmatrix} r_w \\\\ r_c \end{pmatrix}$$
//!
//! (Wächter & Biegler 2006, eq. (13) with the regularisation of Sect. 3.1), where $W$ is the
//! Hessian of the Lagrangian, $\Sigma$ the diagonal barrier term and $J$ the constraint
//! Jacobian. The pattern of this matrix never changes, so it is built once, with index maps
//! from the problem's Hessian and Jacobian triplets to the slots of the matrix (as Clarabel
//! does); only values are scattered in each iteration.
//!
//! [`FaerLdlt`] factorises it with faer's simplicial sparse LDLᵀ, without pivoting. The
//! symbolic analysis is done once per problem, with an ordering of our own: an approximate
//! minimum degree ordering of the primal graph (pattern of $W + J^\top J$) in which each
//! constraint row is placed right after the last of its variables, so that its pivot is a
//! Schur complement $-\delta_c - J_r (\cdot)^{-1} J_r^\top$ rather than the structural zero
//! $-\delta_c$. Variables coupled to very many others (a static parameter shared by every
//! transition) and dense constraint rows are ordered last, so they do not fill in the factor.
//! The factorisation then exists, for example, whenever the primal block is positive definite,
//! and the inertia is read from the signs of $D$ (Sylvester's law of inertia).
//!
//! Pivots with $|d| \le 10^{-30}\max|K_{ij}|$ are replaced by faer's dynamic regularisation
//! ($\pm$ [`REGULARIZATION_DELTA`] $\max|K_{ij}|$ with the pivot's sign) and counted in
//! [`FactorInfo::regularized_pivots`]. faer's sign-prescribing mode (expected signs + for the
//! primal rows, − for the constraint rows) is deliberately not used: it flips every pivot of
//! the unexpected sign, which hides exactly the inertia the interior-point method needs when
//! the Hessian is indefinite. How the interior-point method uses a regularised factorisation
//! is described in the [documentation of `nlp`](super).

// Loops over matrix positions index several arrays (pattern, values, permutation) at once.
#![allow(clippy::needless_range_loop)]

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::ldlt::factor::LdltRegularization;
use faer::sparse::linalg::amd;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, simplicial, CholeskySymbolicParams, SymbolicCholesky, SymbolicCholeskyRaw,
    SymmetricOrdering,
};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};

use super::band::BandLdlt;
use crate::{Error, Result};

/// Relative size $\delta / \max|K_{ij}|$ of the value that replaces a numerically zero pivot
/// (both solvers). A zero pivot arises without pivoting whenever a variable without curvature
/// (e.g. a state entering the drift linearly) is eliminated before its constraints. Replacing
/// it by $\pm\delta$ factorises $K + E$ with $E = \pm\delta e_p e_p^\top$: iterative
/// refinement against $K$ then contracts the error by about $\lVert (K+E)^{-1} E\rVert$, which
/// grows with $\delta$, while the rounding errors of the factorisation grow like
/// $\varepsilon/\delta$ (the element growth caused by the small pivot). The classic compromise
/// of static pivoting is $\delta \approx \sqrt{\varepsilon}\,\lVert K\rVert$ (X. S. Li and
/// J. W. Demmel, ACM Trans. Math. Softw. 29 (2003), the GESP algorithm); $10^{-10}$ (relative to the
/// largest entry) needs one refinement step per solve on the Van der Pol JME problem where
/// $10^{-12}$ needed two to four (`examples/van_der_pol_jme.rs`, 17 instead of 28 solves with
/// the factor over its 7 iterations), with the same iterates on the NLP test problems.
pub const REGULARIZATION_DELTA: f64 = 1e-10;

/// The fixed sparsity structure of a KKT system: dimensions and the problem's patterns.
#[derive(Clone, Copy, Debug)]
pub struct KktStructure<'a> {
    /// Number of primal variables $n$.
    pub n: usize,
    /// Number of equality constraints $m$.
    pub m: usize,
    /// Lower-triangular Hessian pattern, `(row, column)` with `row >= column`, indices `< n`.
    pub hessian: &'a [(u32, u32)],
    /// Jacobian pattern, `(row, column)` with `row < m`, `column < n`.
    pub jacobian: &'a [(u32, u32)],
    /// An elimination order of the KKT matrix known to the problem
    /// ([`NlpProblem::kkt_order`](super::NlpProblem::kkt_order)): `order[p]` is the KKT row at
    /// position `p` (variable `i` as `i`, constraint `r` as `n + r`), a permutation of
    /// `0..n + m`. [`BandLdlt`](super::BandLdlt) eliminates in this order instead of its own;
    /// faer's solver ignores it. `None`: no hint.
    pub order: Option<&'a [usize]>,
}

impl<'a> KktStructure<'a> {
    /// The structure of patterns `hessian` and `jacobian` of a problem with `n` variables and
    /// `m` constraints, without an ordering hint.
    pub fn new(n: usize, m: usize, hessian: &'a [(u32, u32)], jacobian: &'a [(u32, u32)]) -> Self {
        KktStructure { n, m, hessian, jacobian, order: None }
    }

    /// The same structure with the ordering hint `order` (see [`KktStructure::order`]).
    pub fn with_order(self, order: Option<&'a [usize]>) -> Self {
        KktStructure { order, ..self }
    }

    /// The Hessian pattern's entries as `usize` pairs.
    pub fn hessian_entries(&self) -> impl ExactSizeIterator<Item = (usize, usize)> + Clone + 'a {
        self.hessian.iter().map(|&(i, j)| (i as usize, j as usize))
    }

    /// The Jacobian pattern's entries as `usize` pairs.
    pub fn jacobian_entries(&self) -> impl ExactSizeIterator<Item = (usize, usize)> + Clone + 'a {
        self.jacobian.iter().map(|&(r, c)| (r as usize, c as usize))
    }
}

/// An error unless `order` is a permutation of `0..dim` (an ordering hint of the KKT matrix of
/// dimension `dim`, see [`KktStructure::order`]).
pub(crate) fn check_order(order: &[usize], dim: usize) -> Result<()> {
    let invalid = |reason: String| Err(Error::InvalidOption { name: "kkt_order".into(), reason });
    if order.len() != dim {
        return invalid(format!("has {} entries for a KKT matrix of dimension {dim}", order.len()));
    }
    let mut seen = vec![false; dim];
    for &v in order {
        if v >= dim || std::mem::replace(&mut seen[v], true) {
            return invalid(format!("not a permutation of the {dim} KKT rows (entry {v})"));
        }
    }
    Ok(())
}

/// The values of one KKT matrix, in the order of the patterns of [`KktStructure`].
#[derive(Clone, Copy, Debug)]
pub struct KktValues<'a> {
    /// Hessian values (length of the Hessian pattern).
    pub hessian: &'a [f64],
    /// Jacobian values (length of the Jacobian pattern).
    pub jacobian: &'a [f64],
    /// Diagonal added to the primal block ($\Sigma$, length $n$).
    pub primal_diagonal: &'a [f64],
    /// Primal regularisation $\delta_w \ge 0$, added to every primal diagonal entry.
    pub delta_w: f64,
    /// Constraint regularisation $\delta_c \ge 0$, subtracted from every constraint diagonal
    /// entry.
    pub delta_c: f64,
}

/// Inertia of a symmetric matrix: numbers of positive, negative and zero eigenvalues.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Inertia {
    /// Number of positive eigenvalues.
    pub positive: usize,
    /// Number of negative eigenvalues.
    pub negative: usize,
    /// Number of (numerically) zero eigenvalues.
    pub zero: usize,
}

/// What a numeric factorisation found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FactorInfo {
    /// Inertia read from the signs of $D$.
    pub inertia: Inertia,
    /// Number of pivots that were numerically zero and replaced by the dynamic
    /// regularisation; when positive the inertia is uncertain and the matrix should be treated
    /// as singular.
    pub regularized_pivots: usize,
}

/// A linear solver for the KKT system: symbolic analysis once, numeric factorisation per
/// iteration, solves with the last factorisation.
pub trait KktSolver {
    /// Analyses the fixed pattern; called once per problem, before any factorisation.
    ///
    /// # Errors
    /// [`Error::InvalidOption`] if the analysis cannot be done (e.g. out of memory).
    fn analyse(&mut self, structure: &KktStructure<'_>) -> Result<()>;

    /// Assembles and factorises the matrix with the given values. Returns `None` when the
    /// factorisation broke down (non-finite values or a pivot that could not be regularised)
    /// or [`analyse`](Self::analyse) was not called.
    fn factorize(&mut self, values: &KktValues<'_>) -> Option<FactorInfo>;

    /// Solves $K x = b$ in place with the last successful factorisation (the result is
    /// meaningless otherwise) (with iterative refinement against
    /// the assembled matrix) and returns the relative residual
    /// $\lVert b - K x\rVert_\infty / \lVert b\rVert_\infty$.
    fn solve_in_place(&mut self, rhs: &mut [f64]) -> f64;

    /// Numbers of nonzeros of the KKT matrix (upper triangle) and of its factor, when known.
    fn nnz(&self) -> (usize, usize) {
        (0, 0)
    }

    /// A short name of the solver, for reports.
    fn name(&self) -> &'static str {
        "custom"
    }
}

/// [`BandLdlt`] when the analysis finds a narrow band, [`FaerLdlt`] otherwise (decided in
/// [`KktSolver::analyse`]).
#[derive(Debug)]
pub enum AutoLdlt {
    /// The variable-band solver.
    Band(Box<BandLdlt>),
    /// faer's sparse solver.
    Faer(Box<FaerLdlt>),
}

impl Default for AutoLdlt {
    fn default() -> Self {
        Self::new()
    }
}

impl AutoLdlt {
    /// Before the analysis: the band solver.
    pub fn new() -> Self {
        AutoLdlt::Band(Box::new(BandLdlt::new()))
    }

    fn solver(&mut self) -> &mut dyn KktSolver {
        match self {
            AutoLdlt::Band(b) => b.as_mut(),
            AutoLdlt::Faer(f) => f.as_mut(),
        }
    }
}

impl KktSolver for AutoLdlt {
    fn analyse(&mut self, structure: &KktStructure<'_>) -> Result<()> {
        if let AutoLdlt::Band(b) = self {
            if b.reuse_analysis(structure) {
                return Ok(());
            }
        }
        let mut band = BandLdlt::new();
        if band.analyse(structure).is_ok() {
            *self = AutoLdlt::Band(Box::new(band));
            return Ok(());
        }
        drop(band);
        let mut faer = FaerLdlt::new();
        faer.analyse(structure)?;
        *self = AutoLdlt::Faer(Box::new(faer));
        Ok(())
    }

    fn factorize(&mut self, values: &KktValues<'_>) -> Option<FactorInfo> {
        self.solver().factorize(values)
    }

    fn solve_in_place(&mut self, rhs: &mut [f64]) -> f64 {
        self.solver().solve_in_place(rhs)
    }

    fn nnz(&self) -> (usize, usize) {
        match self {
            AutoLdlt::Band(b) => b.nnz(),
            AutoLdlt::Faer(f) => f.nnz(),
        }
    }

    fn name(&self) -> &'static str {
        match self {
            AutoLdlt::Band(b) => b.name(),
            AutoLdlt::Faer(f) => f.name(),
        }
    }
}

/// Sparse LDLᵀ of the KKT matrix with faer (simplicial, no pivoting, ordering described in the
/// [module documentation](self)).
#[derive(Default)]
pub struct FaerLdlt {
    n: usize,
    m: usize,
    /// `perm[p]` = original row of position `p`.
    perm: Vec<usize>,
    /// Upper-triangular CSC pattern of the permuted matrix.
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    values: Vec<f64>,
    slots: SlotMap,
    symbolic: Option<SymbolicCholesky<usize>>,
    l_values: Vec<f64>,
    factor_mem: Option<MemBuffer>,
    work_x: Vec<f64>,
    work_r: Vec<f64>,
    work_b: Vec<f64>,
    work_prev: Vec<f64>,
    norm_k: f64,
    last_residual: f64,
    /// Whether the last factorisation regularised some pivots.
    regularized: bool,
    /// Maximum number of iterative refinement steps (default 10).
    pub max_refinement_steps: usize,
}

impl std::fmt::Debug for FaerLdlt {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FaerLdlt")
            .field("n", &self.n)
            .field("m", &self.m)
            .field("matrix_nnz", &self.matrix_nnz())
            .field("factor_nnz", &self.factor_nnz())
            .field("max_refinement_steps", &self.max_refinement_steps)
            .finish()
    }
}

impl FaerLdlt {
    /// A solver with default settings; call [`KktSolver::analyse`] before use.
    pub fn new() -> Self {
        Self { max_refinement_steps: 10, ..Default::default() }
    }

    /// Number of nonzeros of the (upper triangle of the) KKT matrix.
    pub fn matrix_nnz(&self) -> usize {
        self.row_idx.len()
    }

    /// ‖b − K x‖∞ / ‖b‖∞ after the last solve.
    pub fn last_relative_residual(&self) -> f64 {
        self.last_residual
    }

    /// Number of nonzeros of the factor $L$ (including the diagonal holding $D$).
    pub fn factor_nnz(&self) -> usize {
        self.l_values.len()
    }

    fn simplicial(&self) -> &simplicial::SymbolicSimplicialCholesky<usize> {
        match self.symbolic.as_ref().map(|s| s.raw()) {
            Some(SymbolicCholeskyRaw::Simplicial(s)) => s,
            _ => unreachable!("FaerLdlt forces a simplicial analysis"),
        }
    }

    /// y = K x in permuted coordinates (symmetric product from the upper triangle).
    fn sym_matvec(&self, x: &[f64], y: &mut [f64]) {
        y.fill(0.0);
        for j in 0..x.len() {
            let xj = x[j];
            let mut acc = 0.0;
            for k in self.col_ptr[j]..self.col_ptr[j + 1] {
                let i = self.row_idx[k];
                let a = self.values[k];
                if i == j {
                    acc += a * xj;
                } else {
                    y[i] += a * xj;
                    acc += a * x[i];
                }
            }
            y[j] += acc;
        }
    }
}

/// The variables coupled to very many others and the dense constraint rows of a KKT
/// structure, which both orderings put last: a row is dense when it has more than
/// `max(32, 10√n)` distinct variables, a variable when a cheap upper bound of its degree in
/// the graph of $W + J^\top J$ (Hessian neighbours plus the sizes of the non-dense rows it
/// appears in) exceeds the same limit (e.g. a static parameter shared by every transition
/// constraint). Otherwise every constraint would wait for them and the constraint block would
/// fill in completely.
pub(crate) fn dense_variables_and_rows(s: &KktStructure<'_>) -> Result<(Vec<bool>, Vec<bool>)> {
    let (n, m) = (s.n, s.m);
    if n > u32::MAX as usize {
        return Err(Error::InvalidOption {
            name: "kkt".into(),
            reason: format!("{n} variables: at most 2^32 - 1"),
        });
    }
    // the variables of each row (compressed rows by counting, then sorted and deduplicated
    // within each row)
    let mut ptr = vec![0usize; m + 1];
    for (r, _) in s.jacobian_entries() {
        ptr[r + 1] += 1;
    }
    for r in 0..m {
        ptr[r + 1] += ptr[r];
    }
    // u32 variable indices: half the memory of the pattern's
    let mut vars = vec![0u32; s.jacobian.len()];
    let mut fill = ptr[..m].to_vec();
    for (r, c) in s.jacobian_entries() {
        vars[fill[r]] = c as u32;
        fill[r] += 1;
    }
    let mut len = vec![0usize; m];
    for r in 0..m {
        let v = &mut vars[ptr[r]..ptr[r + 1]];
        v.sort_unstable();
        let mut k = 0;
        for i in 0..v.len() {
            if i == 0 || v[i] != v[k - 1] {
                v[k] = v[i];
                k += 1;
            }
        }
        len[r] = k;
    }
    let dense_limit = 32.max((10.0 * (n as f64).sqrt()) as usize);
    let dense_row: Vec<bool> = len.iter().map(|&l| l > dense_limit).collect();
    let mut degree = vec![0usize; n];
    for (i, j) in s.hessian_entries() {
        if i != j {
            degree[i] += 1;
            degree[j] += 1;
        }
    }
    for r in (0..m).filter(|&r| !dense_row[r]) {
        for &c in &vars[ptr[r]..ptr[r] + len[r]] {
            degree[c as usize] += len[r] - 1;
        }
    }
    Ok((degree.iter().map(|&d| d > dense_limit).collect(), dense_row))
}

/// The KKT ordering from an ordering of the (non-dense) primal variables: `order[p]` is the
/// variable at position `p` and `pos` its inverse (`usize::MAX` for dense variables). Each
/// non-dense constraint row is placed right after the last of its non-dense variables; dense
/// variables, then dense rows (and rows with only dense variables) come last. Returns `perm`
/// with `perm[p]` = original KKT row at position `p` (constraint r is row n + r).
pub(crate) fn place_constraints(
    s: &KktStructure<'_>,
    order: &[usize],
    pos: &[usize],
    dense_var: &[bool],
    dense_row: &[bool],
) -> Vec<usize> {
    let (n, m) = (s.n, s.m);
    let np = order.len();
    let mut last_pos = vec![usize::MAX; m];
    for (r, c) in s.jacobian_entries() {
        if !dense_row[r] && !dense_var[c] {
            let p = pos[c];
            if last_pos[r] == usize::MAX || p > last_pos[r] {
                last_pos[r] = p;
            }
        }
    }
    // bucket the constraints by the position of their last variable (counting sort)
    let mut bucket_start = vec![0usize; np + 2];
    for &p in &last_pos {
        if p != usize::MAX {
            bucket_start[p + 1] += 1;
        }
    }
    for p in 0..=np {
        bucket_start[p + 1] += bucket_start[p];
    }
    let mut bucket = vec![0usize; bucket_start[np + 1]];
    let mut fill = bucket_start.clone();
    for (r, &p) in last_pos.iter().enumerate() {
        if p != usize::MAX {
            bucket[fill[p]] = r;
            fill[p] += 1;
        }
    }
    let mut perm = Vec::with_capacity(n + m);
    for (p, &var) in order.iter().enumerate() {
        perm.push(var);
        for &r in &bucket[bucket_start[p]..bucket_start[p + 1]] {
            perm.push(n + r);
        }
    }
    perm.extend((0..n).filter(|&i| dense_var[i]));
    perm.extend((0..m).filter(|&r| last_pos[r] == usize::MAX).map(|r| n + r));
    debug_assert_eq!(perm.len(), n + m);
    perm
}

/// Approximate-minimum-degree ordering of the primal graph with each constraint placed after
/// its last variable ([`place_constraints`]). Returns `perm` with `perm[p]` = original index at
/// position `p`.
fn kkt_ordering(s: &KktStructure<'_>) -> Result<Vec<usize>> {
    let n = s.n;
    let (dense_var, dense_row) = dense_variables_and_rows(s)?;
    // the primal graph without the dense variables and rows; AMD needs a deduplicated upper
    // CSC pattern, built by counting sorts (column-major, then rows within each column)
    let mut edges: Vec<(usize, usize)> = Vec::new();
    for (i, j) in s.hessian_entries() {
        if i != j && !dense_var[i] && !dense_var[j] {
            edges.push((i.min(j), i.max(j)));
        }
    }
    let mut row_vars: Vec<Vec<usize>> = vec![Vec::new(); s.m];
    for (r, c) in s.jacobian_entries() {
        if !dense_row[r] && !dense_var[c] {
            row_vars[r].push(c);
        }
    }
    for v in &mut row_vars {
        v.sort_unstable();
        v.dedup();
        for (a, &i) in v.iter().enumerate() {
            for &j in &v[a + 1..] {
                edges.push((i, j));
            }
        }
    }
    drop(row_vars);
    for j in 0..n {
        edges.push((j, j));
    }
    let (col_ptr, row_idx) = upper_csc(n, &edges);
    drop(edges);
    let graph = SymbolicSparseColMatRef::new_checked(n, n, &col_ptr, None, &row_idx);
    let mut pperm = vec![0usize; n];
    let mut pperm_inv = vec![0usize; n];
    let mut mem = MemBuffer::try_new(amd::order_scratch::<usize>(n, row_idx.len())).map_err(|_| {
        Error::InvalidOption { name: "kkt".into(), reason: "out of memory in the ordering".into() }
    })?;
    amd::order(&mut pperm, &mut pperm_inv, graph, amd::Control::default(), MemStack::new(&mut mem)).map_err(
        |e| Error::InvalidOption { name: "kkt".into(), reason: format!("ordering failed: {e:?}") },
    )?;
    let order: Vec<usize> = pperm.iter().copied().filter(|&v| !dense_var[v]).collect();
    let mut pos = vec![usize::MAX; n];
    for (p, &v) in order.iter().enumerate() {
        pos[v] = p;
    }
    Ok(place_constraints(s, &order, &pos, &dense_var, &dense_row))
}

/// Deduplicated upper-triangular CSC pattern (`col_ptr`, `row_idx`, rows sorted within each
/// column) of `entries` `(row, column)` with `row <= column`, by two counting sorts.
fn upper_csc(dim: usize, entries: &[(usize, usize)]) -> (Vec<usize>, Vec<usize>) {
    // sort by row (counting), then stable by column: rows end up sorted within each column
    let mut row_ptr = vec![0usize; dim + 1];
    for &(i, _) in entries {
        row_ptr[i + 1] += 1;
    }
    for i in 0..dim {
        row_ptr[i + 1] += row_ptr[i];
    }
    let mut by_row = vec![0usize; entries.len()]; // columns, grouped by row
    let mut fill = row_ptr[..dim].to_vec();
    for &(i, j) in entries {
        by_row[fill[i]] = j;
        fill[i] += 1;
    }
    let mut col_ptr = vec![0usize; dim + 1];
    for &(_, j) in entries {
        col_ptr[j + 1] += 1;
    }
    for j in 0..dim {
        col_ptr[j + 1] += col_ptr[j];
    }
    let mut row_idx = vec![0usize; entries.len()];
    let mut fill = col_ptr[..dim].to_vec();
    for i in 0..dim {
        for &j in &by_row[row_ptr[i]..row_ptr[i + 1]] {
            row_idx[fill[j]] = i;
            fill[j] += 1;
        }
    }
    // deduplicate within each column (rows are sorted)
    let mut out_ptr = vec![0usize; dim + 1];
    let mut w = 0usize;
    for j in 0..dim {
        let mut last = usize::MAX;
        for k in col_ptr[j]..col_ptr[j + 1] {
            let i = row_idx[k];
            if i != last {
                row_idx[w] = i;
                w += 1;
                last = i;
            }
        }
        out_ptr[j + 1] = w;
    }
    row_idx.truncate(w);
    (out_ptr, row_idx)
}

/// How [`refine`] refines the solves with one factorisation of K.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Refinement {
    /// ‖K‖∞, in the backward error ‖r‖ / (‖b‖ + ‖K‖‖x‖).
    pub norm_k: f64,
    /// The most refinement steps after the first solve.
    pub max_steps: usize,
    /// Whether some pivots were regularised (then the relative residual must be small too).
    pub regularized: bool,
}

/// Solves `K x = b` given a solver `solve` of the factorised `K` and the product `matvec`, with
/// iterative refinement. Stops when the backward error ‖r‖ / (‖b‖ + ‖K‖‖x‖) is at most 1e-10
/// (IPOPT's `residual_ratio_max`; A. Wächter and L. T. Biegler, Math. Program. 106 (2006),
/// Sect. 3.1 and the IPOPT option reference), or at most 1e-15; when some pivots were
/// regularised (`regularized`), the relative residual ‖r‖ / ‖b‖ must also be at most 1e-10,
/// since the interior-point method then accepts the factorisation only on that residual. Also
/// stops when refinement stagnates (does not halve the backward error) or after `max_steps`
/// refinement steps; keeps the best iterate (`norm_k`, `max_steps`, `regularized`: the fields of
/// `refinement`).
/// Returns ‖b − K x‖∞ / ‖b‖∞. `r` and `prev` are workspaces of the same length.
pub(crate) fn refine(
    b: &[f64],
    x: &mut [f64],
    r: &mut [f64],
    prev: &mut [f64],
    refinement: Refinement,
    matvec: impl Fn(&[f64], &mut [f64]),
    mut solve: impl FnMut(&mut [f64]),
) -> f64 {
    let Refinement { norm_k, max_steps, regularized } = refinement;
    let dim = b.len();
    let b_norm = b.iter().fold(0.0f64, |a, &v| a.max(v.abs()));
    x.copy_from_slice(b);
    solve(x);
    // backward error ‖r‖ / (‖b‖ + ‖K‖‖x‖) of the best iterate so far, and ‖r‖ / ‖b‖
    let mut best = f64::INFINITY;
    let mut last_residual = f64::INFINITY;
    for step in 0..=max_steps {
        matvec(x, r);
        // r = b − K x and the max norms of r and x in one pass (the comparisons skip NaN and ±∞,
        // which the sum below catches: a non-finite residual counts as infinite)
        let (mut r_norm, mut x_norm, mut nan_check) = (0.0f64, 0.0f64, 0.0f64);
        for ((rp, &bp), &xp) in r.iter_mut().zip(b).zip(x.iter()) {
            let v = bp - *rp;
            *rp = v;
            let (va, xa) = (v.abs(), xp.abs());
            r_norm = if va > r_norm { va } else { r_norm };
            x_norm = if xa > x_norm { xa } else { x_norm };
            #[allow(clippy::eq_op)] // 0 for finite v, NaN otherwise
            let zero = v - v;
            nan_check += zero;
        }
        let r_norm = if nan_check == 0.0 { r_norm } else { f64::INFINITY };
        let denom = b_norm + norm_k * x_norm;
        let backward = if denom > 0.0 { r_norm / denom } else { 0.0 };
        // NaN counts as no improvement
        let improved = |limit: f64| backward.partial_cmp(&limit).is_some_and(|o| o.is_le());
        if step > 0 && !improved(0.5 * best) {
            // refinement stagnates or diverges: keep the better iterate
            if !improved(best) {
                x.copy_from_slice(prev);
            }
            break;
        }
        best = backward;
        last_residual = if b_norm > 0.0 { r_norm / b_norm } else { r_norm };
        if !backward.is_finite()
            || backward <= 1e-15
            || (backward <= 1e-10 && (!regularized || last_residual <= 1e-10))
            || step == max_steps
        {
            break;
        }
        solve(r);
        prev.copy_from_slice(x);
        for p in 0..dim {
            x[p] += r[p];
        }
    }
    last_residual
}

impl KktSolver for FaerLdlt {
    fn analyse(&mut self, s: &KktStructure<'_>) -> Result<()> {
        let (n, m) = (s.n, s.m);
        let dim = n + m;
        self.n = n;
        self.m = m;
        self.perm = kkt_ordering(s)?;
        let mut iperm = vec![0usize; dim];
        for (p, &g) in self.perm.iter().enumerate() {
            iperm[g] = p;
        }
        let upper = |a: usize, b: usize| (a.min(b), a.max(b));
        let mut entries: Vec<(usize, usize)> = Vec::with_capacity(s.hessian.len() + s.jacobian.len() + dim);
        entries.extend(s.hessian_entries().map(|(i, j)| upper(iperm[i], iperm[j])));
        entries.extend(s.jacobian_entries().map(|(r, c)| upper(iperm[n + r], iperm[c])));
        entries.extend((0..dim).map(|g| (iperm[g], iperm[g])));
        let (col_ptr, row_idx) = upper_csc(dim, &entries);
        drop(entries);
        self.row_idx = row_idx;
        self.col_ptr = col_ptr;
        let slot = |me: &Self, a: usize, b: usize| -> usize {
            let (i, j) = upper(a, b);
            let rows = &me.row_idx[me.col_ptr[j]..me.col_ptr[j + 1]];
            me.col_ptr[j] + rows.binary_search(&i).expect("entry is in the pattern")
        };
        self.slots = SlotMap::try_new(
            self.row_idx.len(),
            s.hessian_entries().map(|(i, j)| slot(self, iperm[i], iperm[j])),
            s.jacobian_entries().map(|(r, c)| slot(self, iperm[n + r], iperm[c])),
            (0..dim).map(|g| slot(self, iperm[g], iperm[g])),
        )?;
        self.values = vec![0.0; self.row_idx.len()];

        let pattern = SymbolicSparseColMatRef::new_checked(dim, dim, &self.col_ptr, None, &self.row_idx);
        let symbolic = factorize_symbolic_cholesky(
            pattern,
            Side::Upper,
            SymmetricOrdering::Identity,
            CholeskySymbolicParams {
                supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SIMPLICIAL,
                ..Default::default()
            },
        )
        .map_err(|e| Error::InvalidOption {
            name: "kkt".into(),
            reason: format!("symbolic analysis failed: {e:?}"),
        })?;
        self.l_values = vec![0.0; symbolic.len_val()];
        self.symbolic = Some(symbolic);
        self.factor_mem = Some(
            MemBuffer::try_new(simplicial::factorize_simplicial_numeric_ldlt_scratch::<usize, f64>(dim))
                .map_err(|_| Error::InvalidOption {
                    name: "kkt".into(),
                    reason: "out of memory for the factorisation workspace".into(),
                })?,
        );
        self.work_x = vec![0.0; dim];
        self.work_r = vec![0.0; dim];
        self.work_b = vec![0.0; dim];
        Ok(())
    }

    fn factorize(&mut self, v: &KktValues<'_>) -> Option<FactorInfo> {
        let (n, m) = (self.n, self.m);
        self.slots.scatter(&mut self.values, v);
        let mut max_abs = 0.0f64;
        for &a in &self.values {
            if !a.is_finite() {
                return None;
            }
            max_abs = max_abs.max(a.abs());
        }
        // infinity norm of the symmetric matrix (for the refinement's stopping test)
        let dim = n + m;
        let mut row_sums = vec![0.0; dim];
        for j in 0..dim {
            for k in self.col_ptr[j]..self.col_ptr[j + 1] {
                let i = self.row_idx[k];
                row_sums[j] += self.values[k].abs();
                if i != j {
                    row_sums[i] += self.values[k].abs();
                }
            }
        }
        self.norm_k = row_sums.iter().fold(0.0f64, |a, &b| a.max(b));
        let scale = if max_abs > 0.0 { max_abs } else { 1.0 };
        let regularization = LdltRegularization {
            dynamic_regularization_signs: None,
            dynamic_regularization_delta: REGULARIZATION_DELTA * scale,
            dynamic_regularization_epsilon: 1e-30 * scale,
        };
        let Some(mut mem) = self.factor_mem.take() else {
            return None; // `analyse` was not called
        };
        let mut l_values = std::mem::take(&mut self.l_values);
        let result = {
            let symbolic = self.simplicial();
            let a = SparseColMatRef::new(
                SymbolicSparseColMatRef::new_checked(dim, dim, &self.col_ptr, None, &self.row_idx),
                &self.values,
            );
            simplicial::factorize_simplicial_numeric_ldlt(
                &mut l_values,
                a,
                regularization,
                symbolic,
                MemStack::new(&mut mem),
            )
        };
        self.l_values = l_values;
        self.factor_mem = Some(mem);
        let info = result.ok()?;
        self.regularized = info.dynamic_regularization_count > 0;
        let symbolic = self.simplicial();
        let l_col_ptr = symbolic.col_ptr();
        let mut inertia = Inertia::default();
        for j in 0..dim {
            let d = self.l_values[l_col_ptr[j]];
            if !d.is_finite() {
                return None;
            }
            if d > 0.0 {
                inertia.positive += 1;
            } else if d < 0.0 {
                inertia.negative += 1;
            } else {
                inertia.zero += 1;
            }
        }
        Some(FactorInfo { inertia, regularized_pivots: info.dynamic_regularization_count })
    }

    fn nnz(&self) -> (usize, usize) {
        (self.matrix_nnz(), self.factor_nnz())
    }

    fn name(&self) -> &'static str {
        "faer"
    }

    fn solve_in_place(&mut self, rhs: &mut [f64]) -> f64 {
        let dim = self.n + self.m;
        let mut b = std::mem::take(&mut self.work_b);
        let mut x = std::mem::take(&mut self.work_x);
        let mut r = std::mem::take(&mut self.work_r);
        let mut prev = std::mem::take(&mut self.work_prev);
        prev.resize(dim, 0.0);
        for p in 0..dim {
            b[p] = rhs[self.perm[p]];
        }
        let mut ldlt_mem = MemBuffer::new(StackReq::EMPTY);
        let ldlt = simplicial::SimplicialLdltRef::new(self.simplicial(), &self.l_values);
        let refinement = Refinement {
            norm_k: self.norm_k,
            max_steps: self.max_refinement_steps,
            regularized: self.regularized,
        };
        let residual = refine(
            &b,
            &mut x,
            &mut r,
            &mut prev,
            refinement,
            |x, y| self.sym_matvec(x, y),
            |x| {
                let mat = MatMut::from_column_major_slice_mut(x, dim, 1);
                ldlt.solve_in_place_with_conj(Conj::No, mat, Par::Seq, MemStack::new(&mut ldlt_mem));
            },
        );
        self.last_residual = residual;
        for p in 0..dim {
            rhs[self.perm[p]] = x[p];
        }
        self.work_b = b;
        self.work_x = x;
        self.work_r = r;
        self.work_prev = prev;
        self.last_residual
    }
}

/// Where the entries of the KKT patterns go in a solver's value storage: the slot of each
/// Hessian entry, each Jacobian entry and each diagonal entry (n primal, then m dual), as `u32`
/// with [`SlotMap::ADD`] set on every entry whose slot an earlier entry (in the order Hessian,
/// Jacobian, diagonal) writes too, and the slots no entry writes (fill-in kept in the storage).
/// [`SlotMap::scatter`] then assigns the first contribution to each slot and adds the others,
/// instead of zeroing the whole storage first: the same sums in the same order, so the same
/// values bit for bit, with half the index traffic of `usize` maps and one pass fewer over the
/// storage.
#[derive(Debug, Default, Clone)]
pub(crate) struct SlotMap {
    hess: Vec<u32>,
    jac: Vec<u32>,
    diag: Vec<u32>,
    zero: Vec<u32>,
}

impl SlotMap {
    /// Flag of an entry that adds to its slot (an earlier entry assigned it).
    const ADD: u32 = 1 << 31;

    /// The map of storage with `size` slots from the slots of the Hessian, Jacobian and
    /// diagonal entries in pattern order. An error when the storage has 2³¹ slots or more.
    pub(crate) fn try_new(
        size: usize,
        hess: impl ExactSizeIterator<Item = usize>,
        jac: impl ExactSizeIterator<Item = usize>,
        diag: impl ExactSizeIterator<Item = usize>,
    ) -> Result<SlotMap> {
        if size >= Self::ADD as usize {
            return Err(Error::InvalidOption {
                name: "linear_solver".into(),
                reason: format!("the KKT storage has {size} entries, more than 2^31"),
            });
        }
        let mut written = vec![false; size];
        let hess = Self::flagged(&mut written, hess);
        let jac = Self::flagged(&mut written, jac);
        let diag = Self::flagged(&mut written, diag);
        let zero = (0..size).filter(|&s| !written[s]).map(|s| s as u32).collect();
        Ok(SlotMap { hess, jac, diag, zero })
    }

    /// The slots, each flagged [`SlotMap::ADD`] when `written` already holds it; marks them.
    fn flagged(written: &mut [bool], slots: impl ExactSizeIterator<Item = usize>) -> Vec<u32> {
        let mut out = Vec::with_capacity(slots.len());
        for s in slots {
            let add = std::mem::replace(&mut written[s], true);
            out.push(s as u32 | if add { Self::ADD } else { 0 });
        }
        out
    }

    /// Number of pattern entries (Hessian, Jacobian and diagonal).
    pub(crate) fn entries(&self) -> usize {
        self.hess.len() + self.jac.len() + self.diag.len()
    }

    /// The slots of the diagonal entries (n primal, then m dual).
    pub(crate) fn diagonal_slots(&self) -> impl ExactSizeIterator<Item = usize> + '_ {
        self.diag.iter().map(|&s| (s & !Self::ADD) as usize)
    }

    /// Writes the KKT matrix values of `v` into `values` (the solver's storage of the lower
    /// or upper triangle): the Hessian and Jacobian entries, the primal diagonal Σ + δ_w and
    /// the dual regularisation −δ_c, summed per slot in that order; zero elsewhere.
    pub(crate) fn scatter(&self, values: &mut [f64], v: &KktValues<'_>) {
        let n = v.primal_diagonal.len();
        debug_assert!(self.hess.len() == v.hessian.len() && self.jac.len() == v.jacobian.len());
        debug_assert!(self.diag.len() >= n);
        // `0.0 + x` rather than `x`: the first contribution is added to zero, as before, so
        // that a −0.0 becomes +0.0 exactly as a zeroed storage made it
        #[inline(always)]
        fn put(values: &mut [f64], flagged: u32, x: f64) {
            let s = (flagged & !SlotMap::ADD) as usize;
            let base = if flagged & SlotMap::ADD != 0 { values[s] } else { 0.0 };
            values[s] = base + x;
        }
        for &s in &self.zero {
            values[s as usize] = 0.0;
        }
        for (&s, &h) in self.hess.iter().zip(v.hessian) {
            put(values, s, h);
        }
        for (&s, &a) in self.jac.iter().zip(v.jacobian) {
            put(values, s, a);
        }
        for (&s, &d) in self.diag[..n].iter().zip(v.primal_diagonal) {
            put(values, s, d + v.delta_w);
        }
        for &s in &self.diag[n..] {
            put(values, s, -v.delta_c);
        }
    }
}
