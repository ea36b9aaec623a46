//! A variable-band (envelope, "skyline") LDLᵀ of the KKT matrix, for problems whose
//! variables can be ordered so that the matrix is banded — transcriptions of optimal control
//! and estimation problems, whose variables ordered by time couple only neighbouring
//! intervals.
//!
//! **Ordering.** Reverse Cuthill–McKee (A. George and J. W. H. Liu, *Computer Solution of
//! Large Sparse Positive Definite Systems*, Prentice-Hall 1981, Sect. 4.3; pseudo-peripheral
//! start node of Sect. 4.3.2) on the primal graph of $W + J^\top J$, traversed through the
//! constraint rows so that the cliques of $J^\top J$ are never formed; then, as for
//! [`FaerLdlt`](super::FaerLdlt), each constraint row is placed right after the last of its
//! variables, and variables coupled to very many others (static parameters) and dense
//! constraint rows are ordered last (see [`super::kkt`]). For a time-discretised problem RCM
//! recovers the time order, and the matrix becomes a band of width a few intervals plus a
//! border of the parameter rows. A problem that knows a good order of the whole KKT matrix
//! gives it as a hint ([`NlpProblem::kkt_order`](super::NlpProblem::kkt_order), passed in
//! [`KktStructure::order`]), which is then the elimination order. The path transcriptions do:
//! their time order, with each piece's constraints placed so that no pivot is structurally
//! zero, has a smaller envelope than RCM's and needs no regularised pivots (see
//! `PathNlp::kkt_order`).
//!
//! **Storage and factorisation.** Row $p$ of the lower triangle is stored densely from its
//! first nonzero column $f_p$ to the diagonal (George & Liu, Sect. 4.1, the envelope
//! scheme); $LDL^\top$ without pivoting fills in only inside this envelope (ibid.,
//! Theorem 4.1.1). The factorisation is the row-by-row (bordering) form of George & Liu,
//! Sect. 4.2.1, written for $LDL^\top$: for $j = f_p, \dots, p-1$,
//! $u_{pj} = a_{pj} - \sum_{k=\max(f_p, f_j)}^{j-1} u_{pk}\, l_{jk}$ with $u_{pk} = l_{pk} d_k$,
//! then $l_{pj} = u_{pj}/d_j$ and $d_p = a_{pp} - \sum_j u_{pj} l_{pj}$. Each inner sum is a dot
//! product of two contiguous slices. Consecutive rows with the same first column (the defect
//! constraints of one transcription interval) form a group: their sums over the columns before
//! the group are done together, up to four rows per pass over row $j$ of the factor, and the
//! columns inside the group right after each of its rows is finished (the same sums; only those
//! of eight or more terms before the group are added in another order). Pivots with $|d| \le 10^{-30}\max|K_{ij}|$ are replaced by
//! $\pm\delta\max|K_{ij}|$ ([`REGULARIZATION_DELTA`](super::kkt::REGULARIZATION_DELTA)), exactly
//! as faer's dynamic regularisation in
//! [`FaerLdlt`](super::FaerLdlt), and the inertia is read from the signs of $D$.
//!
//! No sorting is needed anywhere: the slot of entry $(p, j)$ is `row_ptr[p] + j − f_p`.

// Loops over matrix positions index several arrays (pattern, values, permutation) at once.
#![allow(clippy::needless_range_loop)]

use onsager_closures::dot;

use super::kkt::{FactorInfo, Inertia, KktSolver, KktStructure, KktValues, Refinement, SlotMap};
use crate::{Error, Result};

/// Largest mean envelope width (stored entries per row) accepted by [`BandLdlt::analyse`] in
/// its default setting; wider matrices are better served by the general sparse
/// [`FaerLdlt`](super::FaerLdlt).
pub const DEFAULT_MAX_MEAN_WIDTH: usize = 64;

