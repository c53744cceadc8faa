//! Linear solves for the Newton iterations: takes the square KKT matrix of a model (coordinates
//! then constraint rows) and a right-hand side, gives the solution, with a dense LU or a
//! sparse LU (faer) whose symbolic analysis (column ordering, elimination structure) is done once
//! per model and reused for every numeric factorization.
//!
//! The sparsity pattern is fixed by the model: each body's diagonal block (mass, damping,
//! geometric and gyroscopic terms), the blocks between every pair of bodies that share a cable
//! (`g g^T` couples all bodies on a route), the constraint rows against their bodies' columns and
//! the transposes, and the diagonal. `LinearBackend::Auto` picks the sparse LU only for large, thin
//! patterns (at least `SPARSE_MIN_SIZE` unknowns and at most `SPARSE_MAX_DENSITY` of the entries
//! structurally nonzero): in `tensegrity bench scaling` on the 2-core development machine the
//! sparse LU was 1.6-1.9x faster per step for classical towers of 576-768 unknowns (3-5 % full),
//! and slower at every size for towers whose clustered cables couple every stage (16-20 % full)
//! and for all systems below about 400 unknowns.

use std::collections::BTreeSet;

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::lu::partial_pivoting as dense_lu;
use faer::reborrow::{Reborrow, ReborrowMut};
use faer::sparse::linalg::lu::{factorize_symbolic_lu, LuSymbolicParams, NumericLu, SymbolicLu};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par};
use nalgebra::{DMatrix, DVector};

use crate::model::{JointTarget, Model};

/// Smallest size (coordinates + constraint rows) for which `Auto` uses the sparse LU.
pub const SPARSE_MIN_SIZE: usize = 500;
/// Largest fraction of structurally nonzero entries for which `Auto` uses the sparse LU.
pub const SPARSE_MAX_DENSITY: f64 = 0.1;

/// Which factorization solves the Newton systems.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinearBackend {
    /// Dense LU with partial pivoting (faer, in place in a preallocated buffer).
    Dense,
    /// Sparse LU (faer), symbolic analysis once per model.
    Sparse,
    /// Sparse for large thin patterns (`SPARSE_MIN_SIZE`, `SPARSE_MAX_DENSITY`), else dense.
    Auto,
}

/// The structural nonzeros of a model's KKT matrix, in compressed-column form.
#[derive(Debug, Clone)]
pub struct KktPattern {
    size: usize,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
}

impl KktPattern {
    /// The pattern of `model`'s KKT matrix (see the module docs).
    pub fn new(model: &Model) -> Self {
        let n = model.dof_count;
        let size = n + model.constraint_count;
        let mut cols: Vec<BTreeSet<usize>> = vec![BTreeSet::new(); size];
        let dofs = |b: usize| {
            let body = &model.bodies[b];
            body.dof_offset..body.dof_offset + body.dof_count
        };
        let couple = |a: usize, b: usize, cols: &mut Vec<BTreeSet<usize>>| {
            for i in dofs(a) {
                for j in dofs(b) {
                    cols[j].insert(i);
                    cols[i].insert(j);
                }
            }
        };
        for b in 0..model.bodies.len() {
            couple(b, b, &mut cols);
        }
        for c in 0..model.cables.len() {
            let bodies: BTreeSet<usize> =
                model.route(crate::model::CableId(c)).iter().map(|p| model.points[p.0].body.0).collect();
            for &a in &bodies {
                for &b in &bodies {
                    couple(a, b, &mut cols);
                }
            }
        }
        let rows = model.joint_rows();
        for joint in &model.joints {
            let mut bodies = vec![model.points[joint.point.0].body.0];
            if let JointTarget::Point(p) = joint.target {
                bodies.push(model.points[p.0].body.0);
                couple(bodies[0], bodies[1], &mut cols);
            }
            for r in 0..rows {
                let row = n + joint.row_offset + r;
                for &b in &bodies {
                    for j in dofs(b) {
                        cols[j].insert(row);
                        cols[row].insert(j);
                    }
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
        Self { size, col_ptr, row_idx }
    }

    /// Number of structural nonzeros.
    pub fn nonzeros(&self) -> usize {
        self.row_idx.len()
    }
    /// Matrix size.
    pub fn size(&self) -> usize {
        self.size
    }
}

/// A reusable solver for one model's KKT systems.
pub struct LinearSolver {
    backend: LinearBackend,
    pattern: KktPattern,
    symbolic: Option<SymbolicLu<usize>>,
    numeric: NumericLu<usize, f64>,
    values: Vec<f64>,
    mem: MemBuffer,
    dense: Vec<f64>,
    perm: Vec<usize>,
    perm_inv: Vec<usize>,
}

impl std::fmt::Debug for LinearSolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LinearSolver")
            .field("backend", &self.backend)
            .field("size", &self.pattern.size)
            .field("nonzeros", &self.pattern.nonzeros())
            .finish()
    }
}

impl Clone for LinearSolver {
    fn clone(&self) -> Self {
        Self::from_pattern(self.pattern.clone(), self.backend)
    }
}

impl LinearSolver {
    /// A solver for `model`'s KKT matrices; `Auto` resolves to dense or sparse by size. The sparse
    /// backend runs the symbolic analysis here, once.
    pub fn new(model: &Model, backend: LinearBackend) -> Self {
        Self::from_pattern(KktPattern::new(model), backend)
    }

