//! What only the benchmarks in `examples/` use from outside the library (feature `bench`).
//!
//! Without the feature these items stay `pub(crate)` (or live in a `pub(crate)` module), so
//! the public API is what the binary, the tests and the non-benchmark examples need, and
//! nothing is exported only to be timed. Items of a crate-private module are re-exported
//! here as they are; methods and crate-private functions get a one-line wrapper, since Rust
//! cannot re-export them.
//!
//! `cargo run --release --features bench --example bench_clip` (and the other `bench_*`).

use std::path::Path;

use crate::clip::packed::{Kernel, Precision};
use crate::image::Image;
use crate::optimize::captions::CacheOutcome;
use crate::tf::LutGrad;

/// The `gemm`-crate products the CLIP layers run where no packed kernel applies
/// (`bench_clip` times them against the packed kernels).
pub use crate::clip::matmul::{matmul, Mat, Op};

/// The packed kernel CLIP runs at `precision` on this CPU (`Kernel::best`): `bench_clip`
/// marks it in its table. `None` where no kernel of that precision runs here.
pub fn best_kernel(precision: Precision) -> Option<Kernel> {
    Kernel::best(precision)
}

/// `t2tf optimize`'s on-disk cache of the caption pool's embeddings
/// (`optimize::captions::cached_embeddings`): `bench_optimize` reports a hit or a miss.
pub fn cached_embeddings<E>(
    dir: Option<&Path>,
    model_hash: &[u8],
    captions: &[String],
    compute: impl FnOnce(&[String]) -> Result<Vec<Vec<f32>>, E>,
) -> Result<(Vec<Vec<f32>>, CacheOutcome), E> {
    crate::optimize::captions::cached_embeddings(dir, model_hash, captions, compute)
}

/// Views in the near-square grid of `preview.png` (`optimize::driver::tile`):
/// `bench_optimize --out` writes its held-out views so.
pub fn tile(images: &[Image]) -> Image {
    crate::optimize::driver::tile(images)
}

/// `n` views no run trains on, for comparing TFs: yaws between those of the preview orbit,
/// slightly raised (pitch 0.1), at mid distance, on white (`bench_optimize`, `bench_refine`).
pub fn held_out_views(
    settings: &crate::optimize::Settings,
    n: usize,
) -> Vec<crate::optimize::View> {
    (0..n)
        .map(|i| crate::optimize::View {
            yaw: std::f64::consts::TAU * (i as f64 + 0.37) / n as f64,
            pitch: 0.1,
            distance: 0.5 * (settings.distance[0] + settings.distance[1]),
            background: crate::optimize::Background::Gray { level: 1.0 },
            seed: 0,
            time: 0,
        })
        .collect()
}

/// `into += other`, entry by entry (`LutGrad::add`): `bench_render` sums per-view gradients
/// as the optimizer does.
pub fn add_grad(into: &mut LutGrad, other: &LutGrad) {
    into.add(other)
}