/// Variable-band LDLᵀ of the KKT matrix (see the [module documentation](self)).
#[derive(Debug, Default)]
pub struct BandLdlt {
    n: usize,
    m: usize,
    /// `perm[p]` = original row of position `p`. The index arrays are `u32`, as the KKT
    /// patterns are ([`KktStructure`]); the analysis rejects an envelope of 2³² entries or more.
    perm: Vec<u32>,
    /// `iperm[g]` = position of original row `g`.
    iperm: Vec<u32>,
    /// Number of [`KktSolver::analyse`] calls answered by reusing the previous analysis.
    reused: usize,
    /// First stored column of each row.
    first: Vec<u32>,
    /// Start of each row in `values` / `factor`; the row's diagonal is at `row_ptr[p + 1] − 1`.
    row_ptr: Vec<u32>,
    /// Row groups `(p0, end)`, ascending: at least two consecutive rows with the same first
    /// column f < p0 (for example the defect constraints of one transcription interval), so
    /// that the factorisation handles the columns f..p0 before the group once for up to four
    /// of its rows. The other rows are factorised one at a time.
    groups: Vec<(usize, usize)>,
    /// Assembled lower envelope of the matrix.
    values: Vec<f64>,
    /// The factor: unit-lower L below the diagonal, D on the diagonal.
    factor: Vec<f64>,
    inv_d: Vec<f64>,
    /// The slots of the pattern entries in `values`.
    slots: SlotMap,
    work_x: Vec<f64>,
    work_r: Vec<f64>,
    work_b: Vec<f64>,
    work_prev: Vec<f64>,
    norm_k: f64,
    last_residual: f64,
    /// Number of pivots regularised by the last factorisation.
    regularized: usize,
    factored: bool,
    /// Maximum number of iterative refinement steps (default 10).
    pub max_refinement_steps: usize,
    /// Largest mean envelope width accepted by the analysis (default
    /// [`DEFAULT_MAX_MEAN_WIDTH`]); a wider envelope is an error.
    pub max_mean_width: usize,
}

impl BandLdlt {
    /// A solver with default settings; call [`KktSolver::analyse`] before use.
    pub fn new() -> Self {
        Self { max_refinement_steps: 10, max_mean_width: DEFAULT_MAX_MEAN_WIDTH, ..Default::default() }
    }

    /// Number of stored entries of the envelope (lower triangle with the diagonal), which is
    /// also the number of entries of the factor.
    pub fn envelope_size(&self) -> usize {
        self.values.len()
    }

    /// ‖b − K x‖∞ / ‖b‖∞ after the last solve.
    pub fn last_relative_residual(&self) -> f64 {
        self.last_residual
    }

    /// Number of [`KktSolver::analyse`] calls that reused the previous ordering and envelope
    /// (see [`Self::reuse_analysis`]).
    pub fn reused_analyses(&self) -> usize {
        self.reused
    }

    /// Keeps the ordering and envelope of the previous analysis for the structure `s` if they
    /// fit it: same dimensions and every entry of `s` inside the envelope (then the
    /// factorisation of the new matrix fills in only inside it, George & Liu 1981, Theorem
    /// 4.1.1). Only the slot maps of the patterns are recomputed, in O(nnz). Returns whether
    /// the analysis was reused. This is what makes repeated solves of one transcription (Monte
    /// Carlo replicates, the Laplace sd after the solve) skip the ordering. The check is
    /// structural only: a different pattern that happens to fit may be eliminated in an order a
    /// fresh analysis would not choose (a constraint row before one of its variables), which the
    /// unpivoted LDLᵀ can pay for with regularised pivots; pass the same transcription.
    pub fn reuse_analysis(&mut self, s: &KktStructure<'_>) -> bool {
        let (n, m) = (s.n, s.m);
        let dim = n + m;
        if self.n != n || self.m != m || self.row_ptr.len() != dim + 1 || self.iperm.len() != dim {
            return false;
        }
        let (iperm, first, row_ptr) = (&self.iperm, &self.first, &self.row_ptr);
        let lower = |a: u32, b: u32| if a >= b { (a as usize, b as usize) } else { (b as usize, a as usize) };
        let slot = |(r, c): (usize, usize)| {
            let f = first[r] as usize;
            (c >= f).then(|| row_ptr[r] as usize + (c - f))
        };
        let in_range = |&(i, j): &(usize, usize), rows: usize| i < rows && j < n;
        if !s.hessian_entries().all(|e| in_range(&e, n)) || !s.jacobian_entries().all(|e| in_range(&e, m)) {
            return false;
        }
        let hess: Option<Vec<usize>> =
            s.hessian_entries().map(|(i, j)| slot(lower(iperm[i], iperm[j]))).collect();
        let jac: Option<Vec<usize>> =
            s.jacobian_entries().map(|(r, c)| slot(lower(iperm[n + r], iperm[c]))).collect();
        let (Some(hess), Some(jac)) = (hess, jac) else {
            return false;
        };
        let diag: Vec<usize> = self.slots.diagonal_slots().collect();
        match SlotMap::try_new(self.values.len(), hess.into_iter(), jac.into_iter(), diag.into_iter()) {
            Ok(slots) => {
                self.slots = slots;
                self.factored = false;
                self.reused += 1;
                true
            }
            Err(_) => false,
        }
    }

