//! The matrix product matup's own ops and its ONNX executor use: the `gemm` crate's f32
//! product (dispatched at run time to the CPU's SIMD, AVX2 and FMA on x86-64) on one thread,
//! the callers splitting their work across matup's threads themselves; the operands' extents
//! are checked so that callers need no `unsafe`. Views may overlap (a row stride below the
//! row's length), which the ONNX executor's convolutions use.

/// A matrix view's (row stride, column stride) in its slice.
pub type Strides = (usize, usize);

/// Elements a `rows × cols` view with `strides` reaches, counted from its first.
fn extent(rows: usize, cols: usize, (rs, cs): Strides) -> usize {
    if rows == 0 || cols == 0 {
        0
    } else {
        (rows - 1) * rs + (cols - 1) * cs + 1
    }
}

/// `c ← a·b + beta·c` for `a` (m×k) and `b` (k×n) and `c` (m×n, row stride `rsc`). With
/// `beta = 0`, `c` is only written.
#[allow(clippy::too_many_arguments)]
pub fn gemm(
    (m, k, n): (usize, usize, usize),
    a: &[f32],
    sa: Strides,
    b: &[f32],
    sb: Strides,
    beta: f32,
    c: &mut [f32],
    rsc: usize,
) {
    assert!(a.len() >= extent(m, k, sa), "gemm: a is too short");
    assert!(b.len() >= extent(k, n, sb), "gemm: b is too short");
    assert!(c.len() >= extent(m, n, (rsc, 1)), "gemm: c is too short");
    // SAFETY: the asserts keep every element the product reads or writes inside the slices.
    unsafe { sgemm((m, k, n), a, sa, b, sb, beta, c.as_mut_ptr(), rsc) }
}

/// `a (m×k) · b (k×n)` as a new row-major vector, never zero-filled first (the product writes
/// every element; zero-filling the filter's per-step buffers cost ~5% of a training step).
pub fn product(
    (m, k, n): (usize, usize, usize),
    a: &[f32],
    sa: Strides,
    b: &[f32],
    sb: Strides,
) -> Vec<f32> {
    assert!(a.len() >= extent(m, k, sa), "product: a is too short");
    assert!(b.len() >= extent(k, n, sb), "product: b is too short");
    let mut c = Vec::with_capacity(m * n);
    // SAFETY: reads stay inside `a` and `b` (asserted), writes inside `c`'s capacity; with
    // β = 0 `sgemm` writes every element of C (also for k = 0) and reads none, so all m·n
    // values are initialised before `set_len`.
    unsafe {
        sgemm((m, k, n), a, sa, b, sb, 0.0, c.as_mut_ptr(), n);
        c.set_len(m * n);
    }
    c
}

/// # Safety
/// `a`, `b` and the `m × n` block at `c` (row stride `rsc`) must hold every element the
/// strides reach.
#[allow(clippy::too_many_arguments)]
unsafe fn sgemm(
    (m, k, n): (usize, usize, usize),
    a: &[f32],
    (rsa, csa): Strides,
    b: &[f32],
    (rsb, csb): Strides,
    beta: f32,
    c: *mut f32,
    rsc: usize,
) {
    if m == 0 || n == 0 {
        return;
    }
    if k == 0 {
        // An empty sum: the gemm crate may leave C untouched.
        for i in 0..m {
            for j in 0..n {
                let v = unsafe { c.add(i * rsc + j) };
                unsafe { *v = if beta == 0.0 { 0.0 } else { beta * *v } };
            }
        }
        return;
    }
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            c,
            1,
            rsc as isize,
            beta != 0.0,
            a.as_ptr(),
            csa as isize,
            rsa as isize,
            b.as_ptr(),
            csb as isize,
            rsb as isize,
            beta,
            1.0,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
    }
}
