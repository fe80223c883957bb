//! A linear layer y = x·Wᵀ + b on row-major slices, forward and backward, through `gemm` (the kernels candle's
//! CPU matmul uses). The layer only knows where its weight and bias sit in the parameter vector.

use gemm::{Parallelism, gemm};

/// One linear layer: weight [out, inp] at `w`, bias [out] at `b`, in the parameter (and gradient) vector.
#[derive(Debug, Clone, Copy)]
pub struct Lin {
    pub w: usize,
    pub b: usize,
    pub inp: usize,
    pub out: usize,
}

impl Lin {
    fn weight<'a>(&self, p: &'a [f32]) -> &'a [f32] {
        &p[self.w..self.w + self.out * self.inp]
    }

    /// y[rows, out] = x[rows, inp]·Wᵀ + b.
    pub fn forward(&self, p: &[f32], x: &[f32], rows: usize, y: &mut [f32], par: Parallelism) {
        let (inp, out) = (self.inp, self.out);
        let (x, y) = (&x[..rows * inp], &mut y[..rows * out]);
        for row in y.chunks_exact_mut(out) {
            row.copy_from_slice(&p[self.b..self.b + out]);
        }
        let w = self.weight(p);
        // SAFETY: dst is rows×out (row stride out), lhs rows×inp (row stride inp), rhs = Wᵀ, inp×out read from
        // W [out, inp] (row stride 1, column stride inp); the slices above hold exactly those elements.
        unsafe {
            gemm(
                rows,
                out,
                inp,
                y.as_mut_ptr(),
                1,
                out as isize,
                true,
                x.as_ptr(),
                1,
                inp as isize,
                w.as_ptr(),
                inp as isize,
                1,
                1.0,
                1.0,
                false,
                false,
                false,
                par,
            );
        }
    }

    /// dx[rows, inp] = dy[rows, out]·W, or dx += that when `add`.
    pub fn backward_input(&self, p: &[f32], dy: &[f32], rows: usize, dx: &mut [f32], add: bool, par: Parallelism) {
        let (inp, out) = (self.inp, self.out);
        let (dy, dx) = (&dy[..rows * out], &mut dx[..rows * inp]);
        let w = self.weight(p);
        // SAFETY: dst rows×inp, lhs dy rows×out, rhs W out×inp, all row-major and held by the slices above.
        unsafe {
            gemm(
                rows,
                inp,
                out,
                dx.as_mut_ptr(),
                1,
                inp as isize,
                add,
                dy.as_ptr(),
                1,
                out as isize,
                w.as_ptr(),
                1,
                inp as isize,
                1.0,
                1.0,
                false,
                false,
                false,
                par,
            );
        }
    }

    /// dW += dyᵀ·x and db += Σ_rows dy, into the gradient vector `g`.
    pub fn backward_params(&self, g: &mut [f32], x: &[f32], dy: &[f32], rows: usize, par: Parallelism) {
        let (inp, out) = (self.inp, self.out);
        let (x, dy) = (&x[..rows * inp], &dy[..rows * out]);
        let dw = &mut g[self.w..self.w + out * inp];
        // SAFETY: dst dW out×inp row-major; lhs dyᵀ out×rows read from dy [rows, out] (row stride 1, column
        // stride out); rhs x rows×inp row-major; all held by the slices above.
        unsafe {
            gemm(
                out,
                inp,
                rows,
                dw.as_mut_ptr(),
                1,
                inp as isize,
                true,
                dy.as_ptr(),
                out as isize,
                1,
                x.as_ptr(),
                1,
                inp as isize,
                1.0,
                1.0,
                false,
                false,
                false,
                par,
            );
        }
        let db = &mut g[self.b..self.b + out];
        for row in dy.chunks_exact(out) {
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
        lin.forward(&p, &x, 2, &mut y, Parallelism::None);
        let want_y = [1.0 - 2.0 + 6.0 + 0.25, -1.0 - 0.5 + 8.0 - 2.0, 6.0 + 3.0 + 0.25, 1.5 + 4.0 - 2.0];
        assert_eq!(y, want_y);
        let dy = [1.0, 2.0, -1.0, 0.5];
        let mut dx = [0.0; 6];
        lin.backward_input(&p, &dy, 2, &mut dx, false, Parallelism::None);
        assert_eq!(dx, [1.0 - 2.0, 2.0 + 1.0, 3.0 + 8.0, -1.0 - 0.5, -2.0 + 0.25, -3.0 + 2.0]);
        let mut g = [0.0; 8];
        lin.backward_params(&mut g, &x, &dy, 2, Parallelism::None);
        assert_eq!(g, [1.0, -4.0, 1.0, 2.0, -0.5, 4.5, 0.0, 2.5]);
    }
}
