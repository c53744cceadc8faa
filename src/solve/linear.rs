//! Newton systems of the implicit dynamics: takes a model, gives a `KktSystem` that the
//! integrators assemble block by block (mass, tangent stiffness and damping, joint rows) and solve
//! in place, with a dense LU, or sparse factorizations (faer: `LDL^T` of the symmetric part, and
//! LU) whose symbolic analysis is done once per model.
//!
//! # Assembly costs O(segments)
//! Every contribution is a small fixed-size block (6 x 6 at most, `nalgebra` static sizes) of a
//! body pair, a joint row block or a cable border entry. The sparse backend scatters it straight
//! into the compressed-column values through an index map computed once per model
//! (`body_blocks`: for the block of bodies `(a, b)`, the position of row `a`'s first coordinate in
//! each of `b`'s columns; the rows of one body are contiguous in every column). No dense `n x n`
//! matrix is zeroed, filled or copied per iteration on that path. The dense backend writes the same
//! blocks into a column-major buffer that the LU then factors in place.
//!
//! # Clustered cables stay sparse (bordered form)
//! A taut cable adds `g (k g + c' h)^T` to the Newton matrix (`g = dL/dq`, `h = dLdot/dq`,
//! `k = (EA/L0 + c gamma')/beta'`, `c' = c/beta'`, see `crate::solve::dynamics`). When the route
//! crosses `BORDER_MIN_BODIES` or more moving bodies, that rank-one term would couple all of them;
//! the sparse backend instead carries the cable's tension increment `dT` as one more unknown:
//!
//! ```text
//! [ A              g    ] [dq]   [r]
//! [ (g + h c'/k)^T -1/k ] [dT] = [0]
//! ```
//!
//! Eliminating `dT = (k g + c' h)^T dq` gives back `A + g (k g + c' h)^T`: the same Newton step,
//! exactly (a Schur complement, not an approximation; tests/assembly.rs checks it to round-off).
//! The extra row is scaled by `1/k`, so a stiff cable behaves like a compliant constraint
//! (`-1/k -> 0`) instead of putting huge entries in the matrix. A slack cable's row reads `dT = 0`.
//! Classical cables (two bodies) are added directly: their four blocks are already in the pattern.
//!
//! # Choice of factorization
//! `LinearBackend::Auto` uses the dense LU below `SPARSE_MIN_SIZE` unknowns and the sparse
//! backend above; `tensegrity bench scaling` (docs/benchmarks.md) measured the crossover between about 100
//! and 200 unknowns on the 2-core development machine.
//!
//! The sparse backend factors the **symmetric part** `(A + A^T) / 2` of the Newton matrix by a
//! supernodal `LDL^T` (faer's factorization; the substitution with its factors is written out
//! here, `SymmetricFactor::solve`), and keeps an exact sparse LU (faer's simplicial LU, partial
//! pivoting, COLAMD with the borders ordered last) for when that is not good enough. Why: the
//! LU's pivoting spoils its fill-reducing order on these KKT matrices (the 64-stage helical
//! tower spent two thirds of its step in the LU and its triangular solves), while the matrix is
//! symmetric but for small terms (the dampers' `c g h^T`, gyroscopic and geometric terms of
//! rotating bodies away from equilibrium, all small beside `M beta'` at usual steps). The
//! symmetric part is quasi-definite (`+` on the coordinates, `-` on joint rows and borders), so
//! `LDL^T` needs no pivoting and keeps its order: AMD on the pattern, with every joint row moved
//! after all coordinates of the bodies it ties. Then the rows ordered so far only involve
//! coordinates ordered so far, and since the joint Jacobian has full row rank (scenes with
//! redundant joints are refused), every pivot is a true Schur complement, never a bare zero; a
//! pivot of the wrong sign (an indefinite tangent at a very large step) is replaced by a tiny one
//! of the right sign (faer's dynamic regularization). For the explicit integrator's symmetric
//! `[M, Phi_q^T; Phi_q, 0]` the `LDL^T` is exact; for the Newton matrix it is a modified
//! Newton's approximation, and `crate::solve::dynamics` turns to the exact LU for the rest of a
//! step when fresh symmetric factors do not contract the residual (`tests/assembly.rs` compares
//! the trajectories of both with damped sliding cables, fast-spinning rigid bodies and large
//! steps). `LinearBackend::SparseLu` forces the LU, for comparison. Buffers are allocated once;
//! a factorization allocates nothing (`tests/allocation.rs`).

use std::collections::BTreeSet;

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::ldlt::factor::LdltRegularization;
use faer::linalg::lu::partial_pivoting as dense_lu;
use faer::reborrow::ReborrowMut;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, LdltRef, SymbolicCholesky, SymmetricOrdering,
};
use faer::sparse::linalg::lu::{factorize_symbolic_lu, LuSymbolicParams, NumericLu, SymbolicLu};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};
use nalgebra::{DMatrix, DVector, Matrix6, Vector6};

use crate::assembly::TangentSink;
use crate::constraints::{joint_points, side_jacobian};
use crate::kinematics::{PointJacobian, PointKinematics};
use crate::model::{BodyId, CableId, Model, PointId, Pose};

/// Smallest size (unknowns) for which `Auto` uses the sparse LU.
pub const SPARSE_MIN_SIZE: usize = 200;
/// Routes crossing at least this many moving bodies are bordered on the sparse path.
pub const BORDER_MIN_BODIES: usize = 3;

/// Which factorization solves the Newton systems.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinearBackend {
    /// Dense LU with partial pivoting (faer, in place in a preallocated buffer).
    Dense,
    /// Sparse (faer), symbolic analysis once per model; clustered cables bordered; the modified
    /// Newton factors the symmetric part by `LDL^T` and turns to LU where that does not
    /// contract (module docs).
    Sparse,
    /// Sparse as `Sparse`, but always LU (the exact factorization; for comparison).
    SparseLu,
    /// Sparse from `SPARSE_MIN_SIZE` unknowns, else dense.
    Auto,
}

/// Index of each body's slot in a cable's list of distinct moving bodies.
#[derive(Debug, Clone)]
struct CableSlots {
    /// Per cable: start of its bodies in `bodies`.
    start: Vec<usize>,
    /// The distinct moving bodies of every route, concatenated.
    bodies: Vec<BodyId>,
    /// Per entry of `Model::route_points`: the point's slot in its cable, `usize::MAX` when the
    /// point is on a body without coordinates.
    point_slot: Vec<usize>,
    /// Per cable: its first entry in `Model::route_points`.
    route_start: Vec<usize>,
}

impl CableSlots {
    fn new(model: &Model) -> Self {
        let mut start = Vec::with_capacity(model.cables.len() + 1);
        let mut bodies = Vec::new();
        let mut point_slot = vec![usize::MAX; model.route_points.len()];
        for (c, cable) in model.cables.iter().enumerate() {
            start.push(bodies.len());
            for (i, p) in model.route(CableId(c)).iter().enumerate() {
                let body = model.points[p.0].body;
                if model.bodies[body.0].dof_count == 0 {
                    continue;
                }
                let mine = &bodies[start[c]..];
                let slot = match mine.iter().position(|b| *b == body) {
                    Some(s) => s,
                    None => {
                        bodies.push(body);
                        bodies.len() - 1 - start[c]
                    }
                };
                point_slot[cable.route_start + i] = slot;
            }
        }
        start.push(bodies.len());
        let route_start = model.cables.iter().map(|c| c.route_start).collect();
        Self { start, bodies, point_slot, route_start }
    }

    fn of(&self, c: usize) -> &[BodyId] {
        &self.bodies[self.start[c]..self.start[c + 1]]
    }
}

/// Where each block lives in the compressed-column values.
#[derive(Debug, Clone)]
struct SparseIndex {
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    /// Per column body `b`: `(row body a, [position of a's first row in each of b's columns])`,
    /// sorted by `a`.
    body_blocks: Vec<Vec<(usize, [usize; 6])>>,
    /// Per joint and side: position of the joint's first row in each column of the side's body.
    joint_cols: Vec<[[usize; 6]; 2]>,
    /// Per joint and side: position of the body's first coordinate in each of the joint's columns.
    joint_rows: Vec<[[usize; 3]; 2]>,
    /// Per (bordered cable, slot), in `CableSlots` order: position of the slot body's first row
    /// in the border column.
    border_col: Vec<usize>,
    /// Per (bordered cable, slot): position of the border row in each of the slot body's columns.
    border_row: Vec<[usize; 6]>,
    /// Position of every diagonal entry.
    diagonal: Vec<usize>,
}