    /// The ordering: `perm[p]` = original row at position `p`.
    pub fn permutation(&self) -> &[u32] {
        &self.perm
    }

    /// Row p's first column, start in `values` / `factor`, and diagonal slot.
    #[inline]
    fn row(&self, p: usize) -> (usize, usize, usize) {
        (self.first[p] as usize, self.row_ptr[p] as usize, self.row_ptr[p + 1] as usize - 1)
    }

    /// y = K x in permuted coordinates, from the stored lower envelope.
    fn sym_matvec(&self, x: &[f64], y: &mut [f64]) {
        for p in 0..x.len() {
            let (f, start, end) = self.row(p);
            let xp = x[p];
            let mut acc = self.values[end] * xp;
            if f < p {
                let row = &self.values[start..end];
                acc += dot(row, &x[f..p]);
                axpy(-xp, row, &mut y[f..p]);
            }
            // y[p] receives only the contributions of later rows, which are added after it
            y[p] = acc;
        }
    }

    /// x ← (L D Lᵀ)⁻¹ x in permuted coordinates.
    fn solve_permuted(&self, x: &mut [f64]) {
        let dim = x.len();
        for p in 0..dim {
            let (f, start, end) = self.row(p);
            if f < p {
                x[p] -= dot(&self.factor[start..end], &x[f..p]);
            }
        }
        for (xp, &inv) in x.iter_mut().zip(&self.inv_d) {
            *xp *= inv;
        }
        for p in (0..dim).rev() {
            let (f, start, end) = self.row(p);
            if f < p {
                let xp = x[p];
                let (head, _) = x.split_at_mut(p);
                axpy(xp, &self.factor[start..end], &mut head[f..]);
            }
        }
    }
}

/// y ← y − a x over the common length.
#[inline]
fn axpy(a: f64, x: &[f64], y: &mut [f64]) {
    for (yk, &xk) in y.iter_mut().zip(x) {
        *yk -= a * xk;
    }
}

/// The R dot products of the rows with x (each row at least as long as x), each summed left
/// to right, in one pass over x.
#[inline(always)]
fn multi_dot<const R: usize>(rows: [&[f64]; R], x: &[f64]) -> [f64; R] {
    let n = x.len();
    let rows = rows.map(|r| &r[..n]);
    let mut s = [0.0f64; R];
    for k in 0..n {
        let xk = x[k];
        for i in 0..R {
            s[i] += rows[i][k] * xk;
        }
    }
    s
}

/// The runs of at least two consecutive rows with the same first column f < p0 (see
/// [`BandLdlt`]'s `groups`).
fn row_groups(first: &[u32]) -> Vec<(usize, usize)> {
    let mut groups = Vec::new();
    let mut p0 = 0;
    while p0 < first.len() {
        let mut end = p0 + 1;
        while end < first.len() && first[end] == first[p0] {
            end += 1;
        }
        if (first[p0] as usize) < p0 && end - p0 >= 2 {
            groups.push((p0, end));
        }
        p0 = end;
    }
    groups
}

