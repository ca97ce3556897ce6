//! The building blocks of both towers: linear layers, layer norm and the MLP activations, each
//! with a forward pass and the backward pass with respect to its *input* only (the weights are
//! frozen, so no weight gradients are ever formed).
//!
//! Tensors are row-major `[rows, features]` f32 slices; `rows` is tokens × sequences.

use std::ops::Range;

use rayon::prelude::*;

use super::config::Activation;
use super::matmul::{matmul, Mat, Op};
use super::packed::{self, Compute, PackedB, Precision};
#[cfg(test)]
use super::packed::{Engine, Kernel};

/// `torch.nn.Linear`: `y = x Wᵀ + b`, `W` being `[out, in]` in the checkpoint.
///
/// How `W` is stored depends on the GEMM engine, kernel and precision in force when the layer
/// is built (`packed::layer_kernel`): packed for a hand-written kernel, once for the forward
/// and once more for the input backward where the layer has one (unless
/// [`Compute::one_copy`]), or plainly for the `gemm` crate.
pub struct Linear {
    w: Weight,
    /// `[out]`, absent for the bias-free projections.
    pub b: Option<Vec<f32>>,
    pub in_dim: usize,
    pub out_dim: usize,
}

enum Weight {
    /// Forward contracts over `in`, backward over `out`: `fwd` is `Wᵀ` (k = in, n = out) in
    /// the micro-kernel's panel layout. `bwd` is `W` (k = out, n = in) for the backward
    /// `dX = dY · W`, unless the layer is built for the forward only (the text tower) or with
    /// [`Compute::one_copy`]: an f32 backward then reads `fwd`'s panels transposed
    /// (`packed::gemm_t`), 350 MB less for ViT-B/32's image tower for backward products
    /// 1.15–1.35× slower (`Kernel::fast_one_copy`). A bf16 panel
    /// pairs k = in, and `vdpbf16ps` would need out paired for the backward: a bf16 layer with
    /// a backward always keeps `bwd` (two bf16 copies take the bytes of one f32 copy).
    Packed { fwd: PackedB, bwd: Option<PackedB> },
    /// For the `gemm` crate: `[out, in]`, or `[in, out]` when `transposed`. Measured with
    /// `examples/bench_clip.rs`: `gemm` is ~2.5× slower when the right operand is transposed
    /// *and* the inner dimension is long (150×3072 · (768×3072)ᵀ: 63 GFLOPS against 164
    /// untransposed), so a layer that widens keeps `[out, in]` and a layer that narrows (MLP
    /// fc2, patch embedding) stores `Wᵀ`: the long contraction is then always untransposed.
    Plain { w: Vec<f32>, transposed: bool },
}

impl Linear {
    /// From the checkpoint's `[out, in]` weight, stored for `compute`'s kernel
    /// ([`Compute::layer_kernel`]), with the input backward.
    #[cfg(test)]
    pub fn new(
        w: Vec<f32>,
        b: Option<Vec<f32>>,
        in_dim: usize,
        out_dim: usize,
        compute: &Compute,
    ) -> Linear {
        Linear::build(w, b, in_dim, out_dim, compute, true)
    }

    /// As [`Linear::new`]; without `backward` nothing is stored for the input backward (a
    /// bf16 layer packs one copy instead of two), and `backward*` panics on a bf16 layer.
    pub fn build(
        w: Vec<f32>,
        b: Option<Vec<f32>>,
        in_dim: usize,
        out_dim: usize,
        compute: &Compute,
        backward: bool,
    ) -> Linear {
        assert_eq!(w.len(), in_dim * out_dim, "Linear weight size");
        if let Some(b) = &b {
            assert_eq!(b.len(), out_dim, "Linear bias size");
        }
        let w = match compute.layer_kernel() {
            Some(kernel) => Weight::Packed {
                fwd: PackedB::from_cols_for(kernel, &w, in_dim, out_dim),
                bwd: (backward && (kernel.precision() == Precision::Bf16 || !compute.one_copy))
                    .then(|| PackedB::from_rows_for(kernel, &w, out_dim, in_dim)),
            },
            None => {
                let transposed = in_dim > out_dim;
                let w = if transposed {
                    let mut t = vec![0.0; w.len()];
                    for o in 0..out_dim {
                        for i in 0..in_dim {
                            t[i * out_dim + o] = w[o * in_dim + i];
                        }
                    }
                    t
                } else {
                    w
                };
                Weight::Plain { w, transposed }
            }
        };
        Linear {
            w,
            b,
            in_dim,
            out_dim,
        }
    }

    /// The engine this layer was built for.
    #[cfg(test)]
    pub fn engine(&self) -> Engine {
        match self.w {
            Weight::Packed { .. } => Engine::Packed,
            Weight::Plain { .. } => Engine::Crate,
        }
    }