impl SparseIndex {
    fn position(&self, row: usize, col: usize) -> usize {
        let rows = &self.row_idx[self.col_ptr[col]..self.col_ptr[col + 1]];
        self.col_ptr[col] + rows.binary_search(&row).expect("entry in the KKT pattern")
    }
}

enum Storage {
    Dense {
        a: Vec<f64>,
        lu: Vec<f64>,
        perm: Vec<usize>,
        perm_inv: Vec<usize>,
        mem: MemBuffer,
        /// The permuted right-hand side of `solve_small_lu`, `size` long.
        work: Vec<f64>,
    },
    Sparse {
        index: Box<SparseIndex>,
        values: Vec<f64>,
        symbolic: Box<SymbolicLu<usize>>,
        numeric: Box<NumericLu<usize, f64>>,
        mem: MemBuffer,
        symmetric: Option<Box<SymmetricFactor>>,
    },
}

/// Counts of the negative and positive eigenvalues of a regular symmetric matrix (its inertia;
/// a singular one has no factorization here, `KktSystem::symmetric_inertia`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Inertia {
    /// Eigenvalues below zero.
    pub negative: usize,
    /// Eigenvalues above zero.
    pub positive: usize,
}

/// Which factorization the held factors are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FactorKind {
    /// LU with partial pivoting of the assembled matrix: exact.
    Lu,
    /// `LDL^T` of the assembled matrix's symmetric part (module docs): exact for a symmetric
    /// matrix, an approximation of a nonsymmetric one.
    SymmetricLdlt,
}

/// The sparse `LDL^T` of the symmetric part `(A + A^T) / 2` of a `KktSystem`'s matrix
/// (module docs): symbolic analysis once per model, numeric factorization into preallocated
/// buffers.
struct SymmetricFactor {
    symbolic: SymbolicCholesky<usize>,
    /// Upper-triangle pattern (compressed columns) and values.
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    values: Vec<f64>,
    /// Per upper entry: positions of `A[r, c]` and `A[c, r]` in the full values.
    from: Vec<[usize; 2]>,
    /// The elimination order and its inverse.
    order: Vec<usize>,
    inv: Vec<usize>,
    l_values: Vec<f64>,
    /// `+1` for coordinates, `-1` for joint rows and borders (quasi-definite).
    signs: Vec<i8>,
    /// Positions of the coordinates' diagonal entries in `values` (regularization scale).
    coordinate_diagonal: Vec<usize>,
    /// Positions of the coordinates' diagonal entries in the upper-triangle values (shifts).
    upper_diagonal: Vec<usize>,
    /// The factor's supernodes, for `solve` (`SupernodeLayout`).
    supernodes: Vec<SupernodeLayout>,
    /// Every supernode's off-diagonal row indices, concatenated (`SupernodeLayout::pattern`).
    pattern_rows: Vec<usize>,
    /// The permuted right-hand side during `solve` (length: the system's size).
    work: Vec<f64>,
    /// One supernode's off-diagonal rows during `solve` (length: the longest pattern).
    below: Vec<f64>,
    mem: MemBuffer,
}

/// `a . b` over the common length, in four interleaved partial sums (which the compiler keeps in
/// vector registers; a single running sum it may not reorder).
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0f64; 4];
    let (a4, b4) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (a4.remainder(), b4.remainder());
    for (x, y) in a4.zip(b4) {
        for k in 0..4 {
            acc[k] += x[k] * y[k];
        }
    }
    let tail: f64 = ra.iter().zip(rb).map(|(x, y)| x * y).sum();
    (acc[0] + acc[2]) + (acc[1] + acc[3]) + tail
}

/// Where one supernode of the `LDL^T` factor lives: columns `start..start + width` of the
/// permuted system, its values a column-major `(width + rows) x width` block at `values` in the
/// factor's values (unit lower triangle below a diagonal holding `D`, then the off-diagonal
/// rows), the off-diagonal rows' indices at `pattern` in `SymmetricFactor::pattern_rows`.
#[derive(Debug, Clone)]
struct SupernodeLayout {
    start: usize,
    width: usize,
    values: usize,
    pattern: std::ops::Range<usize>,
}

impl SupernodeLayout {
    /// Rows of the block: its own columns, then the off-diagonal rows.
    fn height(&self) -> usize {
        self.width + self.pattern.len()
    }
}

/// The pivots `D` of a supernodal factor with values `values`, in the order of the permuted
/// system's columns (the supernodes cover them in order).
fn pivots<'a>(supernodes: &'a [SupernodeLayout], values: &'a [f64]) -> impl Iterator<Item = f64> + 'a {
    supernodes
        .iter()
        .flat_map(move |node| (0..node.width).map(move |j| values[node.values + j * node.height() + j]))
}

impl SymmetricFactor {
    /// The symbolic analysis for the pattern of `index` (structurally symmetric): an AMD order in
    /// which every joint row comes after all coordinates of one of its bodies, so that its pivot
    /// is the negative Schur complement `-J A^-1 J^T` of those coordinates, never a bare zero.
    /// `joint_bodies[r]`: the coordinate ranges of the moving bodies that joint row `r` ties.
    fn new(
        index: &SparseIndex,
        joint_bodies: &[Vec<std::ops::Range<usize>>],
        n: usize,
        nc: usize,
    ) -> Option<Self> {
        let size = index.col_ptr.len() - 1;
        let full = SymbolicSparseColMatRef::new_checked(size, size, &index.col_ptr, None, &index.row_idx);
        let mut amd_perm = vec![0usize; size];
        let mut amd_inv = vec![0usize; size];
        let nnz_upper = (0..size)
            .map(|j| {
                index.row_idx[index.col_ptr[j]..index.col_ptr[j + 1]].iter().filter(|&&i| i <= j).count()
            })
            .sum::<usize>();
        let mut mem = MemBuffer::new(faer::sparse::linalg::amd::order_scratch::<usize>(size, nnz_upper));
        faer::sparse::linalg::amd::order(
            &mut amd_perm,
            &mut amd_inv,
            full,
            Default::default(),
            MemStack::new(&mut mem),
        )
        .ok()?;
        // defer each joint row until all coordinates of all its bodies are ordered: then the rows
        // ordered so far involve only coordinates ordered so far, and since the joint Jacobian
        // has full row rank (scenes with redundant joints are refused) every leading block
        // `[M_CC, J_RC^T; J_RC, 0]` is regular and no pivot is a bare zero
        let mut body_of_coordinate = vec![usize::MAX; n];
        let mut remaining: Vec<usize> = Vec::new();
        let mut ranges: Vec<std::ops::Range<usize>> = Vec::new();
        for bodies in joint_bodies {
            for r in bodies {
                if !ranges.contains(r) {
                    for c in r.clone() {
                        body_of_coordinate[c] = ranges.len();
                    }
                    remaining.push(r.len());
                    ranges.push(r.clone());
                }
            }
        }
        // per joint row: how many of its bodies are not complete yet; per body: rows waiting on it
        let mut waiting_on: Vec<usize> = vec![0; nc];
        let mut waiting: Vec<Vec<usize>> = vec![Vec::new(); ranges.len()];
        for (r, bodies) in joint_bodies.iter().enumerate() {
            for b in bodies {
                let k = ranges.iter().position(|x| x == b).expect("listed");
                waiting[k].push(n + r);
                waiting_on[r] += 1;
            }
        }
        let mut order = Vec::with_capacity(size);
        let mut ready = vec![false; nc];
        for &i in &amd_perm {
            if i < n {
                order.push(i);
                let k = body_of_coordinate[i];
                if k != usize::MAX {
                    remaining[k] -= 1;
                    if remaining[k] == 0 {
                        for &row in &waiting[k] {
                            waiting_on[row - n] -= 1;
                            if waiting_on[row - n] == 0 && ready[row - n] {
                                order.push(row);
                            }
                        }
                    }
                }
            } else if i < n + nc {
                // a row is placed when AMD reaches it or when its last body completes, whichever
                // comes later
                ready[i - n] = true;
                if waiting_on[i - n] == 0 {
                    order.push(i);
                }
            } else {
                order.push(i);
            }
        }
        if order.len() != size {
            return None;
        }
        let mut inv = vec![0usize; size];
        for (p, &i) in order.iter().enumerate() {
            inv[i] = p;
        }
        // upper triangle of the pattern, and where each entry and its mirror live in the full values
        let mut col_ptr = vec![0];
        let mut row_idx = Vec::with_capacity(nnz_upper);
        let mut from = Vec::with_capacity(nnz_upper);
        let mut upper_diagonal = Vec::with_capacity(n);
        for j in 0..size {
            for k in index.col_ptr[j]..index.col_ptr[j + 1] {
                let i = index.row_idx[k];
                if i <= j {
                    if i == j && j < n {
                        upper_diagonal.push(row_idx.len());
                    }
                    row_idx.push(i);
                    from.push([k, index.position(j, i)]);
                }
            }
            col_ptr.push(row_idx.len());
        }
        let symbolic = Self::analyse(&col_ptr, &row_idx, &order, &inv)?;
        let signs = (0..size).map(|i| if i < n { 1 } else { -1 }).collect();
        let coordinate_diagonal = (0..n).map(|i| index.diagonal[i]).collect();
        let mem = Self::scratch(&symbolic);
        let (supernodes, pattern_rows) = Self::layout(&symbolic)?;
        let longest = supernodes.iter().map(|s| s.pattern.len()).max().unwrap_or(0);
        Some(Self {
            supernodes,
            pattern_rows,
            work: vec![0.0; size],
            below: vec![0.0; longest],
            l_values: vec![0.0; symbolic.len_val()],
            values: vec![0.0; row_idx.len()],
            symbolic,
            col_ptr,
            row_idx,
            from,
            order,
            inv,
            signs,
            coordinate_diagonal,
            upper_diagonal,
            mem,
        })
    }