/// For the R consecutive rows of a group stored in `rows` (lengths `lens`, first column `f`,
/// the group starting at row `p0`), the columns f + 1..p0 before the group:
/// u_pj ← u_pj − Σ_k u_pk l_jk over k = max(f, f_j)..j − 1, for the R rows at once, so that
/// row j of the factor (in `done`) is read once for all of them.
#[inline(always)]
fn factor_shared_columns<const R: usize>(
    rows: &mut [f64],
    lens: [usize; R],
    done: &[f64],
    first: &[u32],
    row_ptr: &[u32],
    f: usize,
    p0: usize,
) {
    let mut rest = rows;
    let rows: [&mut [f64]; R] = std::array::from_fn(|i| {
        let (a, b) = std::mem::take(&mut rest).split_at_mut(lens[i]);
        rest = b;
        a
    });
    for j in f + 1..p0 {
        let k0 = f.max(first[j] as usize);
        if k0 >= j {
            continue; // row j starts at its diagonal: nothing to subtract
        }
        let (a, b) = (k0 - f, j - f);
        let dj = row_ptr[j + 1] as usize - 1;
        let lj = &done[dj - (b - a)..dj];
        let s = multi_dot(rows.each_ref().map(|r| &r[a..b]), lj);
        for i in 0..R {
            rows[i][b] -= s[i];
        }
    }
}

/// Compressed rows of a pattern: `ptr` (length `rows + 1`) and `idx`, built by counting
/// (no sorting; duplicates kept).
fn compress(rows: usize, pairs: impl Iterator<Item = (usize, usize)> + Clone) -> (Vec<usize>, Vec<usize>) {
    let mut ptr = vec![0usize; rows + 1];
    for (r, _) in pairs.clone() {
        ptr[r + 1] += 1;
    }
    for r in 0..rows {
        ptr[r + 1] += ptr[r];
    }
    let mut fill = ptr[..rows].to_vec();
    let mut idx = vec![0usize; ptr[rows]];
    for (r, c) in pairs {
        idx[fill[r]] = c;
        fill[r] += 1;
    }
    (ptr, idx)
}

/// Reverse Cuthill–McKee order of the variables that are not `dense` (George & Liu 1981,
/// Sect. 4.3), in the graph where two variables are adjacent when they share a Hessian entry
/// or a (non-dense) constraint row. Returns `order[p]` = variable at position `p`.
fn rcm_order(s: &KktStructure<'_>, dense_var: &[bool], dense_row: &[bool]) -> Vec<usize> {
    let n = s.n;
    let keep = |i: usize| !dense_var[i];
    // Hessian neighbours (both directions, no diagonal)
    let hess_pairs = s
        .hessian_entries()
        .filter(move |&(i, j)| i != j && keep(i) && keep(j))
        .flat_map(|(i, j)| [(i, j), (j, i)]);
    let (h_ptr, h_idx) = compress(n, hess_pairs);
    // constraint rows of each variable and variables of each row
    let jac = s.jacobian_entries().filter(|&(r, c)| !dense_row[r] && keep(c));
    let (v_ptr, v_rows) = compress(n, jac.clone().map(|(r, c)| (c, r)));
    let (r_ptr, r_vars) = compress(s.m, jac);
    let degree: Vec<usize> = (0..n)
        .map(|i| {
            h_ptr[i + 1] - h_ptr[i]
                + v_rows[v_ptr[i]..v_ptr[i + 1]].iter().map(|&r| r_ptr[r + 1] - r_ptr[r] - 1).sum::<usize>()
        })
        .collect();
    // the deduplicated adjacency lists, built once so that the breadth-first searches below do
    // not walk the (overlapping) constraint rows again in every pass
    let mut adj_ptr = vec![0usize; n + 1];
    let mut adj: Vec<usize> = Vec::new();
    let mut seen = vec![usize::MAX; n];
    for v in 0..n {
        if keep(v) {
            seen[v] = v;
            for &u in &h_idx[h_ptr[v]..h_ptr[v + 1]] {
                if seen[u] != v {
                    seen[u] = v;
                    adj.push(u);
                }
            }
            for &r in &v_rows[v_ptr[v]..v_ptr[v + 1]] {
                for &u in &r_vars[r_ptr[r]..r_ptr[r + 1]] {
                    if seen[u] != v {
                        seen[u] = v;
                        adj.push(u);
                    }
                }
            }
        }
        adj_ptr[v + 1] = adj.len();
    }
    drop((seen, h_ptr, h_idx, v_ptr, v_rows, r_ptr, r_vars));
    let mut level = vec![usize::MAX; n];
    let mut order: Vec<usize> = Vec::with_capacity(n);
    let mut next: Vec<usize> = Vec::new();
    // Breadth-first search from `root`, marking visited vertices with `mark`; appends the
    // visit order to `out` (neighbours in increasing degree: Cuthill–McKee) and returns the
    // position in `out` where the last level starts and the number of levels.
    // Sorting by degree matters only for the final order, not for the search of the root.
    let bfs = |root: usize,
               level: &mut [usize],
               out: &mut Vec<usize>,
               next: &mut Vec<usize>,
               mark: usize,
               sorted: bool| {
        let begin = out.len();
        level[root] = mark;
        out.push(root);
        let (mut head, mut last_level_start, mut level_end, mut depth) = (begin, begin, begin + 1, 1);
        while head < out.len() {
            if head == level_end {
                last_level_start = head;
                level_end = out.len();
                depth += 1;
            }
            let v = out[head];
            head += 1;
            next.clear();
            for &u in &adj[adj_ptr[v]..adj_ptr[v + 1]] {
                if level[u] != mark {
                    level[u] = mark;
                    next.push(u);
                }
            }
            if sorted {
                next.sort_unstable_by_key(|&u| (degree[u], u));
            }
            out.extend_from_slice(next);
        }
        (last_level_start, depth)
    };
    let mut scratch: Vec<usize> = Vec::new();
    let mut stamp = 0usize;
    for start in 0..n {
        if !keep(start) || level[start] != usize::MAX {
            continue;
        }
        // pseudo-peripheral root (George & Liu, Sect. 4.3.2): restart from a vertex of
        // minimum degree in the last level while the number of levels grows
        let mut root = start;
        let mut best_depth = 0usize;
        for _ in 0..5 {
            stamp += 1;
            // distinct from usize::MAX (unvisited) and from 0 (ordered)
            let mark = usize::MAX - stamp;
            scratch.clear();
            let (last, depth) = bfs(root, &mut level, &mut scratch, &mut next, mark, false);
            let candidate = scratch[last..].iter().copied().min_by_key(|&u| (degree[u], u)).unwrap_or(root);
            for &u in &scratch {
                level[u] = usize::MAX;
            }
            if depth <= best_depth {
                break;
            }
            best_depth = depth;
            root = candidate;
        }
        let begin = order.len();
        bfs(root, &mut level, &mut order, &mut next, 0, true);
        order[begin..].reverse();
    }
    order
}