    /// The micro-kernel of a packed layer (`None` for the `gemm` crate).
    #[cfg(test)]
    pub fn kernel(&self) -> Option<Kernel> {
        match &self.w {
            Weight::Packed { fwd, .. } => Some(fwd.kernel()),
            Weight::Plain { .. } => None,
        }
    }

    /// `x: [rows, in]` → `[rows, out]`.
    pub fn forward(&self, x: &[f32], rows: usize) -> Vec<f32> {
        debug_assert_eq!(x.len(), rows * self.in_dim);
        self.forward_part(x, rows, 0..self.out_dim)
    }

    /// Outputs `outs` only: `x: [rows, in]` → `[rows, outs.len()]` (the q or the k|v part of
    /// a stacked projection).
    pub fn forward_part(&self, x: &[f32], rows: usize, outs: Range<usize>) -> Vec<f32> {
        let n = outs.len();
        match &self.w {
            Weight::Packed { fwd, .. } => packed::gemm_new(
                x,
                self.in_dim,
                rows,
                fwd,
                0..self.in_dim,
                outs,
                self.b.as_deref(),
            ),
            Weight::Plain { w, transposed } => {
                let mut y = match &self.b {
                    Some(b) => b[outs.clone()].repeat(rows),
                    None => vec![0.0; rows * n],
                };
                let (w, op) = self.plain_part(w, *transposed, outs, true);
                matmul(
                    &mut y,
                    n,
                    Mat::new(x, self.in_dim),
                    Op::N,
                    w,
                    op,
                    rows,
                    n,
                    self.in_dim,
                    self.b.is_some(),
                );
                y
            }
        }
    }

    /// `act(x Wᵀ + b): [rows, out]`, and `x Wᵀ + b` itself when `keep_pre` (what the backward
    /// pass needs). With packed weights the activation is applied by the product's threads to
    /// each finished tile while it is in cache (`packed::Post`); the values are the same bits
    /// as `forward` followed by `activation_forward`.
    pub fn forward_act(
        &self,
        x: &[f32],
        rows: usize,
        act: Activation,
        keep_pre: bool,
    ) -> (Vec<f32>, Option<Vec<f32>>) {
        let Weight::Packed { fwd, .. } = &self.w else {
            let mut y = self.forward(x, rows);
            if keep_pre {
                return (activation_forward_copy(act, &y), Some(y));
            }
            activation_forward(act, &mut y);
            return (y, None);
        };
        let (n, k) = (self.out_dim, self.in_dim);
        let bias = self.b.as_deref();
        if !keep_pre {
            let post = |_: usize, _: usize, v: &mut [f32]| act_forward_any(act, v);
            let y = packed::gemm_new_post(x, k, rows, fwd, 0..k, 0..n, bias, Some(&post));
            return (y, None);
        }
        let mut pre: Vec<f32> = Vec::with_capacity(rows * n);
        let dst = packed::SendPtr(pre.as_mut_ptr());
        let post = |row: usize, col: usize, v: &mut [f32]| {
            // SAFETY: `gemm_new_post` passes every element of the rows × n result exactly once
            // (`packed::Post`), so these writes stay inside `pre`'s capacity and never overlap
            // across threads.
            unsafe {
                std::ptr::copy_nonoverlapping(v.as_ptr(), dst.get().add(row * n + col), v.len())
            };
            act_forward_any(act, v);
        };
        let y = packed::gemm_new_post(x, k, rows, fwd, 0..k, 0..n, bias, Some(&post));
        // SAFETY: every element was written by `post` (see above).
        unsafe { pre.set_len(rows * n) };
        (y, Some(pre))
    }

    /// `forward` (`act` None) or `forward_act` without the pre-activation (`act` Some) into
    /// `out`, the same bits. Packed weights reuse `out`'s memory (`packed::gemm_into_post`);
    /// the `gemm` crate's path replaces it.
    pub(crate) fn forward_into(
        &self,
        x: &[f32],
        rows: usize,
        act: Option<Activation>,
        out: &mut Vec<f32>,
    ) {
        let Weight::Packed { fwd, .. } = &self.w else {
            *out = self.forward(x, rows);
            if let Some(act) = act {
                activation_forward(act, out);
            }
            return;
        };
        let k = self.in_dim;
        let post = act.map(|act| move |_: usize, _: usize, v: &mut [f32]| act_forward_any(act, v));
        let post: Option<packed::Post> = post.as_ref().map(|p| p as packed::Post);
        let bias = self.b.as_deref();
        packed::gemm_into_post(out, x, k, rows, fwd, 0..k, 0..self.out_dim, bias, post);
    }