    fn analyse(
        col_ptr: &[usize],
        row_idx: &[usize],
        order: &[usize],
        inv: &[usize],
    ) -> Option<SymbolicCholesky<usize>> {
        let size = col_ptr.len() - 1;
        let upper = SymbolicSparseColMatRef::new_checked(size, size, col_ptr, None, row_idx);
        let perm = faer::perm::PermRef::new_checked(order, inv, size);
        let params = faer::sparse::linalg::cholesky::CholeskySymbolicParams {
            supernodal_flop_ratio_threshold: faer::sparse::linalg::SupernodalThreshold::FORCE_SUPERNODAL,
            ..Default::default()
        };
        factorize_symbolic_cholesky(upper, Side::Upper, SymmetricOrdering::Custom(perm), params).ok()
    }

    /// The supernodes of a supernodal analysis (`SupernodeLayout`) and their off-diagonal rows;
    /// `None` for a simplicial one.
    fn layout(symbolic: &SymbolicCholesky<usize>) -> Option<(Vec<SupernodeLayout>, Vec<usize>)> {
        use faer::sparse::linalg::cholesky::SymbolicCholeskyRaw;
        let SymbolicCholeskyRaw::Supernodal(sn) = symbolic.raw() else {
            return None;
        };
        let mut supernodes = Vec::with_capacity(sn.n_supernodes());
        let mut rows = Vec::new();
        for s in 0..sn.n_supernodes() {
            let node = sn.supernode(s);
            let first = rows.len();
            rows.extend_from_slice(node.pattern());
            supernodes.push(SupernodeLayout {
                start: sn.supernode_begin()[s],
                width: sn.supernode_end()[s] - sn.supernode_begin()[s],
                values: sn.col_ptr_for_val()[s],
                pattern: first..rows.len(),
            });
        }
        Some((supernodes, rows))
    }

    /// faer's scratch for the numeric factorization (`solve` needs none of it).
    fn scratch(symbolic: &SymbolicCholesky<usize>) -> MemBuffer {
        MemBuffer::new(symbolic.factorize_numeric_ldlt_scratch::<f64>(Par::Seq, Default::default()))
    }

    /// Factors the symmetric part of the full matrix `full` (values in `SparseIndex` layout).
    /// Pivots of the wrong sign, or below `1e-14` of the largest coordinate diagonal, become
    /// that sign times `1e-10` of it. False when the factorization fails.
    fn factor(&mut self, full: &[f64]) -> bool {
        self.symmetrize(full);
        let size = self.col_ptr.len() - 1;
        let scale = self.coordinate_diagonal.iter().map(|&k| full[k].abs()).fold(0.0, f64::max).max(1e-300);
        let sym = SymbolicSparseColMatRef::new_checked(size, size, &self.col_ptr, None, &self.row_idx);
        let mat = SparseColMatRef::new(sym, &self.values);
        let ok = self
            .symbolic
            .factorize_numeric_ldlt(
                &mut self.l_values,
                mat,
                Side::Upper,
                LdltRegularization {
                    dynamic_regularization_signs: Some(&self.signs),
                    dynamic_regularization_delta: 1e-10 * scale,
                    dynamic_regularization_epsilon: 1e-14 * scale,
                },
                Par::Seq,
                MemStack::new(&mut self.mem),
                Default::default(),
            )
            .is_ok();
        ok && self.l_values.iter().all(|v| v.is_finite())
    }

    /// Factors the symmetric part of `full` with `shift` subtracted from every coordinate's
    /// diagonal, exactly (no regularization, no pivoting: the joint rows' order makes every
    /// pivot a Schur complement), and counts the signs of the pivots `D`: by Sylvester's law of
    /// inertia, those of the shifted matrix. `None` when a pivot is zero or a value not finite.
    fn inertia(&mut self, full: &[f64], shift: f64) -> Option<Inertia> {
        self.symmetrize(full);
        for &k in &self.upper_diagonal {
            self.values[k] -= shift;
        }
        let size = self.col_ptr.len() - 1;
        let sym = SymbolicSparseColMatRef::new_checked(size, size, &self.col_ptr, None, &self.row_idx);
        let mat = SparseColMatRef::new(sym, &self.values);
        self.symbolic
            .factorize_numeric_ldlt(
                &mut self.l_values,
                mat,
                Side::Upper,
                LdltRegularization::default(),
                Par::Seq,
                MemStack::new(&mut self.mem),
                Default::default(),
            )
            .ok()?;
        if !self.l_values.iter().all(|v| v.is_finite()) {
            return None;
        }
        let mut inertia = Inertia::default();
        for d in pivots(&self.supernodes, &self.l_values) {
            if d < 0.0 {
                inertia.negative += 1;
            } else if d > 0.0 {
                inertia.positive += 1;
            } else {
                return None;
            }
        }
        Some(inertia)
    }

    /// The upper triangle of the symmetric part `(A + A^T) / 2` of the full matrix `full`
    /// (values in `SparseIndex` layout) into `values`.
    fn symmetrize(&mut self, full: &[f64]) {
        for (v, [a, b]) in self.values.iter_mut().zip(&self.from) {
            *v = 0.5 * (full[*a] + full[*b]);
        }
    }

    /// Solves `P^T L D L^T P x = b` in place of `x` (`b` on entry), with the held factors.
    ///
    /// Written out over the supernodes instead of faer's `LdltRef::solve_in_place_with_conj`:
    /// these factors' supernodes are a few columns wide (a body's coordinates and its joint
    /// rows), and the generic solve's dense kernel calls per supernode cost more than the
    /// arithmetic (the 64-stage tower spent a third of its step there). Same operations, in
    /// column order: forward substitution with the unit lower `L`, division by `D`, backward
    /// substitution with `L^T`.
    fn solve(&mut self, x: &mut [f64]) {
        let y = &mut self.work;
        for (yi, &from) in y.iter_mut().zip(&self.order) {
            *yi = x[from];
        }
        let values = &self.l_values;
        let rows = &self.pattern_rows;
        let below = &mut self.below;
        for node in &self.supernodes {
            let (w, height) = (node.width, node.height());
            let block = &values[node.values..node.values + w * height];
            let pattern = &rows[node.pattern.clone()];
            let top = &mut y[node.start..node.start + w];
            // the diagonal block, then its rows below gathered as one sum per row
            for j in 0..w {
                let yj = top[j];
                for i in j + 1..w {
                    top[i] -= block[j * height + i] * yj;
                }
            }
            let sums = &mut below[..pattern.len()];
            sums.fill(0.0);
            for (j, &yj) in top.iter().enumerate() {
                for (s, l) in sums.iter_mut().zip(&block[j * height + w..(j + 1) * height]) {
                    *s += l * yj;
                }
            }
            for (&r, s) in pattern.iter().zip(sums.iter()) {
                y[r] -= s;
            }
        }
        for (yi, d) in y.iter_mut().zip(pivots(&self.supernodes, values)) {
            *yi /= d;
        }
        for node in self.supernodes.iter().rev() {
            let (w, height) = (node.width, node.height());
            let block = &values[node.values..node.values + w * height];
            let pattern = &rows[node.pattern.clone()];
            let known = &mut below[..pattern.len()];
            for (k, &r) in known.iter_mut().zip(pattern) {
                *k = y[r];
            }
            let top = &mut y[node.start..node.start + w];
            for j in (0..w).rev() {
                let col = &block[j * height..(j + 1) * height];
                let mut sum = dot(&col[w..], known);
                for i in j + 1..w {
                    sum += col[i] * top[i];
                }
                top[j] -= sum;
            }
        }
        for (xi, &at) in x.iter_mut().zip(&self.inv) {
            *xi = y[at];
        }
    }

