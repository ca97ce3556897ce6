//! Every micro-kernel of `clip::packed` this CPU can run, against a scalar f64 reference of the
//! values it multiplies (odd shapes, sub-ranges, accumulate, bias), against each other, through
//! whole models (the transformers golden fixtures), and across thread counts. Kernels the CPU
//! lacks are skipped and listed (run with `--nocapture` to see the list), unless
//! `T2TF_REQUIRE_KERNELS` names them (comma-separated: avx2, avx512f, avx512bf16, amx): then a
//! missing one fails. CI sets it to what its CPU's flags promise.

use std::path::Path;

use t2tf::clip::packed::{self, Kernel, PackedB, Precision};
use t2tf::clip::{cosine_grad, Clip, ClipConfig, Compute, ModelRequest, RandomSource};
use t2tf::image::Image;

// The golden-file format and parity measure are clip_golden's.
use crate::clip_golden::{rel_err, to_image, Golden, TOKENIZER};

/// The short name `T2TF_REQUIRE_KERNELS` uses for a SIMD kernel.
fn short(k: Kernel) -> Option<&'static str> {
    match k {
        Kernel::Avx2Fma => Some("avx2"),
        Kernel::Avx512F => Some("avx512f"),
        Kernel::Avx512Bf16 => Some("avx512bf16"),
        Kernel::Amx => Some("amx"),
        Kernel::Portable | Kernel::PortableBf16 | Kernel::AmxEmulated => None,
    }
}

/// The kernels to test here, printing the others with the reason; a missing kernel that
/// `T2TF_REQUIRE_KERNELS` names fails the test.
fn available(test: &str) -> Vec<Kernel> {
    let required = std::env::var("T2TF_REQUIRE_KERNELS").unwrap_or_default();
    let required: Vec<&str> = required
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .collect();
    for r in &required {
        assert!(
            Kernel::ALL.into_iter().any(|k| short(k) == Some(r)),
            "T2TF_REQUIRE_KERNELS: unknown kernel {r:?} (avx2, avx512f, avx512bf16, amx)"
        );
    }
    let mut run = Vec::new();
    for k in Kernel::ALL {
        match k.missing() {
            None => run.push(k),
            Some(what) => {
                assert!(
                    !short(k).is_some_and(|s| required.contains(&s)),
                    "{test}: T2TF_REQUIRE_KERNELS requires {}, but this CPU lacks {what}",
                    k.name()
                );
                eprintln!("{test}: skipped {}: this CPU lacks {what}", k.name())
            }
        }
    }
    eprintln!(
        "{test}: running {} ({})",
        run.iter().map(|k| k.name()).collect::<Vec<_>>().join(", "),
        packed::cpu_features()
    );
    run
}

/// Deterministic values in [-scale, scale].
fn values(len: usize, seed: usize, scale: f32) -> Vec<f32> {
    (0..len)
        .map(|i| ((((i + seed) * 2654435761usize) % 2001) as f32 / 1000.0 - 1.0) * scale)
        .collect()
}

/// What `kernel` multiplies: the values themselves, or rounded to bf16.
fn seen(kernel: Kernel, v: &[f32]) -> Vec<f32> {
    match kernel.precision() {
        Precision::F32 => v.to_vec(),
        Precision::Bf16 => v.iter().map(|&x| packed::round_bf16(x)).collect(),
    }
}

/// The scalar reference: `C[i][j] = base + bias[cols.start + j] + Σ_p A[i][p] · B[ks.start + p][cols.start + j]`
/// in f64, A `[m][lda]`, B row-major `[k_total][n_total]`.
#[allow(clippy::too_many_arguments)]
fn reference(
    base: Option<(&[f32], usize)>,
    a: &[f32],
    lda: usize,
    m: usize,
    b: &[f32],
    n_total: usize,
    ks: std::ops::Range<usize>,
    cols: std::ops::Range<usize>,
    bias: Option<&[f32]>,
) -> Vec<f64> {
    let mut c = Vec::with_capacity(m * cols.len());
    for i in 0..m {
        for (jj, j) in cols.clone().enumerate() {
            let mut s = base.map_or(0.0, |(c, ldc)| c[i * ldc + jj] as f64);
            s += bias.map_or(0.0, |b| b[j] as f64);
            for (p, kk) in ks.clone().enumerate() {
                s += a[i * lda + p] as f64 * b[kk * n_total + j] as f64;
            }
            c.push(s);
        }
    }
    c
}