    /// The input gradient through an activation before this layer: `(dy W) ⊙ act'(pre)`,
    /// `pre: [rows, in]` being the activation's input (fused into the product as in
    /// `forward_act`; same bits as `backward` followed by `activation_backward`).
    pub fn backward_act(&self, dy: &[f32], rows: usize, act: Activation, pre: &[f32]) -> Vec<f32> {
        assert_eq!(pre.len(), rows * self.in_dim, "backward_act: pre size");
        let Weight::Packed { fwd, bwd } = &self.w else {
            let mut dx = self.backward(dy, rows);
            activation_backward(act, pre, &mut dx);
            return dx;
        };
        let (n, k) = (self.in_dim, self.out_dim);
        let post = |row: usize, col: usize, g: &mut [f32]| {
            act_backward_any(act, &pre[row * n + col..][..g.len()], g)
        };
        match bwd {
            Some(bwd) => packed::gemm_new_post(dy, k, rows, bwd, 0..k, 0..n, None, Some(&post)),
            None => packed::gemm_t_post(dy, k, rows, Self::f32_panels(fwd), 0..k, Some(&post)),
        }
    }

    /// The forward panels, for a backward that reads them transposed: only an f32 kernel's
    /// (a bf16 layer without `bwd` was built for the forward only).
    fn f32_panels(fwd: &PackedB) -> &PackedB {
        assert!(
            fwd.kernel().precision() == Precision::F32,
            "Linear: this bf16 layer was built for the forward pass only"
        );
        fwd
    }

    // `backward`/`backward_part` mirror `forward`/`forward_part` above: the same split of a
    // stacked projection, in the transposed direction.
    /// `dy: [rows, out]` → `dx = dy W: [rows, in]`.
    pub fn backward(&self, dy: &[f32], rows: usize) -> Vec<f32> {
        debug_assert_eq!(dy.len(), rows * self.out_dim);
        self.backward_part(dy, rows, 0..self.out_dim)
    }

    /// Backward of `forward_part`: `dy: [rows, outs.len()]` → `dx: [rows, in]`.
    pub fn backward_part(&self, dy: &[f32], rows: usize, outs: Range<usize>) -> Vec<f32> {
        let n = outs.len();
        match &self.w {
            Weight::Packed { bwd: Some(bwd), .. } => {
                packed::gemm_new(dy, n, rows, bwd, outs, 0..self.in_dim, None)
            }
            Weight::Packed { fwd, bwd: None } => {
                packed::gemm_t_post(dy, n, rows, Self::f32_panels(fwd), outs, None)
            }
            Weight::Plain { w, transposed } => {
                let mut dx = vec![0.0; rows * self.in_dim];
                let (w, op) = self.plain_part(w, *transposed, outs, false);
                matmul(
                    &mut dx,
                    self.in_dim,
                    Mat::new(dy, n),
                    Op::N,
                    w,
                    op,
                    rows,
                    self.in_dim,
                    n,
                    false,
                );
                dx
            }
        }
    }

    /// The rows `outs` of `W` (stored `[out, in]`), or the columns `outs` of `Wᵀ` (stored
    /// `[in, out]`), as a `gemm`-crate operand for forward (`Wᵀ`, in × outs) or backward (`W`,
    /// outs × in).
    fn plain_part<'a>(
        &self,
        w: &'a [f32],
        transposed: bool,
        outs: Range<usize>,
        forward: bool,
    ) -> (Mat<'a>, Op) {
        let (ld, offset) = if transposed {
            (self.out_dim, outs.start)
        } else {
            (self.in_dim, outs.start * self.in_dim)
        };
        // Forward wants Wᵀ: free if Wᵀ is what is stored. Backward wants W.
        let op = if forward == transposed { Op::N } else { Op::T };
        (Mat::new(&w[offset..], ld), op)
    }
}

/// `torch.nn.LayerNorm` over the last dimension.
pub struct LayerNorm {
    pub gamma: Vec<f32>,
    pub beta: Vec<f32>,
    pub eps: f32,
}

/// What layer-norm backward needs: the normalized input and 1/σ per row.
pub struct LnSaved {
    /// `[rows, dim]`
    pub xhat: Vec<f32>,
    /// `[rows]`
    pub rstd: Vec<f32>,
}

impl LayerNorm {
    pub fn dim(&self) -> usize {
        self.gamma.len()
    }

    /// `x: [rows, dim]` → `y: [rows, dim]`, and the saved state when `save`.
    ///
    /// One parallel pass over the rows writes x̂ (when saved) and y = x̂ γ + β: no serial loop
    /// after the parallel normalisation (with two threads, serial work costs twice its share
    /// of the image pass).
    pub fn forward(&self, x: &[f32], save: bool) -> (Vec<f32>, Option<LnSaved>) {
        let mut y = Vec::new();
        let saved = self.forward_to(x, save, &mut y);
        (y, saved)
    }

    /// `forward` without the saved state, into `y` (its memory reused).
    pub(crate) fn forward_into(&self, x: &[f32], y: &mut Vec<f32>) {
        self.forward_to(x, false, y);
    }