    /// Stored entries of the factor `L`.
    fn factor_entries(&self) -> usize {
        self.l_values.len()
    }
}

impl Clone for SymmetricFactor {
    fn clone(&self) -> Self {
        let symbolic = Self::analyse(&self.col_ptr, &self.row_idx, &self.order, &self.inv)
            .expect("the pattern was analysed before");
        let mem = Self::scratch(&symbolic);
        Self {
            symbolic,
            order: self.order.clone(),
            inv: self.inv.clone(),
            col_ptr: self.col_ptr.clone(),
            row_idx: self.row_idx.clone(),
            values: self.values.clone(),
            from: self.from.clone(),
            l_values: self.l_values.clone(),
            signs: self.signs.clone(),
            coordinate_diagonal: self.coordinate_diagonal.clone(),
            upper_diagonal: self.upper_diagonal.clone(),
            supernodes: self.supernodes.clone(),
            pattern_rows: self.pattern_rows.clone(),
            work: self.work.clone(),
            below: self.below.clone(),
            mem,
        }
    }
}

/// One model's Newton (KKT) matrix and its factorization. Unknowns: the `n` coordinates, the
/// `nc` joint rows (multipliers), then one tension increment per bordered cable.
pub struct KktSystem {
    backend: LinearBackend,
    n: usize,
    nc: usize,
    size: usize,
    /// Rows of each joint (`JointModel::rows`).
    joint_rows: Vec<usize>,
    offsets: Vec<(usize, usize)>,
    slots: CableSlots,
    /// Per cable: index of its border unknown among the borders.
    border: Vec<Option<usize>>,
    /// Per border: position of its first slot in the `SparseIndex` border tables.
    border_slot_start: Vec<usize>,
    slot_g: Vec<Vector6<f64>>,
    slot_w: Vec<Vector6<f64>>,
    storage: Storage,
    factored: bool,
    kind: FactorKind,
}

impl std::fmt::Debug for KktSystem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("KktSystem")
            .field("backend", &self.backend)
            .field("size", &self.size)
            .field("nonzeros", &self.nonzeros())
            .finish()
    }
}

impl Clone for KktSystem {
    fn clone(&self) -> Self {
        self.rebuild()
    }
}

impl KktSystem {
    /// The Newton system of `model` factored with `backend` (`Auto` resolves by size). The sparse
    /// backend borders clustered cables and runs the symbolic analysis here, once.
    pub fn new(model: &Model, backend: LinearBackend) -> Self {
        let slots = CableSlots::new(model);
        let n = model.dof_count;
        let nc = model.constraint_count;
        let backend = match backend {
            // pulley friction couples a cable's segments through its return map, a tangent the
            // bordered sparse pattern does not hold
            _ if !model.pulley_friction.is_empty() => LinearBackend::Dense,
            LinearBackend::Auto if n + nc >= SPARSE_MIN_SIZE => LinearBackend::Sparse,
            LinearBackend::Auto => LinearBackend::Dense,
            b => b,
        };
        let symmetric_wanted = backend == LinearBackend::Sparse;
        let sparse = matches!(backend, LinearBackend::Sparse | LinearBackend::SparseLu);
        let mut border = vec![None; model.cables.len()];
        let mut border_slot_start = Vec::new();
        if sparse {
            let mut slot_total = 0;
            for (c, b) in border.iter_mut().enumerate() {
                let count = slots.of(c).len();
                if count >= BORDER_MIN_BODIES {
                    *b = Some(border_slot_start.len());
                    border_slot_start.push(slot_total);
                    slot_total += count;
                }
            }
        }
        let size = n + nc + border_slot_start.len();
        let max_slots = (0..model.cables.len()).map(|c| slots.of(c).len()).max().unwrap_or(0);
        let offsets = model.bodies.iter().map(|b| (b.dof_offset, b.dof_count)).collect();
        let storage = if sparse && size > 0 {
            Self::sparse_storage(model, &slots, &border, size, symmetric_wanted)
        } else {
            None
        };
        let (backend, storage) = match storage {
            Some(s) => (backend, s),
            None => {
                // no sparse structure (or no unknowns): dense without borders
                border.iter_mut().for_each(|b| *b = None);
                border_slot_start.clear();
                let size = n + nc;
                let req = dense_scratch(size);
                (
                    LinearBackend::Dense,
                    Storage::Dense {
                        a: vec![0.0; size * size],
                        lu: vec![0.0; size * size],
                        perm: vec![0; size],
                        perm_inv: vec![0; size],
                        mem: MemBuffer::new(req),
                        work: vec![0.0; size],
                    },
                )
            }
        };
        let size = n + nc + border_slot_start.len();
        Self {
            backend,
            n,
            nc,
            size,
            joint_rows: model.joints.iter().map(|j| j.rows).collect(),
            offsets,
            slots,
            border,
            border_slot_start,
            slot_g: vec![Vector6::zeros(); max_slots],
            slot_w: vec![Vector6::zeros(); max_slots],
            storage,
            factored: false,
            kind: FactorKind::Lu,
        }
    }

    fn rebuild(&self) -> Self {
        // the model is not kept; rebuild the storage from the tables we hold
        let storage = match &self.storage {
            Storage::Dense { a, lu, perm, perm_inv, .. } => {
                let size = perm.len();
                let req = dense_scratch(size);
                Storage::Dense {
                    a: a.clone(),
                    lu: lu.clone(),
                    perm: perm.clone(),
                    perm_inv: perm_inv.clone(),
                    mem: MemBuffer::new(req),
                    work: vec![0.0; size],
                }
            }
            Storage::Sparse { index, values, symbolic, symmetric, .. } => Storage::Sparse {
                mem: MemBuffer::new(sparse_scratch(symbolic)),
                index: index.clone(),
                values: values.clone(),
                symbolic: symbolic.clone(),
                numeric: Box::new(NumericLu::new()),
                symmetric: symmetric.clone(),
            },
        };
        Self {
            backend: self.backend,
            n: self.n,
            nc: self.nc,
            size: self.size,
            joint_rows: self.joint_rows.clone(),
            offsets: self.offsets.clone(),
            slots: self.slots.clone(),
            border: self.border.clone(),
            border_slot_start: self.border_slot_start.clone(),
            slot_g: self.slot_g.clone(),
            slot_w: self.slot_w.clone(),
            storage,
            factored: false,
            kind: FactorKind::Lu,
        }
    }