/// f32 kernels: each sum of k products of O(1) values carries ≲ √k · 2⁻²⁴ relative rounding
/// (random-walk growth, with a safety factor of 4), measured against Σ|a||b| ~ k; bf16 kernels
/// multiply exactly the rounded values and add in f32, so the same bound holds against the
/// reference of the rounded inputs.
fn tolerance(k: usize) -> f64 {
    4.0 * 6e-8 * (k.max(1) as f64).sqrt() * k.max(1) as f64
}

#[test]
fn every_kernel_matches_the_scalar_reference_on_odd_shapes() {
    // m, n, k: not multiples of 6, 16, 64 or the k blocks (256 rows / 128 pairs), and the
    // exact ViT shapes (150 rows, 768 columns) too.
    let shapes = [
        (1, 1, 1),
        (5, 7, 3),
        (7, 17, 1),
        (13, 65, 2),
        (6, 64, 256),
        (17, 33, 257),
        (11, 130, 515),
        (150, 151, 770),
        (151, 150, 513),
        (150, 768, 300),
        (3, 200, 1030),
    ];
    for kernel in available("odd shapes") {
        for &(m, n, k) in &shapes {
            let a = values(m * k, 1, 1.0);
            let b = values(k * n, 2, 1.0);
            let bias = values(n, 3, 1.0);
            let packed = PackedB::from_rows_for(kernel, &b, k, n);
            assert_eq!(packed.kernel(), kernel);
            let (ar, br) = (seen(kernel, &a), seen(kernel, &b));
            let tol = tolerance(k);
            for (accumulate, with_bias) in [(false, false), (false, true), (true, true)] {
                let base = values(m * n, 4, 2.0);
                let mut c = if accumulate {
                    base.clone()
                } else {
                    vec![f32::NAN; m * n]
                };
                let bias = with_bias.then_some(&bias[..]);
                packed::gemm(&mut c, n, &a, k, m, &packed, 0..k, 0..n, bias, accumulate);
                let want = reference(
                    accumulate.then_some((&base[..], n)),
                    &ar,
                    k,
                    m,
                    &br,
                    n,
                    0..k,
                    0..n,
                    bias,
                );
                for (idx, (&g, &w)) in c.iter().zip(&want).enumerate() {
                    assert!(
                        (g as f64 - w).abs() <= tol,
                        "{} {m}x{n}x{k} acc={accumulate} bias={with_bias}: element {idx}: {g} vs {w}",
                        kernel.name()
                    );
                }
            }
        }
    }
}