    fn forward_to(&self, x: &[f32], save: bool, y: &mut Vec<f32>) -> Option<LnSaved> {
        let d = self.dim();
        let rows = x.len() / d;
        y.clear();
        y.resize(x.len(), 0.0);
        let mut rstd = vec![0.0; rows];
        let mut xhat = if save { vec![0.0; x.len()] } else { Vec::new() };
        let rows_per_task = (CHUNK / d).max(1);
        let row = |xr: &[f32], yr: &mut [f32], hr: Option<&mut [f32]>, rs: &mut f32| {
            // Two passes in f64: exact enough that a constant row (variance 0) gives y = β.
            let mean = xr.iter().map(|&v| v as f64).sum::<f64>() / d as f64;
            let var = xr.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / d as f64;
            let r = 1.0 / (var + self.eps as f64).sqrt();
            *rs = r as f32;
            for (yv, &xv) in yr.iter_mut().zip(xr) {
                *yv = ((xv as f64 - mean) * r) as f32;
            }
            if let Some(hr) = hr {
                hr.copy_from_slice(yr);
            }
            for ((yv, g), b) in yr.iter_mut().zip(&self.gamma).zip(&self.beta) {
                *yv = *yv * g + b;
            }
        };
        if save {
            y.par_chunks_mut(d)
                .zip(xhat.par_chunks_mut(d))
                .zip(x.par_chunks(d))
                .zip(rstd.par_iter_mut())
                .with_min_len(rows_per_task)
                .for_each(|(((yr, hr), xr), rs)| row(xr, yr, Some(hr), rs));
        } else {
            y.par_chunks_mut(d)
                .zip(x.par_chunks(d))
                .zip(rstd.par_iter_mut())
                .with_min_len(rows_per_task)
                .for_each(|((yr, xr), rs)| row(xr, yr, None, rs));
        }
        save.then_some(LnSaved { xhat, rstd })
    }

    /// `dy: [rows, dim]` → `dx`. With x̂ the normalized input and g = dy·γ:
    /// `dx = rstd · (g − mean(g) − x̂ · mean(g x̂))`.
    pub fn backward(&self, dy: &[f32], s: &LnSaved) -> Vec<f32> {
        let d = self.dim();
        let mut dx = vec![0.0; dy.len()];
        let rows_per_task = (CHUNK / d).max(1);
        dx.par_chunks_mut(d)
            .zip(dy.par_chunks(d))
            .zip(s.xhat.par_chunks(d))
            .zip(s.rstd.par_iter())
            .with_min_len(rows_per_task)
            .for_each(|(((dxr, dyr), xr), &r)| {
                let mut sg = 0.0f64;
                let mut sgx = 0.0f64;
                for ((&g, &gam), &xh) in dyr.iter().zip(&self.gamma).zip(xr) {
                    let gg = (g * gam) as f64;
                    sg += gg;
                    sgx += gg * xh as f64;
                }
                let (mg, mgx) = (sg / d as f64, sgx / d as f64);
                for (((o, &g), &gam), &xh) in dxr.iter_mut().zip(dyr).zip(&self.gamma).zip(xr) {
                    *o = (r as f64 * ((g * gam) as f64 - mg - xh as f64 * mgx)) as f32;
                }
            });
        dx
    }
}

const SQRT_2_OVER_PI: f32 = 0.797_884_6;

/// Elementwise work is split into chunks of this many values across threads: the MLP
/// activation of three ViT-B/32 views is 150 × 3072 values, enough exp/erf calls to matter
/// next to the GEMMs.
const CHUNK: usize = 8192;

/// `x += y`, in parallel chunks (the residual connections).
pub fn add_assign(x: &mut [f32], y: &[f32]) {
    assert_eq!(x.len(), y.len(), "add_assign: lengths");
    x.par_chunks_mut(CHUNK)
        .zip(y.par_chunks(CHUNK))
        .for_each(|(x, y)| x.iter_mut().zip(y).for_each(|(x, y)| *x += y));
}

/// The activation of `pre` into a new vector (`pre` itself is kept for the backward pass:
/// this replaces a serial copy followed by the in-place activation).
pub fn activation_forward_copy(act: Activation, pre: &[f32]) -> Vec<f32> {
    let mut out = vec![0.0; pre.len()];
    out.par_chunks_mut(CHUNK)
        .zip(pre.par_chunks(CHUNK))
        .for_each(|(o, p)| {
            o.copy_from_slice(p);
            act_forward_any(act, o)
        });
    out
}

/// Apply the activation in place.
pub fn activation_forward(act: Activation, x: &mut [f32]) {
    x.par_chunks_mut(CHUNK)
        .for_each(|c| act_forward_any(act, c));
}