    fn sparse_storage(
        model: &Model,
        slots: &CableSlots,
        border: &[Option<usize>],
        size: usize,
        symmetric_wanted: bool,
    ) -> Option<Storage> {
        let n = model.dof_count;
        let nc = model.constraint_count;
        let dofs = |b: BodyId| {
            let body = &model.bodies[b.0];
            body.dof_offset..body.dof_offset + body.dof_count
        };
        let mut cols: Vec<BTreeSet<usize>> = vec![BTreeSet::new(); size];
        let couple = |a: BodyId, b: BodyId, cols: &mut Vec<BTreeSet<usize>>| {
            for j in dofs(b) {
                cols[j].extend(dofs(a));
            }
            for j in dofs(a) {
                cols[j].extend(dofs(b));
            }
        };
        let tie = |row: usize, b: BodyId, cols: &mut Vec<BTreeSet<usize>>| {
            for j in dofs(b) {
                cols[j].insert(row);
            }
            cols[row].extend(dofs(b));
        };
        for b in 0..model.bodies.len() {
            couple(BodyId(b), BodyId(b), &mut cols);
        }
        for (c, bordered) in border.iter().enumerate() {
            let route = model.route(CableId(c));
            match bordered {
                Some(k) => {
                    for w in route.windows(2) {
                        couple(model.points[w[0].0].body, model.points[w[1].0].body, &mut cols);
                    }
                    for &b in slots.of(c) {
                        tie(n + nc + k, b, &mut cols);
                    }
                }
                None => {
                    for &a in slots.of(c) {
                        for &b in slots.of(c) {
                            couple(a, b, &mut cols);
                        }
                    }
                }
            }
        }
        for pair in &model.strut_pairs {
            couple(pair.bars[0], pair.bars[1], &mut cols);
        }
        for coupling in &model.mass_couplings {
            couple(coupling.ends[0], coupling.ends[1], &mut cols);
        }
        // rows that turn with both bodies (a hinge's or planar joint's axis, a planar joint's
        // point row) couple them in `d(Phi_q^T lambda)/dq`
        for joint in model.joints.iter().filter(|j| j.alignment.is_some() || j.plane_normal.is_some()) {
            if let crate::model::JointTarget::Point(b) = joint.target {
                couple(model.points[joint.point.0].body, model.points[b.0].body, &mut cols);
            }
        }
        for joint in &model.joints {
            for (p, _) in joint_points(joint) {
                for r in 0..joint.rows {
                    tie(n + joint.row_offset + r, model.points[p.0].body, &mut cols);
                }
            }
        }
        for (i, c) in cols.iter_mut().enumerate() {
            c.insert(i);
        }
        let mut col_ptr = vec![0];
        let mut row_idx = Vec::new();
        for c in &cols {
            row_idx.extend(c.iter().copied());
            col_ptr.push(row_idx.len());
        }
        let mut index = SparseIndex {
            col_ptr,
            row_idx,
            body_blocks: vec![Vec::new(); model.bodies.len()],
            joint_cols: Vec::new(),
            joint_rows: Vec::new(),
            border_col: Vec::new(),
            border_row: Vec::new(),
            diagonal: Vec::new(),
        };
        index.diagonal = (0..size).map(|i| index.position(i, i)).collect();
        for (b, body) in model.bodies.iter().enumerate() {
            if body.dof_count == 0 {
                continue;
            }
            let col0 = body.dof_offset;
            let neighbours: BTreeSet<usize> = model
                .bodies
                .iter()
                .enumerate()
                .filter(|(_, a)| a.dof_count > 0)
                .filter(|(_, a)| {
                    index.row_idx[index.col_ptr[col0]..index.col_ptr[col0 + 1]].contains(&a.dof_offset)
                })
                .map(|(a, _)| a)
                .collect();
            for a in neighbours {
                let mut starts = [0; 6];
                for (c, s) in starts.iter_mut().enumerate().take(body.dof_count) {
                    *s = index.position(model.bodies[a].dof_offset, col0 + c);
                }
                index.body_blocks[b].push((a, starts));
            }
        }
        for joint in &model.joints {
            let mut jc = [[0; 6]; 2];
            let mut jr = [[0; 3]; 2];
            for (side, (p, _)) in joint_points(joint).enumerate() {
                let body = &model.bodies[model.points[p.0].body.0];
                if body.dof_count == 0 {
                    continue;
                }
                for c in 0..body.dof_count {
                    jc[side][c] = index.position(n + joint.row_offset, body.dof_offset + c);
                }
                for r in 0..joint.rows {
                    jr[side][r] = index.position(body.dof_offset, n + joint.row_offset + r);
                }
            }
            index.joint_cols.push(jc);
            index.joint_rows.push(jr);
        }
        for (c, bordered) in border.iter().enumerate() {
            let Some(k) = bordered else { continue };
            let u = n + nc + k;
            for &b in slots.of(c) {
                let body = &model.bodies[b.0];
                index.border_col.push(index.position(body.dof_offset, u));
                let mut row = [0; 6];
                for (cc, r) in row.iter_mut().enumerate().take(body.dof_count) {
                    *r = index.position(u, body.dof_offset + cc);
                }
                index.border_row.push(row);
            }
        }
        let sym = SymbolicSparseColMatRef::new_checked(size, size, &index.col_ptr, None, &index.row_idx);
        // COLAMD orders "dense" rows and columns last. Make every border (a clustered cable's row
        // and column, which touch all bodies on its route) count as dense once it is longer than
        // twice the longest ordinary column, so that eliminating it early cannot fill the factors.
        let ordinary = (0..n + nc).map(|j| index.col_ptr[j + 1] - index.col_ptr[j]).max().unwrap_or(1);
        let symbolic = factorize_symbolic_lu(sym, sparse_lu_params(2 * ordinary, size)).ok()?;
        let mut row_bodies: Vec<Vec<std::ops::Range<usize>>> = vec![Vec::new(); nc];
        for joint in &model.joints {
            let ranges: Vec<std::ops::Range<usize>> = joint_points(joint)
                .map(|(p, _)| dofs(model.points[p.0].body))
                .filter(|r| !r.is_empty())
                .collect();
            for r in 0..joint.rows {
                row_bodies[joint.row_offset + r] = ranges.clone();
            }
        }
        let symmetric = if symmetric_wanted {
            SymmetricFactor::new(&index, &row_bodies, n, nc).map(Box::new)
        } else {
            None
        };
        Some(Storage::Sparse {
            mem: MemBuffer::new(sparse_scratch(&symbolic)),
            values: vec![0.0; index.row_idx.len()],
            index: Box::new(index),
            symbolic: Box::new(symbolic),
            numeric: Box::new(NumericLu::new()),
            symmetric,
        })
    }

    /// The backend in use (never `Auto`).
    pub fn backend(&self) -> LinearBackend {
        self.backend
    }
    /// Number of unknowns: coordinates, joint rows, bordered cables.
    pub fn size(&self) -> usize {
        self.size
    }
    /// Number of cables carried as a border unknown.
    pub fn bordered_cables(&self) -> usize {
        self.border_slot_start.len()
    }
    /// Structural nonzeros of the matrix (`size^2` for the dense backend).
    pub fn nonzeros(&self) -> usize {
        match &self.storage {
            Storage::Dense { a, .. } => a.len(),
            Storage::Sparse { values, .. } => values.len(),
        }
    }

    /// Zeroes the matrix; a bordered cable's row reads `-dT = 0` until `cable_rank_one` fills it
    /// (negative, like every border pivot of the quasi-definite matrix).
    pub fn clear(&mut self) {
        match &mut self.storage {
            Storage::Dense { a, .. } => a.fill(0.0),
            Storage::Sparse { values, index, .. } => {
                values.fill(0.0);
                for k in self.n + self.nc..self.size {
                    values[index.diagonal[k]] = -1.0;
                }
            }
        }
    }

    /// `A[a, b] += scale * blk` on the bodies' coordinates (`k_a x k_b` corner of `blk`).
    pub fn add_body_block(&mut self, a: BodyId, b: BodyId, blk: &Matrix6<f64>, scale: f64) {
        let (ra, ka) = self.offsets[a.0];
        let (cb, kb) = self.offsets[b.0];
        if ka == 0 || kb == 0 {
            return;
        }
        match &mut self.storage {
            Storage::Dense { a: m, .. } => {
                let size = self.n + self.nc;
                for c in 0..kb {
                    let col = &mut m[(cb + c) * size + ra..(cb + c) * size + ra + ka];
                    for (r, x) in col.iter_mut().enumerate() {
                        *x += scale * blk[(r, c)];
                    }
                }
            }
            Storage::Sparse { values, index, .. } => {
                let blocks = &index.body_blocks[b.0];
                let at = blocks.binary_search_by_key(&a.0, |e| e.0).expect("body pair in the KKT pattern");
                let starts = &blocks[at].1;
                for (c, &s) in starts.iter().enumerate().take(kb) {
                    for (r, x) in values[s..s + ka].iter_mut().enumerate() {
                        *x += scale * blk[(r, c)];
                    }
                }
            }
        }
    }