    fn from_pattern(pattern: KktPattern, backend: LinearBackend) -> Self {
        let backend = match backend {
            LinearBackend::Auto
                if pattern.size >= SPARSE_MIN_SIZE
                    && pattern.nonzeros() as f64
                        <= SPARSE_MAX_DENSITY * (pattern.size * pattern.size) as f64 =>
            {
                LinearBackend::Sparse
            }
            LinearBackend::Auto => LinearBackend::Dense,
            b => b,
        };
        let symbolic = if backend == LinearBackend::Sparse && pattern.size > 0 {
            let sym = SymbolicSparseColMatRef::new_checked(
                pattern.size,
                pattern.size,
                &pattern.col_ptr,
                None,
                &pattern.row_idx,
            );
            factorize_symbolic_lu(sym, LuSymbolicParams::default()).ok()
        } else {
            None
        };
        let backend = if symbolic.is_none() { LinearBackend::Dense } else { backend };
        let size = pattern.size;
        let req = match &symbolic {
            Some(s) => StackReq::or(
                s.factorize_numeric_lu_scratch::<f64>(Par::Seq, Default::default()),
                s.solve_in_place_scratch::<f64>(1, Par::Seq),
            ),
            None => StackReq::or(
                dense_lu::factor::lu_in_place_scratch::<usize, f64>(size, size, Par::Seq, Default::default()),
                dense_lu::solve::solve_in_place_scratch::<usize, f64>(size, 1, Par::Seq),
            ),
        };
        let dense_len = if symbolic.is_none() { size * size } else { 0 };
        Self {
            backend,
            dense: vec![0.0; dense_len],
            perm: vec![0; size],
            perm_inv: vec![0; size],
            values: vec![0.0; pattern.nonzeros()],
            pattern,
            symbolic,
            numeric: NumericLu::new(),
            mem: MemBuffer::new(req),
        }
    }

    /// The backend in use (never `Auto`).
    pub fn backend(&self) -> LinearBackend {
        self.backend
    }

    /// Solves `a x = b` in place of `b`. `a` is the dense KKT matrix (entries outside the pattern
    /// must be zero). Returns false when the matrix is singular or the result is not finite.
    pub fn solve(&mut self, a: &DMatrix<f64>, b: &mut DVector<f64>) -> bool {
        let ok = match self.backend {
            LinearBackend::Sparse => self.solve_sparse(a, b),
            _ => self.solve_dense(a, b),
        };
        ok && b.iter().all(|v| v.is_finite())
    }

    /// Dense LU with partial pivoting, in place in a preallocated buffer (faer; no allocation).
    fn solve_dense(&mut self, a: &DMatrix<f64>, b: &mut DVector<f64>) -> bool {
        let size = self.pattern.size;
        if size == 0 {
            return true;
        }
        self.dense.copy_from_slice(a.as_slice());
        let mut lu = MatMut::from_column_major_slice_mut(&mut self.dense, size, size);
        let (_, perm) = dense_lu::factor::lu_in_place(
            lu.rb_mut(),
            &mut self.perm,
            &mut self.perm_inv,
            Par::Seq,
            MemStack::new(&mut self.mem),
            Default::default(),
        );
        if (0..size).any(|i| {
            let d = lu[(i, i)];
            d == 0.0 || !d.is_finite()
        }) {
            return false;
        }
        let rhs = MatMut::from_column_major_slice_mut(b.as_mut_slice(), size, 1);
        dense_lu::solve::solve_in_place(lu.rb(), lu.rb(), perm, rhs, Par::Seq, MemStack::new(&mut self.mem));
        true
    }

    fn solve_sparse(&mut self, a: &DMatrix<f64>, b: &mut DVector<f64>) -> bool {
        let p = &self.pattern;
        for j in 0..p.size {
            for k in p.col_ptr[j]..p.col_ptr[j + 1] {
                self.values[k] = a[(p.row_idx[k], j)];
            }
        }
        let Some(symbolic) = &self.symbolic else { return false };
        let sym = SymbolicSparseColMatRef::new_checked(p.size, p.size, &p.col_ptr, None, &p.row_idx);
        let mat = SparseColMatRef::new(sym, &self.values);
        let stack = MemStack::new(&mut self.mem);
        let Ok(lu) =
            symbolic.factorize_numeric_lu(&mut self.numeric, mat, Par::Seq, stack, Default::default())
        else {
            return false;
        };
        let rhs = MatMut::from_column_major_slice_mut(b.as_mut_slice(), p.size, 1);
        lu.solve_in_place_with_conj(Conj::No, rhs, Par::Seq, MemStack::new(&mut self.mem));
        true
    }
}