/// `dy ← dy · act'(pre)` in place, `pre` being the activation's input.
pub fn activation_backward(act: Activation, pre: &[f32], dy: &mut [f32]) {
    dy.par_chunks_mut(CHUNK)
        .zip(pre.par_chunks(CHUNK))
        .for_each(|(g, p)| act_backward_any(act, p, g));
}

/// The activation of one chunk, in the widest copy this CPU runs (same bits in each).
fn act_forward_any(act: Activation, c: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    if avx2_fma() {
        // SAFETY: the CPU has AVX2 and FMA (checked just above).
        return unsafe { act_forward_avx2(act, c) };
    }
    act_forward_chunk(act, c)
}

/// `g ← g · act'(pre)` for one chunk, in the widest copy this CPU runs (same bits in each).
fn act_backward_any(act: Activation, pre: &[f32], g: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    if avx2_fma() {
        // SAFETY: the CPU has AVX2 and FMA (checked just above).
        return unsafe { act_backward_avx2(act, pre, g) };
    }
    act_backward_chunk(act, pre, g)
}

// The activation loops are compiled twice: for the baseline target (SSE2, 4 lanes) and with
// AVX2 (8 lanes), chosen at run time; both do the same operations per element (no FMA
// contraction in Rust), so results are identical. The AVX2 copy runs these loops in half the
// time of the baseline one.
#[inline(always)]
fn act_forward_chunk(act: Activation, c: &mut [f32]) {
    // Plain indexed loops: iterator adapters (zip's fold) were not inlined into the AVX2 copy.
    for v in c.iter_mut() {
        *v = act_value(act, *v);
    }
}

#[inline(always)]
fn act_backward_chunk(act: Activation, pre: &[f32], g: &mut [f32]) {
    let n = g.len().min(pre.len());
    let (g, pre) = (&mut g[..n], &pre[..n]);
    for i in 0..n {
        g[i] *= act_slope(act, pre[i]);
    }
}