    /// Adds `sign * J` (the joint's rows of the point Jacobian `jac`, `D J` for a support that
    /// holds some directions only: `constraints::joint_jacobian`) at joint `joint`'s rows and
    /// the `side` point's body columns, and its transpose (`Phi_q` and `Phi_q^T`).
    pub fn add_joint_jacobian(
        &mut self,
        joint: usize,
        row_offset: usize,
        side: usize,
        body: BodyId,
        jac: &PointJacobian,
        sign: f64,
    ) {
        let (off, k) = self.offsets[body.0];
        let rows = self.joint_rows[joint];
        let row0 = self.n + row_offset;
        match &mut self.storage {
            Storage::Dense { a: m, .. } => {
                let size = self.n + self.nc;
                for r in 0..rows {
                    for c in 0..k {
                        let v = sign * jac[(r, c)];
                        m[(off + c) * size + row0 + r] += v;
                        m[(row0 + r) * size + off + c] += v;
                    }
                }
            }
            Storage::Sparse { values, index, .. } => {
                let (jc, jr) = (&index.joint_cols[joint][side], &index.joint_rows[joint][side]);
                for r in 0..rows {
                    for c in 0..k {
                        let v = sign * jac[(r, c)];
                        values[jc[c] + r] += v;
                        values[jr[r] + c] += v;
                    }
                }
            }
        }
    }

    /// Adds every joint's rows `Phi_q` and columns `Phi_q^T` at the poses `poses` and point
    /// kinematics `points` (`add_joint_jacobian` for each side of each joint of `model`;
    /// `poses` may be empty when no joint holds an axis, `Workspace::poses`).
    pub fn add_joints(&mut self, model: &Model, poses: &[Pose], points: &[PointKinematics]) {
        for (j, joint) in model.joints.iter().enumerate() {
            for (side, (p, sign)) in joint_points(joint).enumerate() {
                let point = &points[p.0];
                if joint.alignment.is_some() || joint.plane_normal.is_some() {
                    let jacobian = side_jacobian(model, poses, joint, point);
                    self.add_joint_jacobian(j, joint.row_offset, side, point.body, &jacobian, sign);
                    continue;
                }
                let projected: PointJacobian;
                let jacobian = match &joint.directions {
                    None => &point.jacobian,
                    Some(d) => {
                        projected = d * point.jacobian;
                        &projected
                    }
                };
                self.add_joint_jacobian(j, joint.row_offset, side, point.body, jacobian, sign);
            }
        }
    }

    /// `A[i, i] += value` for every coordinate `i` (a Levenberg term, or the identity block).
    pub fn add_to_coordinate_diagonal(&mut self, value: f64) {
        match &mut self.storage {
            Storage::Dense { a, .. } => {
                let size = self.n + self.nc;
                for i in 0..self.n {
                    a[i * size + i] += value;
                }
            }
            Storage::Sparse { values, index, .. } => {
                for i in 0..self.n {
                    values[index.diagonal[i]] += value;
                }
            }
        }
    }

    /// Solves `A x = b` in place of `rhs` (length `size()`) with a fresh factorization of the
    /// assembled `A`. False when `A` is singular or `x` is not finite.
    pub fn solve(&mut self, rhs: &mut DVector<f64>) -> bool {
        self.factor() && self.solve_factored(rhs)
    }

    /// Factors the assembled matrix and keeps the factors (the assembly buffer may then be
    /// cleared and refilled: the factors stay until the next `factor` or `forget_factors`).
    /// False when the matrix is singular.
    pub fn factor(&mut self) -> bool {
        let size = self.size;
        self.factored = false;
        self.kind = FactorKind::Lu;
        if size == 0 {
            self.factored = true;
            return true;
        }
        let ok = match &mut self.storage {
            Storage::Dense { a, lu, perm, perm_inv, mem, .. } => {
                lu.copy_from_slice(a);
                let mut f = MatMut::from_column_major_slice_mut(lu, size, size);
                dense_lu::factor::lu_in_place(
                    f.rb_mut(),
                    perm,
                    perm_inv,
                    Par::Seq,
                    MemStack::new(mem),
                    Default::default(),
                );
                (0..size).all(|i| {
                    let d = f[(i, i)];
                    d != 0.0 && d.is_finite()
                })
            }
            Storage::Sparse { index, values, symbolic, numeric, mem, .. } => {
                let sym =
                    SymbolicSparseColMatRef::new_checked(size, size, &index.col_ptr, None, &index.row_idx);
                let mat = SparseColMatRef::new(sym, values);
                symbolic
                    .factorize_numeric_lu(numeric, mat, Par::Seq, MemStack::new(mem), Default::default())
                    .is_ok()
            }
        };
        self.factored = ok;
        ok
    }

    /// Factors the symmetric part `(A + A^T) / 2` of the assembled matrix by sparse `LDL^T`
    /// where the backend has it (module docs), else exactly like `factor`. For a symmetric
    /// matrix (the explicit integrator's `[M, Phi_q^T; Phi_q, 0]`) the factors are exact; for
    /// the nonsymmetric Newton matrix they are a modified Newton's approximation, and the
    /// caller watches the contraction. False when the factorization fails.
    pub fn factor_symmetric(&mut self) -> bool {
        let Storage::Sparse { values, symmetric: Some(sym), .. } = &mut self.storage else {
            return self.factor();
        };
        self.factored = false;
        if !sym.factor(values) {
            return self.factor();
        }
        self.kind = FactorKind::SymmetricLdlt;
        self.factored = true;
        true
    }

    /// The inertia of the symmetric part of the assembled matrix with `shift` subtracted from
    /// every coordinate's diagonal, `[[A_sym - shift I, Phi_q^T, G], [Phi_q, 0, 0], [G^T, 0, -1/k]]`
    /// (`G` the bordered cables' length gradients, `k` their axial stiffnesses), from an exact
    /// sparse `LDL^T` of it. By Sylvester's law, with `Z` an orthonormal basis of the null space
    /// of `Phi_q` (full row rank) and `A_red = Z^T (A_sym + G diag(k) G^T) Z`, its negative count
    /// is `nc + borders` plus the number of eigenvalues of `A_red` below `shift`: the stability
    /// test of an equilibrium without forming `Z` (`crate::solve::statics`). The shifted factors
    /// are then held (`solve_factored` solves with this matrix; `FactorKind::SymmetricLdlt`).
    /// `None` on the dense backend, or when a pivot is zero (`shift` is an eigenvalue of a
    /// leading block) or not finite.
    pub fn symmetric_inertia(&mut self, shift: f64) -> Option<Inertia> {
        let Storage::Sparse { values, symmetric: Some(sym), .. } = &mut self.storage else {
            return None;
        };
        self.factored = false;
        let inertia = sym.inertia(values, shift)?;
        self.kind = FactorKind::SymmetricLdlt;
        self.factored = true;
        Some(inertia)
    }

    /// The symmetric coordinate part of the assembled matrix with the bordered cables folded
    /// back in, `S = A_sym + G diag(k) G^T` (see `symmetric_inertia`), as the bilinear form
    /// `x^T S y` (`x`, `y` of length `n`). `None` on the dense backend.
    pub fn coordinate_form(&self, x: &[f64], y: &[f64]) -> Option<f64> {
        let Storage::Sparse { index, values, .. } = &self.storage else { return None };
        let n = self.n;
        let mut sum = 0.0;
        for j in 0..n {
            for k in index.col_ptr[j]..index.col_ptr[j + 1] {
                let i = index.row_idx[k];
                if i < n {
                    // x^T A_sym y = (x^T A y + y^T A x) / 2
                    sum += 0.5 * values[k] * (x[i] * y[j] + y[i] * x[j]);
                }
            }
        }
        for b in self.n + self.nc..self.size {
            let stiffness = -1.0 / values[index.diagonal[b]];
            let (mut gx, mut gy) = (0.0, 0.0);
            for (i, g) in border_gradient(index, values, n, b) {
                gx += g * x[i];
                gy += g * y[i];
            }
            sum += stiffness * gx * gy;
        }
        Some(sum)
    }

    /// A Gershgorin bound on the magnitude of every eigenvalue of `S = A_sym + G diag(k) G^T`
    /// (`coordinate_form`): the largest row sum of `|S|` over the coordinates, which by
    /// interlacing also bounds `A_red`'s (`symmetric_inertia`). `None` on the dense backend.
    pub fn coordinate_bound(&self) -> Option<f64> {
        let Storage::Sparse { index, values, .. } = &self.storage else { return None };
        let n = self.n;
        let mut rows = vec![0.0; n];
        for j in 0..n {
            for k in index.col_ptr[j]..index.col_ptr[j + 1] {
                let i = index.row_idx[k];
                if i < n {
                    rows[i] += (0.5 * (values[k] + values[index.position(j, i)])).abs();
                }
            }
        }
        for b in self.n + self.nc..self.size {
            let stiffness = (-1.0 / values[index.diagonal[b]]).abs();
            let total: f64 = border_gradient(index, values, n, b).map(|(_, g)| g.abs()).sum();
            for (i, g) in border_gradient(index, values, n, b) {
                rows[i] += stiffness * g.abs() * total;
            }
        }
        Some(rows.into_iter().fold(0.0, f64::max))
    }