impl KktSolver for BandLdlt {
    fn analyse(&mut self, s: &KktStructure<'_>) -> Result<()> {
        if self.reuse_analysis(s) {
            return Ok(());
        }
        // a failed analysis must leave nothing to reuse or factorise with
        self.iperm.clear();
        self.row_ptr.clear();
        let (n, m) = (s.n, s.m);
        let dim = n + m;
        self.n = n;
        self.m = m;
        self.factored = false;
        if dim > u32::MAX as usize {
            return Err(Error::InvalidOption {
                name: "linear_solver".into(),
                reason: format!("the band solver indexes at most 2^32 - 1 rows, not {dim}"),
            });
        }
        self.perm = match s.order {
            Some(hint) => {
                super::kkt::check_order(hint, dim)?;
                hint.iter().map(|&g| g as u32).collect()
            }
            None => {
                let (dense_var, dense_row) = super::kkt::dense_variables_and_rows(s)?;
                let order = rcm_order(s, &dense_var, &dense_row);
                let mut pos = vec![usize::MAX; n];
                for (p, &v) in order.iter().enumerate() {
                    pos[v] = p;
                }
                let perm = super::kkt::place_constraints(s, &order, &pos, &dense_var, &dense_row);
                perm.into_iter().map(|g| g as u32).collect()
            }
        };
        let mut iperm = vec![0u32; dim];
        for (p, &g) in self.perm.iter().enumerate() {
            iperm[g as usize] = p as u32;
        }
        // envelope: first stored column of each row
        let mut first: Vec<u32> = (0..dim as u32).collect();
        let lower = |a: u32, b: u32| if a >= b { (a as usize, b) } else { (b as usize, a) };
        let entries = s
            .hessian_entries()
            .map(|(i, j)| lower(iperm[i], iperm[j]))
            .chain(s.jacobian_entries().map(|(r, c)| lower(iperm[n + r], iperm[c])));
        for (r, c) in entries.clone() {
            first[r] = first[r].min(c);
        }
        let size: usize = (0..dim).map(|p| p - first[p] as usize + 1).sum();
        if size > u32::MAX as usize {
            return Err(Error::InvalidOption {
                name: "linear_solver".into(),
                reason: format!(
                    "the KKT matrix's envelope has {size} entries, more than the band solver's 2^32 - 1"
                ),
            });
        }
        if size > self.max_mean_width.saturating_mul(dim.max(1)) {
            return Err(Error::InvalidOption {
                name: "linear_solver".into(),
                reason: format!(
                    "the KKT matrix is not banded: its envelope has {size} entries for dimension {dim}"
                ),
            });
        }
        let mut row_ptr = vec![0u32; dim + 1];
        for p in 0..dim {
            row_ptr[p + 1] = row_ptr[p] + (p as u32 - first[p] + 1);
        }
        let slot = |(r, c): (usize, u32)| row_ptr[r] as usize + (c - first[r]) as usize;
        self.slots = SlotMap::try_new(
            size,
            s.hessian_entries().map(|(i, j)| slot(lower(iperm[i], iperm[j]))),
            s.jacobian_entries().map(|(r, c)| slot(lower(iperm[n + r], iperm[c]))),
            (0..dim).map(|g| row_ptr[iperm[g] as usize + 1] as usize - 1),
        )?;
        self.groups = row_groups(&first);
        self.first = first;
        self.row_ptr = row_ptr;
        self.iperm = iperm;
        self.values = vec![0.0; size];
        self.factor = vec![0.0; size];
        self.inv_d = vec![0.0; dim];
        self.work_x = vec![0.0; dim];
        self.work_r = vec![0.0; dim];
        self.work_b = vec![0.0; dim];
        self.work_prev = vec![0.0; dim];
        Ok(())
    }

