//! Writes a model folder of ViT-B/32's shapes with random weights (`model.safetensors`, 605 MB,
//! the real `config.json` and `tokenizer.json` of ../shared) for measuring what `t2tf optimize`
//! costs in memory with a model of that size, e.g. under `/usr/bin/time -v`:
//!
//!     cargo run --release --features bench --example bench_memory -- DIR
//!     /usr/bin/time -v target/release/t2tf optimize VOLUME --model DIR --prompt "..." --out OUT
//!
//! With `--volume DIR` it writes a 1 GiB uint8 volume there (the aneurism upsampled to 1024³)
//! for the large-volume path (the preview's level). With `--backward [REPS]` instead of a folder it times what holding one copy of a weight
//! costs: the input backward `dX = dY · W` of ViT-B/32's layers (150 rows: 3 views × 50
//! tokens) from the forward's packed `Wᵀ` read transposed (`packed::gemm_t`, what a layer
//! does) against a second packed copy `W` (`packed::gemm`), for the best f32 kernel, the two
//! taking turns so that a load on the machine meets both alike.

use std::path::{Path, PathBuf};

#[path = "common/random_model.rs"]
mod random_model;
use random_model::write_model;

/// Best and median seconds of `reps` runs of each of two products, taking turns.
fn turns(reps: usize, mut x: impl FnMut(), mut y: impl FnMut()) -> [(f64, f64); 2] {
    let mut t = [Vec::new(), Vec::new()];
    x();
    y();
    for _ in 0..reps {
        let s = std::time::Instant::now();
        x();
        t[0].push(s.elapsed().as_secs_f64());
        let s = std::time::Instant::now();
        y();
        t[1].push(s.elapsed().as_secs_f64());
    }
    t.map(|mut v| {
        v.sort_by(f64::total_cmp);
        (v[0], v[v.len() / 2])
    })
}

fn backward(reps: usize) -> anyhow::Result<()> {
    use t2tf::clip::packed::{self, Kernel, PackedB, Precision};
    let kernel = Kernel::best(Precision::F32).ok_or_else(|| anyhow::anyhow!("no f32 kernel"))?;
    println!(
        "kernel {}, {} threads, {reps} reps each, taking turns; {}",
        kernel.name(),
        rayon::current_num_threads(),
        packed::cpu_features()
    );
    println!("| layer (in → out) | dY·W, two copies: best / median ms | dY·W from Wᵀ's panels: best / median ms | ratio of medians |");
    println!("|---|---|---|---|");
    let m = 150;
    let (mut total_two, mut total_one) = (0.0, 0.0);
    for (what, inp, out, count) in [
        ("qkv (768 → 2304)", 768, 2304, 12),
        ("out-proj (768 → 768)", 768, 768, 12),
        ("fc1 (768 → 3072)", 768, 3072, 12),
        ("fc2 (3072 → 768)", 3072, 768, 12),
    ] {
        // W: [out, in] as in a checkpoint.
        let w: Vec<f32> = (0..out * inp)
            .map(|i| ((i * 7919) % 997) as f32 / 997.0 - 0.5)
            .collect();
        let dy: Vec<f32> = (0..m * out)
            .map(|i| ((i * 104729) % 991) as f32 / 991.0 - 0.5)
            .collect();
        let fwd = PackedB::from_cols_for(kernel, &w, inp, out);
        let bwd = PackedB::from_rows_for(kernel, &w, out, inp);
        let mut dx = vec![0.0; m * inp];
        let [two, one] = turns(
            reps,
            || packed::gemm(&mut dx, inp, &dy, out, m, &bwd, 0..out, 0..inp, None, false),
            || {
                drop(std::hint::black_box(packed::gemm_t(
                    &dy,
                    out,
                    m,
                    &fwd,
                    0..out,
                )))
            },
        );
        total_two += two.1 * count as f64;
        total_one += one.1 * count as f64;
        println!(
            "| {what} | {:.3} / {:.3} | {:.3} / {:.3} | {:.3} |",
            two.0 * 1e3,
            two.1 * 1e3,
            one.0 * 1e3,
            one.1 * 1e3,
            one.1 / two.1
        );
    }
    println!(
        "| 12 layers of each (medians) | {:.1} | {:.1} | {:.3} |",
        total_two * 1e3,
        total_one * 1e3,
        total_one / total_two
    );
    Ok(())
}

/// A 1 GiB uint8 volume for measuring the large-volume path: the 256³ aneurism of ../shared
/// upsampled 4× trilinearly to 1024³ (`aneurism4x_1024x1024x1024_uint8.raw` in `dir`).
fn large_volume(dir: &Path, shared: &Path) -> anyhow::Result<PathBuf> {
    use rayon::prelude::*;
    let src = std::fs::read(shared.join("data/volumes/aneurism_256x256x256_uint8.raw"))?;
    let (n, f) = (256usize, 4usize);
    let out_n = n * f;
    let at = |x: usize, y: usize, z: usize| src[(z * n + y) * n + x] as f32;
    // Source coordinate and weight of output index i (cell-centred ×4, clamped at the ends).
    let coord = |i: usize| {
        let c = ((i as f32 + 0.5) / f as f32 - 0.5).clamp(0.0, (n - 1) as f32);
        let i0 = (c.floor() as usize).min(n - 2);
        (i0, c - i0 as f32)
    };
    let path = dir.join(format!("aneurism4x_{out_n}x{out_n}x{out_n}_uint8.raw"));
    let mut file = std::io::BufWriter::new(std::fs::File::create(&path)?);
    for z in 0..out_n {
        let (z0, wz) = coord(z);
        let mut slice = vec![0u8; out_n * out_n];
        slice
            .par_chunks_mut(out_n)
            .enumerate()
            .for_each(|(y, row)| {
                let (y0, wy) = coord(y);
                for (x, v) in row.iter_mut().enumerate() {
                    let (x0, wx) = coord(x);
                    let mut s = 0.0;
                    for (dz, cz) in [(0, 1.0 - wz), (1, wz)] {
                        for (dy, cy) in [(0, 1.0 - wy), (1, wy)] {
                            for (dx, cx) in [(0, 1.0 - wx), (1, wx)] {
                                s += cz * cy * cx * at(x0 + dx, y0 + dy, z0 + dz);
                            }
                        }
                    }
                    *v = s.round().clamp(0.0, 255.0) as u8;
                }
            });
        std::io::Write::write_all(&mut file, &slice)?;
    }
    std::io::Write::flush(&mut file)?;
    Ok(path)
}

fn main() -> anyhow::Result<()> {
    if std::env::args().nth(1).as_deref() == Some("--volume") {
        let dir = PathBuf::from(
            std::env::args()
                .nth(2)
                .ok_or_else(|| anyhow::anyhow!("usage: bench_memory --volume DIR"))?,
        );
        std::fs::create_dir_all(&dir)?;
        let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared");
        println!("wrote {}", large_volume(&dir, &shared)?.display());
        return Ok(());
    }
    if std::env::args().nth(1).as_deref() == Some("--backward") {
        let reps = std::env::args()
            .nth(2)
            .map(|s| s.parse())
            .transpose()?
            .unwrap_or(20);
        return backward(reps);
    }
    let dir = PathBuf::from(
        std::env::args()
            .nth(1)
            .ok_or_else(|| anyhow::anyhow!("usage: bench_memory DIR"))?,
    );
    std::fs::create_dir_all(&dir)?;
    let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared");
    write_model(&dir, &shared)?;
    println!("wrote {}", dir.display());
    Ok(())
}