    /// Which factorization the held factors are.
    pub fn factor_kind(&self) -> FactorKind {
        self.kind
    }

    /// Stored entries of the symmetric factor `L` (`factor_symmetric`), when the backend has one.
    pub fn symmetric_factor_entries(&self) -> Option<usize> {
        match &self.storage {
            Storage::Sparse { symmetric: Some(sym), .. } => Some(sym.factor_entries()),
            _ => None,
        }
    }

    /// True when factors from a successful `factor` are held.
    pub fn is_factored(&self) -> bool {
        self.factored
    }

    /// Drops the held factors (e.g. after the step size changed).
    pub fn forget_factors(&mut self) {
        self.factored = false;
    }

    /// Solves with the held factors, in place of `rhs`. False without factors or when `x` is
    /// not finite.
    pub fn solve_factored(&mut self, rhs: &mut DVector<f64>) -> bool {
        let size = self.size;
        if !self.factored {
            return false;
        }
        if size == 0 {
            return true;
        }
        let x = MatMut::from_column_major_slice_mut(rhs.as_mut_slice(), size, 1);
        match &mut self.storage {
            Storage::Dense { lu, perm, work, .. } if size <= SMALL_DENSE_SOLVE => {
                solve_small_lu(lu, perm, rhs.as_mut_slice(), work);
            }
            Storage::Dense { lu, perm, perm_inv, mem, .. } => {
                let f = faer::MatRef::from_column_major_slice(lu, size, size);
                let p = faer::perm::PermRef::new_checked(perm, perm_inv, size);
                dense_lu::solve::solve_in_place(f, f, p, x, Par::Seq, MemStack::new(mem));
            }
            Storage::Sparse { symmetric: Some(sym), .. } if self.kind == FactorKind::SymmetricLdlt => {
                sym.solve(rhs.as_mut_slice());
            }
            Storage::Sparse { symbolic, numeric, mem, .. } => {
                let lu = faer::sparse::linalg::lu::LuRef::new_unchecked(symbolic, numeric);
                lu.solve_in_place_with_conj(Conj::No, x, Par::Seq, MemStack::new(mem));
            }
        }
        rhs.iter().all(|v| v.is_finite())
    }

    /// `out = A x` with the assembled matrix (before a factorization consumes it: call between
    /// assembly and `factor`, or keep the assembly). `x` and `out` have `size()` rows.
    pub fn multiply(&self, x: &DVector<f64>, out: &mut DVector<f64>) {
        out.fill(0.0);
        match &self.storage {
            Storage::Dense { a, .. } => {
                let m = nalgebra::DMatrixView::from_slice(a, self.size, self.size);
                out.gemv(1.0, &m, x, 0.0);
            }
            Storage::Sparse { index, values, .. } => {
                for j in 0..self.size {
                    for k in index.col_ptr[j]..index.col_ptr[j + 1] {
                        out[index.row_idx[k]] += values[k] * x[j];
                    }
                }
            }
        }
    }

    /// The assembled matrix as a dense `size x size` matrix (tests and diagnostics; allocates).
    /// Call before `solve`, which consumes it.
    pub fn to_dense(&self) -> DMatrix<f64> {
        match &self.storage {
            Storage::Dense { a, .. } => DMatrix::from_column_slice(self.size, self.size, a),
            Storage::Sparse { index, values, .. } => {
                let mut m = DMatrix::zeros(self.size, self.size);
                for j in 0..self.size {
                    for k in index.col_ptr[j]..index.col_ptr[j + 1] {
                        m[(index.row_idx[k], j)] = values[k];
                    }
                }
                m
            }
        }
    }

    /// A `TangentSink` that adds `stiffness_scale * K + damping_scale * C` into this matrix.
    pub fn tangents(&mut self, stiffness_scale: f64, damping_scale: f64) -> NewtonTangents<'_> {
        NewtonTangents { kkt: self, stiffness_scale, damping_scale }
    }
}

/// The coordinate entries `(row, g_i)` of border `b`'s symmetric column: the bordered cable's
/// length gradient `G` (module docs; `n` coordinates).
fn border_gradient<'a>(
    index: &'a SparseIndex,
    values: &'a [f64],
    n: usize,
    b: usize,
) -> impl Iterator<Item = (usize, f64)> + 'a {
    (index.col_ptr[b]..index.col_ptr[b + 1])
        .map(|k| (k, index.row_idx[k]))
        .filter(move |&(_, i)| i < n)
        .map(move |(k, i)| (i, 0.5 * (values[k] + values[index.position(b, i)])))
}

/// The symbolic settings of every sparse LU here: COLAMD ordering, with rows and columns of more
/// than `dense_len` entries (of `size`) counted dense and ordered last, so that eliminating them
/// early cannot fill the factors; simplicial numeric factorization (faer's supernodal one was
/// about 2x faster on towers of 16-64 stages, but it allocates working storage in every
/// factorization; this one reuses its buffers).
fn sparse_lu_params(dense_len: usize, size: usize) -> LuSymbolicParams<'static> {
    let dense = dense_len as f64 / size.max(1) as f64;
    LuSymbolicParams {
        colamd_params: faer::sparse::linalg::colamd::Control {
            dense_row: dense,
            dense_col: dense,
            aggressive: true,
        },
        supernodal_flop_ratio_threshold: faer::sparse::linalg::SupernodalThreshold::FORCE_SIMPLICIAL,
        ..Default::default()
    }
}

/// A one-off sparse `LDL^T` (faer, AMD ordering) of a symmetric quasi-definite matrix, for
/// saddle-point solves outside the step loop (form finding). Quasi-definite (`[H A^T; A -G]`
/// with `H` and `G` positive definite) means the factorization exists for every symmetric
/// ordering, so the fill-reducing ordering is never spoiled by pivoting; a pivot whose sign
/// differs from the expected one, or whose magnitude is below `1e-13` of the largest diagonal
/// entry, is replaced by that sign times the regularization (faer's dynamic regularization).
pub struct SparseLdlt {
    size: usize,
    symbolic: SymbolicCholesky<usize>,
    values: Vec<f64>,
    mem: MemBuffer,
}

impl SparseLdlt {
    /// Factors the `size x size` symmetric matrix given by its upper-triangle entries
    /// `(row, col, value)` with `row <= col` (duplicates summed). `signs[i]` is `+1` for a row of
    /// the positive definite block and `-1` for one of the negative definite block;
    /// `regularization` (> 0, same units as the entries) replaces pivots of the wrong sign.
    /// Err with the reason when the pattern is invalid or a pivot is zero.
    pub fn factor(
        size: usize,
        upper: &[(usize, usize, f64)],
        signs: &[i8],
        regularization: f64,
    ) -> Result<Self, String> {
        let triplets: Vec<faer::sparse::Triplet<usize, usize, f64>> =
            upper.iter().map(|&(r, c, v)| faer::sparse::Triplet::new(r, c, v)).collect();
        let matrix = faer::sparse::SparseColMat::<usize, f64>::try_new_from_triplets(size, size, &triplets)
            .map_err(|e| format!("{e:?}"))?;
        let symbolic = factorize_symbolic_cholesky(
            matrix.symbolic(),
            Side::Upper,
            SymmetricOrdering::Amd,
            Default::default(),
        )
        .map_err(|e| format!("{e:?}"))?;
        let mut values = vec![0.0; symbolic.len_val()];
        let mut mem = MemBuffer::new(StackReq::or(
            symbolic.factorize_numeric_ldlt_scratch::<f64>(Par::Seq, Default::default()),
            symbolic.solve_in_place_scratch::<f64>(1, Par::Seq),
        ));
        let largest = upper.iter().filter(|e| e.0 == e.1).fold(0.0f64, |m, e| m.max(e.2.abs())).max(1e-300);
        symbolic
            .factorize_numeric_ldlt(
                &mut values,
                matrix.as_ref(),
                Side::Upper,
                LdltRegularization {
                    dynamic_regularization_signs: Some(signs),
                    dynamic_regularization_delta: regularization,
                    dynamic_regularization_epsilon: 1e-13 * largest,
                },
                Par::Seq,
                MemStack::new(&mut mem),
                Default::default(),
            )
            .map_err(|e| format!("{e:?}"))?;
        Ok(Self { size, symbolic, values, mem })
    }