    fn factorize(&mut self, v: &KktValues<'_>) -> Option<FactorInfo> {
        let (n, m) = (self.n, self.m);
        let dim = n + m;
        self.factored = false;
        if self.row_ptr.len() != dim + 1 {
            return None; // `analyse` was not called
        }
        self.slots.scatter(&mut self.values, v);
        // max |K_ij| and the row sums of |K| (∞-norm of the symmetric matrix) in one pass, which
        // also copies the matrix into the factor's storage; a non-finite entry makes the total
        // non-finite (the comparisons below skip NaN, the sums do not)
        let mut max_abs = 0.0f64;
        let mut total = 0.0f64;
        let mut row_sums = std::mem::take(&mut self.work_r);
        for p in 0..dim {
            let (f, start, diag_slot) = self.row(p);
            let end = diag_slot + 1;
            let (src, dst) = (&self.values[start..end], &mut self.factor[start..end]);
            let (&diag, offdiag) = src.split_last().expect("a row holds its diagonal");
            let mut s = diag.abs();
            let mut row_max = s;
            for ((rk, &a), out) in row_sums[f..p].iter_mut().zip(offdiag).zip(dst.iter_mut()) {
                *out = a;
                let a = a.abs();
                row_max = if a > row_max { a } else { row_max };
                *rk += a;
                s += a;
            }
            dst[p - f] = diag;
            max_abs = if row_max > max_abs { row_max } else { max_abs };
            // row p's own sum is complete once its stored part is added: later rows only add
            // to columns before their diagonal
            row_sums[p] = s;
            total += s;
        }
        if !total.is_finite() {
            self.work_r = row_sums;
            return None;
        }
        self.norm_k = row_sums.iter().fold(0.0f64, |a, &b| if b > a { b } else { a });
        self.work_r = row_sums;
        let scale = if max_abs > 0.0 { max_abs } else { 1.0 };
        let (eps, delta) = (1e-30 * scale, super::kkt::REGULARIZATION_DELTA * scale);
        let mut regularized = 0usize;
        let mut inertia = Inertia::default();
        let (first, row_ptr) = (&self.first, &self.row_ptr);
        let (factor, inv_d) = (&mut self.factor, &mut self.inv_d);
        // turns row p (u_p· for the columns f_p..p, then a_pp) into l_p· and d_p; None for a
        // non-finite pivot
        let mut finish = |p: usize, row: &mut [f64]| -> Option<()> {
            let fp = first[p] as usize;
            let (offdiag, diag) = row.split_at_mut(p - fp);
            let mut d = diag[0];
            for (u, &inv) in offdiag.iter_mut().zip(&inv_d[fp..p]) {
                let l = *u * inv;
                d -= *u * l;
                *u = l;
            }
            if d.abs() <= eps {
                d = if d < 0.0 { -delta } else { delta };
                regularized += 1;
            }
            if !d.is_finite() {
                return None;
            }
            diag[0] = d;
            inv_d[p] = 1.0 / d;
            if d > 0.0 {
                inertia.positive += 1;
            } else {
                inertia.negative += 1;
            }
            Some(())
        };
        let mut p = 0;
        for &(p0, end) in self.groups.iter().chain(std::iter::once(&(dim, dim))) {
            // single rows: u_pj = a_pj − Σ_k u_pk l_jk over k = max(f_p, f_j)..j − 1, the last
            // `len` entries before the diagonal of row j against the entries of row p before
            // column j (row p holds u_p· for the columns already done)
            for q in p..p0 {
                let (done, rest) = factor.split_at_mut(row_ptr[q] as usize);
                let row = &mut rest[..(row_ptr[q + 1] - row_ptr[q]) as usize];
                let fq = first[q] as usize;
                for jj in 1..q - fq {
                    let j = fq + jj;
                    let len = jj.min(j - first[j] as usize);
                    if len > 0 {
                        let dj = row_ptr[j + 1] as usize - 1;
                        row[jj] -= dot(&row[jj - len..jj], &done[dj - len..dj]);
                    }
                }
                finish(q, row)?;
            }
            if p0 == dim {
                break;
            }
            let f = first[p0] as usize;
            // a group: the columns f + 1..p0 before it (column f needs nothing), up to four
            // rows at a time
            let (done, rest) = factor.split_at_mut(row_ptr[p0] as usize);
            let mut seg = &mut rest[..(row_ptr[end] - row_ptr[p0]) as usize];
            let mut t = p0;
            while t < end {
                let r = (end - t).min(4);
                let (chunk, tail) =
                    std::mem::take(&mut seg).split_at_mut((row_ptr[t + r] - row_ptr[t]) as usize);
                seg = tail;
                let len = |i: usize| (row_ptr[t + i + 1] - row_ptr[t + i]) as usize;
                let (fr, rp) = (first, row_ptr);
                match r {
                    4 => factor_shared_columns(chunk, [len(0), len(1), len(2), len(3)], done, fr, rp, f, p0),
                    3 => factor_shared_columns(chunk, [len(0), len(1), len(2)], done, fr, rp, f, p0),
                    2 => factor_shared_columns(chunk, [len(0), len(1)], done, fr, rp, f, p0),
                    _ => factor_shared_columns(chunk, [len(0)], done, fr, rp, f, p0),
                }
                t += r;
            }
            // then its rows in order: the columns p0..q of row q were updated when the earlier
            // rows of the group were finished; finish row q and update the later rows t of the
            // group at column q: u_tq = a_tq − Σ_{k=f}^{q−1} u_tk l_qk
            for q in p0..end {
                let (q0, q1) = (row_ptr[q] as usize, row_ptr[q + 1] as usize);
                let (head, tail) = factor.split_at_mut(q1);
                finish(q, &mut head[q0..])?;
                let w = q - f;
                let lq = &head[q0..q1 - 1];
                let mut seg = &mut tail[..row_ptr[end] as usize - q1];
                for t in q + 1..end {
                    let (rt, rest) = std::mem::take(&mut seg).split_at_mut(t - f + 1);
                    seg = rest;
                    rt[w] -= dot(&rt[..w], lq);
                }
            }
            p = end;
        }
        self.factored = true;
        self.regularized = regularized;
        Some(FactorInfo { inertia, regularized_pivots: regularized })
    }