/// Parts of a packed matrix, as `Linear::forward_part` / `backward_part` use them: row ranges
/// starting and ending at odd rows (bf16: inside a k pair), column ranges not aligned to a
/// panel, strided A and C (C's padding untouched).
#[test]
fn every_kernel_matches_the_reference_on_sub_ranges() {
    let (m, kt, nt) = (14, 301, 203);
    let b = values(kt * nt, 5, 1.0);
    let bias = values(nt, 6, 1.0);
    for kernel in available("sub-ranges") {
        let packed = PackedB::from_cols_for(
            kernel,
            &{
                // The same B given transposed (`[n][k]`, the checkpoint layout).
                let mut bt = vec![0.0; kt * nt];
                for p in 0..kt {
                    for j in 0..nt {
                        bt[j * kt + p] = b[p * nt + j];
                    }
                }
                bt
            },
            kt,
            nt,
        );
        let br = seen(kernel, &b);
        for (ks, cols) in [
            (0..kt, 0..nt),
            (3..300, 5..200),
            (1..2, 64..128),
            (64..129, 63..65),
            (299..301, 202..203),
            (100..101, 0..1),
        ] {
            let (kk, nn) = (ks.len(), cols.len());
            let (lda, ldc) = (kk + 3, nn + 2);
            let a = values(m * lda, 7, 1.0);
            let ar = seen(kernel, &a);
            let mut c = values(m * ldc, 8, 1.0);
            let before = c.clone();
            packed::gemm(
                &mut c,
                ldc,
                &a,
                lda,
                m,
                &packed,
                ks.clone(),
                cols.clone(),
                Some(&bias),
                true,
            );
            let want = reference(
                Some((&before, ldc)),
                &ar,
                lda,
                m,
                &br,
                nt,
                ks.clone(),
                cols.clone(),
                Some(&bias),
            );
            for i in 0..m {
                for j in 0..ldc {
                    let got = c[i * ldc + j];
                    if j >= nn {
                        assert_eq!(got.to_bits(), before[i * ldc + j].to_bits(), "padding");
                        continue;
                    }
                    let w = want[i * nn + j];
                    assert!(
                        (got as f64 - w).abs() <= tolerance(kk),
                        "{} {ks:?} {cols:?} ({i}, {j}): {got} vs {w}",
                        kernel.name()
                    );
                }
            }
        }
    }
}

/// SIMD kernels against the scalar kernel of their layout on the same packed data: f32 kernels
/// differ from `Portable` only by fused vs separate rounding order inside each k block; the
/// bf16 kernel and `PortableBf16` multiply the same bf16 values.
#[test]
fn simd_kernels_agree_with_the_scalar_kernels() {
    let (m, n, k) = (23, 140, 700);
    let a = values(m * k, 11, 1.0);
    let b = values(k * n, 12, 1.0);
    let run = |kernel: Kernel| {
        let packed = PackedB::from_rows_for(kernel, &b, k, n);
        let mut c = vec![0.0; m * n];
        packed::gemm(&mut c, n, &a, k, m, &packed, 0..k, 0..n, None, false);
        c
    };
    let kernels = available("simd vs scalar");
    for kernel in &kernels {
        let scalar = match kernel.precision() {
            Precision::F32 => Kernel::Portable,
            Precision::Bf16 => Kernel::PortableBf16,
        };
        let (got, want) = (run(*kernel), run(scalar));
        let worst = got
            .iter()
            .zip(&want)
            .map(|(g, w)| (g - w).abs() as f64)
            .fold(0.0, f64::max);
        eprintln!(
            "{} vs {}: max |diff| {worst:.1e}",
            kernel.name(),
            scalar.name()
        );
        assert!(worst <= tolerance(k), "{}: {worst}", kernel.name());
    }
    // The AVX2 and AVX-512 f32 kernels run the same fused multiply-adds in the same order:
    // identical bits, so the engine choice does not change an f32 result.
    if kernels.contains(&Kernel::Avx2Fma) && kernels.contains(&Kernel::Avx512F) {
        let (x, y) = (run(Kernel::Avx2Fma), run(Kernel::Avx512F));
        assert!(x.iter().zip(&y).all(|(p, q)| p.to_bits() == q.to_bits()));
    }
}