    /// Stored entries of the factor `L` (its fill, a measure of the cost).
    pub fn factor_entries(&self) -> usize {
        self.values.len()
    }

    /// Solves in place of `x` (length `size`).
    pub fn solve_in_place(&mut self, x: &mut [f64]) {
        let ldlt = LdltRef::new(&self.symbolic, &self.values);
        let x = MatMut::from_column_major_slice_mut(x, self.size, 1);
        ldlt.solve_in_place_with_conj(Conj::No, x, Par::Seq, MemStack::new(&mut self.mem));
    }
}

/// Thin singular value decomposition `a = U diag(s) V^T` (faer's: nalgebra 0.35's SVD
/// reconstructed the 20 x 14 form-finding matrix of a 4-strut prism with an error of 9.5e-4,
/// singular values all near 1; see also dimforge/nalgebra#1172).
#[derive(Debug, Clone)]
pub struct ThinSvd {
    /// Left singular vectors, `m x k` (`k = min(m, n)`).
    pub u: DMatrix<f64>,
    /// Singular values, nonnegative and nonincreasing.
    pub s: DVector<f64>,
    /// Right singular vectors, `n x k`.
    pub v: DMatrix<f64>,
}

impl ThinSvd {
    /// Decomposes `a`; None when the iteration does not converge or `a` is not finite.
    pub fn new(a: &DMatrix<f64>) -> Option<Self> {
        let (m, n) = a.shape();
        if m == 0 || n == 0 {
            let k = m.min(n);
            return Some(Self { u: DMatrix::zeros(m, k), s: DVector::zeros(k), v: DMatrix::zeros(n, k) });
        }
        let f = faer::MatRef::from_column_major_slice(a.as_slice(), m, n);
        let svd = f.thin_svd().ok()?;
        let (u, s, v) = (svd.U(), svd.S().column_vector(), svd.V());
        let k = s.nrows();
        Some(Self {
            u: DMatrix::from_fn(m, k, |i, j| u[(i, j)]),
            s: DVector::from_fn(k, |i, _| s[i]),
            v: DMatrix::from_fn(n, k, |i, j| v[(i, j)]),
        })
    }

    /// The minimum-norm least-squares solution of `a x = b`, singular values `<= tol` taken
    /// as zero.
    pub fn solve(&self, b: &DVector<f64>, tol: f64) -> DVector<f64> {
        let mut c = self.u.transpose() * b;
        for (ci, si) in c.iter_mut().zip(self.s.iter()) {
            *ci = if *si > tol { *ci / si } else { 0.0 };
        }
        &self.v * c
    }
}

/// Dense systems up to this size are solved with held LU factors by `solve_small_lu`, larger
/// ones by faer's blocked triangular solves. At the six-bar's 30 unknowns faer's dispatch costs
/// several times the substitutions' own 2 n^2 flops (callgrind, `bench steps`).
const SMALL_DENSE_SOLVE: usize = 64;

/// Solves `A x = b` in place of `b` with the partial-pivoting factors of faer's
/// `lu_in_place`: `P A = L U`, `lu` column-major `n x n` holding `U` on and above the diagonal
/// and the unit lower `L` below it, `(P b)[i] = b[perm[i]]`. Forward then back substitution,
/// column by column; `work` has `n` entries. Precondition: `U`'s diagonal nonzero (`factor`
/// checks it).
fn solve_small_lu(lu: &[f64], perm: &[usize], b: &mut [f64], work: &mut [f64]) {
    let n = perm.len();
    for (w, &p) in work.iter_mut().zip(perm) {
        *w = b[p];
    }
    for j in 0..n {
        let yj = work[j];
        if yj != 0.0 {
            let column = &lu[j * n + j + 1..(j + 1) * n];
            for (y, l) in work[j + 1..].iter_mut().zip(column) {
                *y -= l * yj;
            }
        }
    }
    for j in (0..n).rev() {
        let column = &lu[j * n..j * n + j + 1];
        let xj = work[j] / column[j];
        work[j] = xj;
        if xj != 0.0 {
            for (y, u) in work[..j].iter_mut().zip(column) {
                *y -= u * xj;
            }
        }
    }
    b.copy_from_slice(work);
}

fn dense_scratch(size: usize) -> StackReq {
    StackReq::or(
        dense_lu::factor::lu_in_place_scratch::<usize, f64>(size, size, Par::Seq, Default::default()),
        dense_lu::solve::solve_in_place_scratch::<usize, f64>(size, 1, Par::Seq),
    )
}

fn sparse_scratch(symbolic: &SymbolicLu<usize>) -> StackReq {
    StackReq::or(
        symbolic.factorize_numeric_lu_scratch::<f64>(Par::Seq, Default::default()),
        symbolic.solve_in_place_scratch::<f64>(1, Par::Seq),
    )
}

/// Adds scaled tangents into a `KktSystem`: `K` times `stiffness_scale`, `C` times
/// `damping_scale` (for generalized-alpha `1/beta'` and `gamma'/beta'`).
pub struct NewtonTangents<'a> {
    kkt: &'a mut KktSystem,
    stiffness_scale: f64,
    damping_scale: f64,
}

impl TangentSink for NewtonTangents<'_> {
    fn stiffness(&mut self, a: BodyId, b: BodyId, blk: &Matrix6<f64>, scale: f64) {
        self.kkt.add_body_block(a, b, blk, scale * self.stiffness_scale);
    }
    fn damping(&mut self, a: BodyId, b: BodyId, blk: &Matrix6<f64>, scale: f64) {
        self.kkt.add_body_block(a, b, blk, scale * self.damping_scale);
    }
    fn cable_rank_one(
        &mut self,
        cable: CableId,
        route: &[PointId],
        _kin: &[PointKinematics],
        grad: &[Vector6<f64>],
        rate_grad: Option<&[Vector6<f64>]>,
        axial: f64,
        damping: f64,
    ) {
        // A += g (k g + c' h)^T, k = axial s_K + damping s_C, c' = damping s_K
        let k = axial * self.stiffness_scale + damping * self.damping_scale;
        let c_rate = damping * self.stiffness_scale;
        let kkt = &mut *self.kkt;
        let c = cable.0;
        let first = kkt.slots.start[c];
        let count = kkt.slots.start[c + 1] - first;
        debug_assert_eq!(route.len(), grad.len());
        let g = &mut kkt.slot_g[..count];
        let w = &mut kkt.slot_w[..count];
        g.fill(Vector6::zeros());
        w.fill(Vector6::zeros());
        let base = kkt.slots.route_start[c];
        let point_slot = &kkt.slots.point_slot;
        for i in 0..grad.len() {
            let s = point_slot[base + i];
            if s == usize::MAX {
                continue;
            }
            g[s] += grad[i];
            w[s] += grad[i] * k;
            if let Some(h) = rate_grad {
                w[s] += h[i] * c_rate;
            }
        }
        match kkt.border[c] {
            None => {
                for sa in 0..count {
                    for sb in 0..count {
                        let (a, b) = (kkt.slots.bodies[first + sa], kkt.slots.bodies[first + sb]);
                        let blk = kkt.slot_g[sa] * kkt.slot_w[sb].transpose();
                        kkt.add_body_block(a, b, &blk, 1.0);
                    }
                }
            }
            Some(border) => {
                let Storage::Sparse { index, values, .. } = &mut kkt.storage else {
                    unreachable!("only the sparse backend borders cables")
                };
                let t0 = kkt.border_slot_start[border];
                for s in 0..count {
                    let b = kkt.slots.bodies[first + s];
                    let kb = kkt.offsets[b.0].1;
                    let col = index.border_col[t0 + s];
                    let row = &index.border_row[t0 + s];
                    for r in 0..kb {
                        values[col + r] += kkt.slot_g[s][r];
                        values[row[r]] += kkt.slot_w[s][r] / k;
                    }
                }
                values[index.diagonal[kkt.n + kkt.nc + border]] = -1.0 / k;
            }
        }
    }
}