    fn solve_in_place(&mut self, rhs: &mut [f64]) -> f64 {
        let dim = self.n + self.m;
        if !self.factored {
            rhs.fill(f64::NAN);
            self.last_residual = f64::INFINITY;
            return self.last_residual;
        }
        let mut b = std::mem::take(&mut self.work_b);
        let mut x = std::mem::take(&mut self.work_x);
        let mut r = std::mem::take(&mut self.work_r);
        let mut prev = std::mem::take(&mut self.work_prev);
        for p in 0..dim {
            b[p] = rhs[self.perm[p] as usize];
        }
        let refinement = Refinement {
            norm_k: self.norm_k,
            max_steps: self.max_refinement_steps,
            regularized: self.regularized > 0,
        };
        self.last_residual = super::kkt::refine(
            &b,
            &mut x,
            &mut r,
            &mut prev,
            refinement,
            |x, y| self.sym_matvec(x, y),
            |x| self.solve_permuted(x),
        );
        for p in 0..dim {
            rhs[self.perm[p] as usize] = x[p];
        }
        self.work_b = b;
        self.work_x = x;
        self.work_r = r;
        self.work_prev = prev;
        self.last_residual
    }

    fn nnz(&self) -> (usize, usize) {
        (self.slots.entries(), self.envelope_size())
    }