#[cfg(target_arch = "x86_64")]
fn avx2_fma() -> bool {
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn act_forward_avx2(act: Activation, c: &mut [f32]) {
    act_forward_chunk(act, c)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn act_backward_avx2(act: Activation, pre: &[f32], g: &mut [f32]) {
    act_backward_chunk(act, pre, g)
}

#[inline(always)]
fn act_value(act: Activation, x: f32) -> f32 {
    match act {
        Activation::QuickGelu => x * sigmoid(1.702 * x),
        Activation::Gelu => 0.5 * x * (1.0 + libm::erff(x * std::f32::consts::FRAC_1_SQRT_2)),
        Activation::GeluTanh => {
            let u = SQRT_2_OVER_PI * (x + 0.044715 * x * x * x);
            0.5 * x * (1.0 + u.tanh())
        }
    }
}

#[inline(always)]
fn act_slope(act: Activation, x: f32) -> f32 {
    match act {
        Activation::QuickGelu => {
            let s = sigmoid(1.702 * x);
            s + 1.702 * x * s * (1.0 - s)
        }
        Activation::Gelu => {
            // d/dx [x Φ(x)] = Φ(x) + x φ(x)
            let cdf = 0.5 * (1.0 + libm::erff(x * std::f32::consts::FRAC_1_SQRT_2));
            cdf + x * 0.398_942_3 * fast_exp(-0.5 * x * x)
        }
        Activation::GeluTanh => {
            let u = SQRT_2_OVER_PI * (x + 0.044715 * x * x * x);
            let t = u.tanh();
            let du = SQRT_2_OVER_PI * (1.0 + 3.0 * 0.044715 * x * x);
            0.5 * (1.0 + t) + 0.5 * x * (1.0 - t * t) * du
        }
    }
}

/// Logistic function, finite for any input, written without branches so the activation
/// loops vectorise.
#[inline(always)]
fn sigmoid(z: f32) -> f32 {
    1.0 / (1.0 + fast_exp(-z))
}

pub use t2tf_core::math::fast_exp;

#[cfg(test)]
mod tests {
    use super::*;

    /// Central differences in f64 of a scalar function of an f32 vector.
    /// Steps of 1e-2 on O(1) inputs: the f32 rounding of the loss (~1e-7 relative) divided by
    /// the step gives ~1e-5 noise, the truncation error O(h²) ~1e-4 for these smooth
    /// functions, hence the 2e-3 relative tolerance below.
    fn fd(f: &dyn Fn(&[f32]) -> f64, x: &[f32], i: usize) -> f64 {
        let h = 1e-2f32;
        let (mut xp, mut xm) = (x.to_vec(), x.to_vec());
        xp[i] += h;
        xm[i] -= h;
        (f(&xp) - f(&xm)) / (2.0 * h as f64)
    }

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol * (1.0 + b.abs())
    }

    #[test]
    fn activations_match_definitions_and_finite_differences() {
        let xs: Vec<f32> = (-40..=40).map(|i| i as f32 * 0.1).collect();
        for act in [
            Activation::QuickGelu,
            Activation::Gelu,
            Activation::GeluTanh,
        ] {
            let mut y = xs.clone();
            activation_forward(act, &mut y);
            for (&x, &v) in xs.iter().zip(&y) {
                let x64 = x as f64;
                let want = match act {
                    Activation::QuickGelu => x64 / (1.0 + (-1.702 * x64).exp()),
                    Activation::Gelu => 0.5 * x64 * (1.0 + libm::erf(x64 / 2f64.sqrt())),
                    Activation::GeluTanh => {
                        0.5 * x64
                            * (1.0
                                + ((2.0 / std::f64::consts::PI).sqrt()
                                    * (x64 + 0.044715 * x64.powi(3)))
                                .tanh())
                    }
                };
                assert!(close(v as f64, want, 1e-6), "{act:?} at {x}: {v} vs {want}");
            }
            let mut g = vec![1.0; xs.len()];
            activation_backward(act, &xs, &mut g);
            for i in 0..xs.len() {
                let f = |x: &[f32]| {
                    let mut y = x.to_vec();
                    activation_forward(act, &mut y);
                    y[i] as f64
                };
                assert!(
                    close(g[i] as f64, fd(&f, &xs, i), 2e-3),
                    "{act:?} grad at {}",
                    xs[i]
                );
            }
        }
        // Huge inputs stay finite.
        let mut big = vec![1e30f32, -1e30, 88.0, -88.0];
        let pre = big.clone();
        activation_forward(Activation::QuickGelu, &mut big);
        let mut g = vec![1.0; 4];
        activation_backward(Activation::QuickGelu, &pre, &mut g);
        assert!(big.iter().chain(&g).all(|v| v.is_finite()));
    }

    /// The run-time-dispatched (AVX2 where available) activation loops give the same bits as
    /// the baseline copies, including the scalar remainder of a length that is not a multiple
    /// of 8.
    #[test]
    fn activation_copies_agree_bit_for_bit() {
        let xs: Vec<f32> = (0..20_003)
            .map(|i| (i as f32 - 10_000.0) * 1.3e-3)
            .collect();
        for act in [
            Activation::QuickGelu,
            Activation::Gelu,
            Activation::GeluTanh,
        ] {
            let (mut fast, mut base) = (xs.clone(), xs.clone());
            activation_forward(act, &mut fast);
            act_forward_chunk(act, &mut base);
            assert!(fast
                .iter()
                .zip(&base)
                .all(|(a, b)| a.to_bits() == b.to_bits()));
            let (mut gf, mut gb) = (vec![0.7f32; xs.len()], vec![0.7f32; xs.len()]);
            activation_backward(act, &xs, &mut gf);
            act_backward_chunk(act, &xs, &mut gb);
            assert!(gf.iter().zip(&gb).all(|(a, b)| a.to_bits() == b.to_bits()));
        }
    }

    #[test]
    fn layer_norm_backward_matches_finite_differences() {
        let d = 6;
        let ln = LayerNorm {
            gamma: (0..d).map(|i| 0.5 + i as f32 * 0.3).collect(),
            beta: (0..d).map(|i| i as f32 * 0.1 - 0.2).collect(),
            eps: 1e-5,
        };
        let x: Vec<f32> = (0..2 * d)
            .map(|i| ((i * 7 % 11) as f32 - 5.0) * 0.4)
            .collect();
        let w: Vec<f32> = (0..2 * d)
            .map(|i| ((i * 5 % 13) as f32 - 6.0) * 0.2)
            .collect();
        let loss = |x: &[f32]| -> f64 {
            let (y, _) = ln.forward(x, false);
            y.iter().zip(&w).map(|(a, b)| (a * b) as f64).sum()
        };
        let (_, s) = ln.forward(&x, true);
        let dx = ln.backward(&w, &s.unwrap());
        for (i, &g) in dx.iter().enumerate() {
            assert!(close(g as f64, fd(&loss, &x, i), 2e-3), "dx[{i}]");
        }
        // A constant row normalizes to β with a finite gradient.
        let (y, s) = ln.forward(&[3.0; 6], true);
        assert!(y.iter().zip(&ln.beta).all(|(a, b)| (a - b).abs() < 1e-6));
        assert!(ln
            .backward(&[1.0; 6], &s.unwrap())
            .iter()
            .all(|v| v.is_finite()));
    }

    /// The activation fused into the product (`forward_act`, `backward_act`) gives the same
    /// bits as the product followed by the separate activation pass, for every kernel this
    /// CPU runs and the crate, with shapes that leave partial tiles.
    #[test]
    fn fused_activation_equals_separate_passes() {
        let (rows, inp, out) = (157, 70, 301);
        let val = |i: usize, s: usize| ((((i + s) * 2654435761usize) % 2001) as f32 / 500.0) - 2.0;
        let w: Vec<f32> = (0..inp * out).map(|i| val(i, 1) * 0.1).collect();
        let b: Vec<f32> = (0..out).map(|i| val(i, 2)).collect();
        let x: Vec<f32> = (0..rows * inp).map(|i| val(i, 3)).collect();
        let dy: Vec<f32> = (0..rows * out).map(|i| val(i, 4)).collect();
        let crate_engine = Compute::default().with_engine(Engine::Crate);
        let mut builds: Vec<Box<dyn Fn() -> Linear>> = vec![Box::new(|| {
            Linear::new(w.clone(), Some(b.clone()), inp, out, &crate_engine)
        })];
        for k in Kernel::ALL.into_iter().filter(|k| k.available()) {
            let (w, b) = (w.clone(), b.clone());
            let c = Compute::default().with_kernel(k).unwrap();
            builds.push(Box::new(move || {
                Linear::new(w.clone(), Some(b.clone()), inp, out, &c)
            }));
        }
        let same = |a: &[f32], b: &[f32]| a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits());
        for build in &builds {
            // `up`: in → out with the activation after it; `down`: out → in, so that its
            // backward lands on `up`'s activation input.
            let up = build();
            let what = format!("{:?}", up.kernel());
            for act in [
                Activation::QuickGelu,
                Activation::Gelu,
                Activation::GeluTanh,
            ] {
                let pre = up.forward(&x, rows);
                let mut post = pre.clone();
                activation_forward(act, &mut post);
                let (fused, kept) = up.forward_act(&x, rows, act, true);
                assert!(same(&fused, &post), "{what} {act:?} forward");
                assert!(same(kept.as_ref().unwrap(), &pre), "{what} {act:?} pre");
                let (fused, none) = up.forward_act(&x, rows, act, false);
                assert!(
                    same(&fused, &post) && none.is_none(),
                    "{what} {act:?} forward"
                );
                // Backward through `up` viewed as the layer after an activation of width out.
                let g_pre: Vec<f32> = (0..rows * inp).map(|i| val(i, 5)).collect();
                let mut want = up.backward(&dy, rows);
                activation_backward(act, &g_pre, &mut want);
                let got = up.backward_act(&dy, rows, act, &g_pre);
                assert!(same(&got, &want), "{what} {act:?} backward");
            }
        }
    }

    #[test]
    fn linear_forward_and_backward() {
        for engine in [Engine::Packed, Engine::Crate] {
            linear_small_cases(engine);
        }
    }

    fn linear_small_cases(engine: Engine) {
        let c = Compute::default().with_engine(engine);
        // [2 out, 3 in]: narrowing (the `gemm` path stores it transposed).
        let l = Linear::new(
            vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
            Some(vec![0.5, -0.5]),
            3,
            2,
            &c,
        );
        assert_eq!(l.engine(), engine);
        let y = l.forward(&[1.0, 0.0, -1.0, 2.0, 1.0, 0.0], 2);
        assert_eq!(y, vec![-1.5, -2.5, 4.5, 12.5]);
        let dx = l.backward(&[1.0, 0.0, 0.0, 2.0], 2);
        assert_eq!(dx, vec![1.0, 2.0, 3.0, 8.0, 10.0, 12.0]);
        // [3 out, 2 in] = the transpose of the above: widening, stored as is.
        let l = Linear::new(vec![1.0, 4.0, 2.0, 5.0, 3.0, 6.0], None, 2, 3, &c);
        assert_eq!(l.forward(&[1.0, 2.0], 1), vec![9.0, 12.0, 15.0]);
        assert_eq!(l.backward(&[1.0, 0.0, -1.0], 1), vec![-2.0, -2.0]);
        // Parts agree with the whole, in both storage layouts.
        for l in [
            Linear::new(
                (0..12).map(|v| v as f32 - 5.0).collect(),
                Some(vec![0.1; 4]),
                3,
                4,
                &c,
            ),
            Linear::new(
                (0..12).map(|v| v as f32 - 5.0).collect(),
                Some(vec![0.1; 3]),
                4,
                3,
                &c,
            ),
        ] {
            let x: Vec<f32> = (0..2 * l.in_dim).map(|v| v as f32 * 0.5).collect();
            let full = l.forward(&x, 2);
            let part = l.forward_part(&x, 2, 1..3);
            for r in 0..2 {
                assert_eq!(
                    &part[r * 2..r * 2 + 2],
                    &full[r * l.out_dim + 1..r * l.out_dim + 3]
                );
            }
            let dy_part = [1.0, -1.0, 0.5, 2.0];
            let mut dy = vec![0.0; 2 * l.out_dim];
            for r in 0..2 {
                dy[r * l.out_dim + 1..r * l.out_dim + 3]
                    .copy_from_slice(&dy_part[r * 2..r * 2 + 2]);
            }
            assert_eq!(l.backward_part(&dy_part, 2, 1..3), l.backward(&dy, 2));
        }
    }

    /// The into-buffer forwards the caption pool uses give the allocating forwards' bits,
    /// whatever the buffer held before (longer, shorter, NaN-filled) and on both engines.
    #[test]
    fn forwards_into_a_reused_buffer_give_the_same_bits() {
        let val = |i: usize, s: usize| ((((i + s) * 2654435761usize) % 2001) as f32 / 1000.0) - 1.0;
        for engine in [Engine::Packed, Engine::Crate] {
            let c = Compute::default().with_engine(engine);
            let (inp, out) = (37, 70);
            let w: Vec<f32> = (0..inp * out).map(|i| val(i, 1)).collect();
            let b: Vec<f32> = (0..out).map(|i| val(i, 2)).collect();
            let l = Linear::new(w, Some(b), inp, out, &c);
            let ln = LayerNorm {
                gamma: (0..inp).map(|i| val(i, 5)).collect(),
                beta: (0..inp).map(|i| val(i, 6)).collect(),
                eps: 1e-5,
            };
            let (mut y, mut a, mut n) = (Vec::new(), Vec::new(), Vec::new());
            for rows in [9, 3, 17, 1] {
                let x: Vec<f32> = (0..rows * inp).map(|i| val(i, rows)).collect();
                for buf in [&mut y, &mut a, &mut n] {
                    buf.iter_mut().for_each(|v| *v = f32::NAN);
                }
                l.forward_into(&x, rows, None, &mut y);
                assert_eq!(
                    bits(&y),
                    bits(&l.forward(&x, rows)),
                    "{engine:?} {rows} rows"
                );
                l.forward_into(&x, rows, Some(Activation::QuickGelu), &mut a);
                let (want, _) = l.forward_act(&x, rows, Activation::QuickGelu, false);
                assert_eq!(bits(&a), bits(&want), "{engine:?} act {rows} rows");
                ln.forward_into(&x, &mut n);
                assert_eq!(
                    bits(&n),
                    bits(&ln.forward(&x, false).0),
                    "layer norm {rows} rows"
                );
            }
        }
    }

    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// Both engines against f64 on shapes that are not multiples of the tiles, including the
    /// parts of a stacked projection at unaligned offsets. Tolerance: an f32 dot product of
    /// length k has error ~√k · 6e-8 relative to Σ|x||w| for these O(1) values.
    #[test]
    fn linear_engines_match_f64_on_odd_shapes() {
        // The same data generator and odd-shape table as attention/mm.rs's test: each checks
        // its own product against f64 on them.
        let val = |i: usize, s: usize| ((((i + s) * 2654435761usize) % 2001) as f32 / 1000.0) - 1.0;
        for engine in [Engine::Packed, Engine::Crate] {
            for &(rows, inp, out) in &[
                (1, 1, 1),
                (5, 7, 3),
                (17, 770, 5),
                (151, 37, 150),
                (3, 48, 150),
            ] {
                let w: Vec<f32> = (0..inp * out).map(|i| val(i, 1)).collect();
                let b: Vec<f32> = (0..out).map(|i| val(i, 2)).collect();
                let c = Compute::default().with_engine(engine);
                let l = Linear::new(w.clone(), Some(b.clone()), inp, out, &c);
                let x: Vec<f32> = (0..rows * inp).map(|i| val(i, 3)).collect();
                let dy: Vec<f32> = (0..rows * out).map(|i| val(i, 4)).collect();
                let tol = 1e-6 * ((inp.max(out)) as f64).sqrt() * 4.0;
                let outs = out / 3..out;
                let y = l.forward_part(&x, rows, outs.clone());
                let dx = l.backward_part(&dy[..rows * outs.len()], rows, outs.clone());
                for r in 0..rows {
                    for (jj, o) in outs.clone().enumerate() {
                        let want = b[o] as f64
                            + (0..inp)
                                .map(|i| x[r * inp + i] as f64 * w[o * inp + i] as f64)
                                .sum::<f64>();
                        let got = y[r * outs.len() + jj] as f64;
                        assert!(
                            (got - want).abs() <= tol * (1.0 + want.abs()),
                            "{engine:?} fwd {rows}x{inp}x{out}"
                        );
                    }
                    for i in 0..inp {
                        let want: f64 = outs
                            .clone()
                            .enumerate()
                            .map(|(jj, o)| dy[r * outs.len() + jj] as f64 * w[o * inp + i] as f64)
                            .sum();
                        let got = dx[r * inp + i] as f64;
                        assert!(
                            (got - want).abs() <= tol * (1.0 + want.abs()),
                            "{engine:?} bwd {rows}x{inp}x{out}"
                        );
                    }
                }
            }
        }
    }
}