/// A model's image embeddings and input gradient do not depend on the number of threads, for
/// every kernel.
#[test]
fn image_pass_is_deterministic_across_thread_counts() {
    let mut cfg = ClipConfig::vit_b32();
    // Two narrower layers (the scalar kernels are slow): every weight product still has
    // ≥ 2^20 multiply-adds and so runs threaded, over 4 (64-column) or 16 panels.
    cfg.vision.tower.num_layers = 2;
    cfg.vision.tower.hidden_size = 256;
    cfg.vision.tower.intermediate_size = 1024;
    cfg.vision.tower.num_heads = 4;
    cfg.text.tower.num_layers = 1;
    let s = cfg.vision.image_size;
    let views: Vec<Image> = (0..3)
        .map(|v| Image {
            width: s,
            height: s,
            data: (0..s * s * 3)
                .map(|i| ((i * 7 + v * 13) % 256) as f32 / 255.0)
                .collect(),
        })
        .collect();
    for kernel in available("determinism") {
        let compute = Compute::default().with_kernel(kernel).unwrap();
        let clip = Clip::from_source_with(cfg.clone(), &RandomSource::new(3), compute).unwrap();
        let pass = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let (emb, cache) = clip.encode_images(&views).unwrap();
                let d: Vec<Vec<f32>> = emb.iter().map(|e| cosine_grad(e, &emb[0])).collect();
                let g = clip.image_backward(&cache, &d).unwrap();
                (emb, g)
            })
        };
        let (e1, g1) = pass(1);
        for threads in [2, 3] {
            let (e, g) = pass(threads);
            let same = e
                .iter()
                .flatten()
                .zip(e1.iter().flatten())
                .all(|(a, b)| a.to_bits() == b.to_bits())
                && g.iter().zip(&g1).all(|(x, y)| {
                    x.data
                        .iter()
                        .zip(&y.data)
                        .all(|(a, b)| a.to_bits() == b.to_bits())
                });
            assert!(same, "{}: {threads} threads differ from 1", kernel.name());
        }
    }
}

/// The transformers golden fixtures (tests/clip/clip_golden.rs) through every kernel: the f32 ones
/// at the golden tests' 1e-4; the bf16 ones at 5e-2, from rounding every weight and
/// activation to 8 significant bits (2⁻⁹ relative each) through 2 layers: measured worst
/// 1.1e-2 (text), 6.3e-3 (image) and 1.4e-2 (input gradient) on these fixtures.
#[test]
fn golden_fixtures_with_every_kernel() {
    let kernels = available("golden");
    for variant in ["quick_gelu", "gelu"] {
        let dir = format!("tests/fixtures/clip/{variant}");
        let golden: Golden =
            serde_json::from_str(&std::fs::read_to_string(format!("{dir}/golden.json")).unwrap())
                .unwrap();
        // Every kernel with a backward copy of each weight, and with one copy (the f32
        // backward then reads the forward's panels transposed, `packed::gemm_t`).
        let setups = kernels.iter().flat_map(|&k| [(k, false), (k, true)]);
        for (kernel, one_copy) in setups {
            let tol = match kernel.precision() {
                Precision::F32 => 1e-4,
                Precision::Bf16 => 5e-2,
            };
            let copies = if one_copy { "one copy" } else { "two copies" };
            let name = format!("{variant} ({}, {copies})", kernel.name());
            let mut req = ModelRequest::new(&dir);
            req.tokenizer = Some(Path::new(TOKENIZER).to_path_buf());
            let compute = Compute::default()
                .with_kernel(kernel)
                .unwrap()
                .with_one_copy(one_copy);
            let clip = Clip::load_request_with(&req, compute).unwrap();
            let ids: Vec<Vec<u32>> = golden.texts.iter().map(|t| t.ids.clone()).collect();
            let text = clip.encode_tokens(&ids).unwrap();
            let worst_text = text
                .iter()
                .zip(&golden.texts)
                .map(|(g, t)| rel_err(g, &t.embedding))
                .fold(0.0, f64::max);
            let images: Vec<Image> = golden.images.iter().map(|i| to_image(i)).collect();
            let (emb, cache) = clip.encode_images(&images).unwrap();
            let worst_img = emb
                .iter()
                .zip(&golden.image_embeddings)
                .map(|(g, w)| rel_err(g, w))
                .fold(0.0, f64::max);
            let d: Vec<Vec<f32>> = emb
                .iter()
                .zip(&golden.grad_pairs)
                .map(|(e, &p)| cosine_grad(e, &text[p]))
                .collect();
            let grads = clip.image_backward(&cache, &d).unwrap();
            let worst_grad = grads
                .iter()
                .zip(&golden.grad_images)
                .map(|(g, w)| rel_err(&g.data, &to_image(w).data))
                .fold(0.0, f64::max);
            eprintln!(
                "{name}: text {worst_text:.1e}, image {worst_img:.1e}, input gradient {worst_grad:.1e}"
            );
            assert!(worst_text <= tol, "{name}: text {worst_text:.2e}");
            assert!(worst_img <= tol, "{name}: image {worst_img:.2e}");
            assert!(worst_grad <= tol, "{name}: gradient {worst_grad:.2e}");
        }
    }
}