    fn name(&self) -> &'static str {
        "band"
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nlp::kkt::{KktStructure, KktValues};
    use rand::{RngExt, SeedableRng};

    /// The grouped factorisation (runs of 2 to 9 rows with one first column, after columns
    /// whose own first column lies later) reproduces the assembled matrix: L D Lᵀ = K on every
    /// entry of the envelope (outside it both are zero), with no refinement to hide an error.
    #[test]
    fn grouped_rows_factorise_exactly() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(11);
        // a chain of variables (tridiagonal Hessian) and, after every fifth variable, a run of
        // g identical-pattern constraints on the five variables before it, g = 2, …, 9
        let blocks = 8usize;
        let n = 5 * blocks + 1;
        let mut hess: Vec<(usize, usize)> = (0..n).map(|i| (i, i)).collect();
        hess.extend((1..n).map(|i| (i, i - 1)));
        let mut jac = Vec::new();
        let mut m = 0;
        for b in 0..blocks {
            for _ in 0..b + 2 {
                jac.extend((5 * b..5 * b + 5).map(|c| (m, c)));
                m += 1;
            }
        }
        let (hess, jac) = (crate::nlp::tests::pairs(hess), crate::nlp::tests::pairs(jac));
        let structure = KktStructure::new(n, m, &hess, &jac);
        let mut band = BandLdlt::new();
        band.analyse(&structure).unwrap();
        let sizes: Vec<usize> = band.groups.iter().map(|&(p0, end)| end - p0).collect();
        for g in [3, 5, 9] {
            assert!(sizes.contains(&g), "group sizes {sizes:?}");
        }
        let hv: Vec<f64> = hess
            .iter()
            .map(|&(i, j)| if i == j { rng.random_range(1.0..4.0) } else { rng.random_range(-1.0..1.0) })
            .collect();
        let jv: Vec<f64> = jac.iter().map(|_| rng.random_range(-2.0..2.0)).collect();
        let sigma: Vec<f64> = (0..n).map(|_| rng.random_range(0.0..1.0)).collect();
        let values =
            KktValues { hessian: &hv, jacobian: &jv, primal_diagonal: &sigma, delta_w: 0.5, delta_c: 1e-3 };
        let info = band.factorize(&values).unwrap();
        assert_eq!(info.regularized_pivots, 0);
        let first: Vec<usize> = band.first.iter().map(|&f| f as usize).collect();
        let ptr: Vec<usize> = band.row_ptr.iter().map(|&r| r as usize).collect();
        let l = &band.factor;
        let entry = |p: usize, k: usize| if k < first[p] { 0.0 } else { l[ptr[p] + k - first[p]] };
        let scale = band.values.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        for p in 0..n + m {
            for j in first[p]..=p {
                // (L D Lᵀ)_pj = Σ_{k ≤ j} L_pk D_k L_jk with unit diagonals
                let mut s = 0.0;
                for k in first[p].max(first[j])..=j {
                    let (lp, lj) =
                        (if k == p { 1.0 } else { entry(p, k) }, if k == j { 1.0 } else { entry(j, k) });
                    s += lp * entry(k, k) * lj;
                }
                let a = band.values[ptr[p] + j - first[p]];
                assert!((s - a).abs() <= 1e-12 * scale, "entry ({p}, {j}): {s} vs {a}");
            }
        }
    }
}
