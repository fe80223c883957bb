//! A linear layer y = x·Wᵀ + b on row-major slices, forward and backward, through `gemm` (the kernels candle's
//! CPU matmul uses). The layer only knows where its weight and bias sit in the parameter vector.

use gemm::{Parallelism, gemm};

/// One weight, bias and size of a linear layer: weight [out, inp] at `w`, bias [out] at `b`, in the parameter
/// (and gradient) vector.
#[derive(Debug, Clone, Copy)]
pub struct Lin {
    pub w: usize,
    pub b: usize,
    pub inp: usize,
    pub out: usize,
}

/// A strided operand of [`product`]: its elements, row stride and column stride.
struct Operand<'a>(&'a [f32], usize, usize);

/// dst [m, n] (row-major, row stride n) = lhs [m, k]·rhs [k, n], or += when `add`. On this thread: a training
/// step takes its threads by splitting rows (`super::step`), not inside the product.
fn product(m: usize, n: usize, k: usize, dst: &mut [f32], add: bool, lhs: Operand, rhs: Operand) {
    let last = |rows: usize, cols: usize, rs: usize, cs: usize| (rows.max(1) - 1) * rs + (cols.max(1) - 1) * cs;
    assert!(dst.len() >= m * n && lhs.0.len() > last(m, k, lhs.1, lhs.2) && rhs.0.len() > last(k, n, rhs.1, rhs.2));
    // SAFETY: the assertion above: every element gemm reads or writes, at the given strides, lies in its slice.
    unsafe {
        gemm(
            m,
            n,
            k,
            dst.as_mut_ptr(),
            1,
            n as isize,
            add,
            lhs.0.as_ptr(),
            lhs.2 as isize,
            lhs.1 as isize,
            rhs.0.as_ptr(),
            rhs.2 as isize,
            rhs.1 as isize,
            1.0,
            1.0,
            false,
            false,
            false,
            Parallelism::None,
        );
    }
}

impl Lin {
    fn weight<'a>(&self, p: &'a [f32]) -> &'a [f32] {
        &p[self.w..self.w + self.out * self.inp]
    }

    /// y[rows, out] = x[rows, inp]·Wᵀ + b.
    pub fn forward(&self, p: &[f32], x: &[f32], rows: usize, y: &mut [f32]) {
        let (inp, out) = (self.inp, self.out);
        for row in y[..rows * out].chunks_exact_mut(out) {
            row.copy_from_slice(&p[self.b..self.b + out]);
        }
        // Wᵀ [inp, out] read from W [out, inp]: row stride 1, column stride inp.
        product(rows, out, inp, y, true, Operand(x, inp, 1), Operand(self.weight(p), 1, inp));
    }

    /// dx[rows, inp] = dy[rows, out]·W, or dx += that when `add`.
    pub fn backward_input(&self, p: &[f32], dy: &[f32], rows: usize, dx: &mut [f32], add: bool) {
        let (inp, out) = (self.inp, self.out);
        product(rows, inp, out, dx, add, Operand(dy, out, 1), Operand(self.weight(p), inp, 1));
    }

    /// dW += dyᵀ·x and db += Σ_rows dy, into the gradient vector `g`.
    pub fn backward_params(&self, g: &mut [f32], x: &[f32], dy: &[f32], rows: usize) {
        let (inp, out) = (self.inp, self.out);
        // dyᵀ [out, rows] read from dy [rows, out]: row stride 1, column stride out.
        product(out, inp, rows, &mut g[self.w..self.w + out * inp], true, Operand(dy, 1, out), Operand(x, inp, 1));
        let db = &mut g[self.b..self.b + out];
        for row in dy[..rows * out].chunks_exact(out) {
            for (d, v) in db.iter_mut().zip(row) {
                *d += v;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Against the sums written out: y = xWᵀ + b, dx = dy·W, dW = dyᵀx, db = Σ dy.
    #[test]
    fn forward_and_backward_match_the_definitions() {
        let lin = Lin { w: 0, b: 6, inp: 3, out: 2 };
        let p = [1.0, 2.0, 3.0, -1.0, 0.5, 4.0, 0.25, -2.0];
        let x = [1.0, -1.0, 2.0, 0.0, 3.0, 1.0];
        let mut y = [0.0; 4];
        lin.forward(&p, &x, 2, &mut y);
        let want_y = [1.0 - 2.0 + 6.0 + 0.25, -1.0 - 0.5 + 8.0 - 2.0, 6.0 + 3.0 + 0.25, 1.5 + 4.0 - 2.0];
        assert_eq!(y, want_y);
        let dy = [1.0, 2.0, -1.0, 0.5];
        let mut dx = [0.0; 6];
        lin.backward_input(&p, &dy, 2, &mut dx, false);
        assert_eq!(dx, [1.0 - 2.0, 2.0 + 1.0, 3.0 + 8.0, -1.0 - 0.5, -2.0 + 0.25, -3.0 + 2.0]);
        let mut g = [0.0; 8];
        lin.backward_params(&mut g, &x, &dy, 2);
        assert_eq!(g, [1.0, -4.0, 1.0, 2.0, -0.5, 4.5, 0.0, 2.5]);
    }
}