/// A kernel the CPU lacks is refused before anything runs.
#[test]
fn missing_kernels_are_refused() {
    for kernel in Kernel::ALL {
        let refused = Compute::default().with_kernel(kernel).is_none();
        assert_eq!(refused, !kernel.available(), "{}", kernel.name());
        let refused =
            std::panic::catch_unwind(|| PackedB::from_rows_for(kernel, &[1.0], 1, 1)).is_err();
        assert_eq!(refused, !kernel.available(), "{}", kernel.name());
    }
    // bf16 is native exactly where its kernel is, and `auto` never picks an emulated one, nor
    // one its calibration measured too slow.
    assert_eq!(
        Precision::Bf16.native(),
        Kernel::Avx512Bf16.available() || Kernel::Amx.available()
    );
    assert_eq!(
        Precision::auto() == Precision::Bf16,
        Precision::Bf16.native()
            && t2tf::clip::bf16_speedup().unwrap() >= t2tf::clip::AUTO_BF16_MIN_SPEEDUP
    );
}

/// Where the CPU has AMX: the AMX units and their emulation (`Kernel::AmxEmulated`, tested
/// against the instruction's definition on every CPU) give the same bits, through the whole
/// product path, on odd shapes, sub-ranges, both precisions of edge (partial tiles, partial
/// steps) and every thread count. Elsewhere the test says why it did not run, and fails where
/// `T2TF_REQUIRE_KERNELS` names `amx`.
#[test]
fn amx_hardware_matches_its_emulation_bit_for_bit() {
    let kernels = available("amx vs emulation");
    if !kernels.contains(&Kernel::Amx) {
        eprintln!(
            "amx vs emulation: not run: {}",
            packed::amx_status().err().unwrap_or_default()
        );
        return;
    }
    let shapes = [
        (1, 1, 1, 0..1, 0..1),
        (150, 768, 768, 0..768, 0..768),
        (150, 3072, 768, 0..768, 0..3072),
        (37, 130, 301, 3..300, 5..130),
        (40, 200, 700, 1..700, 64..200),
    ];
    for (m, n, bk, ks, cols) in shapes {
        let k = ks.len();
        let a = values(m * k, 21, 1.0);
        let b = values(bk * n, 22, 1.0);
        let bias = values(n, 23, 1.0);
        let run = |kernel: Kernel, threads: usize| {
            let packed = PackedB::from_rows_for(kernel, &b, bk, n);
            let mut c = values(m * cols.len(), 24, 1.0);
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                packed::gemm(
                    &mut c,
                    cols.len(),
                    &a,
                    k,
                    m,
                    &packed,
                    ks.clone(),
                    cols.clone(),
                    Some(&bias),
                    true,
                )
            });
            c
        };
        let emulated = run(Kernel::AmxEmulated, 1);
        for threads in [1, 2] {
            let hardware = run(Kernel::Amx, threads);
            for (i, (h, e)) in hardware.iter().zip(&emulated).enumerate() {
                assert!(
                    h.to_bits() == e.to_bits(),
                    "{m}x{n}, B rows {ks:?}, columns {cols:?}, {threads} threads: element {i}: AMX {h}, emulation {e}"
                );
            }
        }
    }
}

/// The transposed product `C = A · B[.., cols]ᵀ` on a forward packing (`packed::gemm_t`, the
/// input backward of a layer holding one copy of its weight), for every f32 kernel, against the
/// f64 reference: odd shapes, column ranges starting and ending inside a panel, strided A, the
/// ViT-B/32 backward shapes; the same bits whatever the thread count, the same bits from the
/// AVX2 and AVX-512 kernels, and the same bits as the product with a second copy of the
/// weight for the AVX2 and scalar kernels.
#[test]
fn transposed_products_match_the_scalar_reference() {
    // m, B's k × n, the columns of B that A's columns multiply.
    let cases = [
        (1, 1, 1, 0..1),
        (5, 7, 3, 0..3),
        (7, 65, 130, 63..65),
        (13, 301, 203, 3..200),
        (6, 64, 256, 64..256),
        (151, 97, 515, 1..515),
        (150, 768, 2304, 768..1536),
        (150, 3072, 768, 0..768),
        (150, 768, 3072, 0..3072),
    ];
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let two = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    let kernels: Vec<Kernel> = available("transposed")
        .into_iter()
        .filter(|k| k.precision() == Precision::F32)
        .collect();
    for (m, kt, nt, cols) in cases {
        let b = values(kt * nt, 21, 1.0);
        let lda = cols.len() + 5;
        let a = values(m * lda, 22, 1.0);
        // Reference: C[i][p] = Σ_j A[i][j] · B[p][cols.start + j].
        let want: Vec<f64> = (0..m * kt)
            .map(|e| {
                let (i, p) = (e / kt, e % kt);
                cols.clone()
                    .enumerate()
                    .map(|(j, col)| a[i * lda + j] as f64 * b[p * nt + col] as f64)
                    .sum()
            })
            .collect();
        let mut by_kernel = Vec::new();
        for &kernel in &kernels {
            let packed = PackedB::from_rows_for(kernel, &b, kt, nt);
            let got = two.install(|| packed::gemm_t(&a, lda, m, &packed, cols.clone()));
            let single = one.install(|| packed::gemm_t(&a, lda, m, &packed, cols.clone()));
            assert_eq!(got.len(), m * kt);
            for (idx, (&g, &w)) in got.iter().zip(&want).enumerate() {
                assert!(
                    (g as f64 - w).abs() <= tolerance(cols.len()),
                    "{} {m}x{kt}x{nt} {cols:?}: element {idx}: {g} vs {w}",
                    kernel.name()
                );
            }
            assert!(
                got.iter()
                    .zip(&single)
                    .all(|(x, y)| x.to_bits() == y.to_bits()),
                "{} {m}x{kt}x{nt}: 1 and 2 threads differ",
                kernel.name()
            );
            if cols.start % 64 == 0 && kernel != Kernel::Avx512F {
                // The same k-blocks as the product with a second copy `W` (k-blocks from a
                // multiple of 64, that is how layers split B): the same sums in the same
                // order, so one copy or two give the same bits. (The AVX-512 kernels' tiles
                // differ in shape; there the two agree to rounding.)
                let w: Vec<f32> = (0..kt)
                    .flat_map(|p| b[p * nt..][cols.clone()].iter().copied())
                    .collect();
                let second = PackedB::from_cols_for(kernel, &w, cols.len(), kt);
                let mut c = vec![0.0f32; m * kt];
                let (ks, n) = (0..cols.len(), 0..kt);
                two.install(|| packed::gemm(&mut c, kt, &a, lda, m, &second, ks, n, None, false));
                assert!(
                    got.iter().zip(&c).all(|(x, y)| x.to_bits() == y.to_bits()),
                    "{} {m}x{kt}x{nt} {cols:?}: one copy and two differ",
                    kernel.name()
                );
            }
            by_kernel.push((kernel, got));
        }
        let bits = |k: Kernel| by_kernel.iter().find(|(x, _)| *x == k).map(|(_, c)| c);
        if let (Some(x), Some(y)) = (bits(Kernel::Avx2Fma), bits(Kernel::Avx512F)) {
            assert!(
                x.iter().zip(y).all(|(p, q)| p.to_bits() == q.to_bits()),
                "{m}x{kt}x{nt} {cols:?}: AVX2 and AVX-512 differ"
            );
        }
    }
}
