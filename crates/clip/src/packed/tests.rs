use super::*;
use std::ops::Range;

/// C = base + A·B (+ bias) in f64, B given row-major [k, n].
fn naive(
    base: &[f32],
    a: &[f32],
    b: &[f32],
    m: usize,
    n: usize,
    k: usize,
    bias: Option<&[f32]>,
) -> Vec<f64> {
    let mut c: Vec<f64> = base.iter().map(|&v| v as f64).collect();
    for i in 0..m {
        for j in 0..n {
            let s: f64 = (0..k)
                .map(|p| a[i * k + p] as f64 * b[p * n + j] as f64)
                .sum();
            c[i * n + j] += s + bias.map_or(0.0, |b| b[j] as f64);
        }
    }
    c
}

fn values(len: usize, seed: usize, scale: f32) -> Vec<f32> {
    (0..len)
        .map(|i| ((((i + seed) * 2654435761usize) % 2001) as f32 / 1000.0 - 1.0) * scale)
        .collect()
}

/// Every kernel this CPU runs (the scalar ones always).
fn kernels() -> Vec<Kernel> {
    Kernel::ALL.into_iter().filter(|k| k.available()).collect()
}

/// What the kernel multiplies: `v` itself, or rounded to bf16.
fn seen(kernel: Kernel, v: &[f32]) -> Vec<f32> {
    if kernel.bf16() {
        v.iter().map(|&x| round_bf16(x)).collect()
    } else {
        v.to_vec()
    }
}

/// Error bound of an f32 dot product of length k against the f64 value: ~k·ε·Σ|a||b|,
/// here bounded with the magnitudes used.
fn check(got: &[f32], want: &[f64], tol: f64, what: &str) {
    for (i, (&g, &w)) in got.iter().zip(want).enumerate() {
        assert!(
            (g as f64 - w).abs() <= tol * (1.0 + w.abs()),
            "{what}: element {i}: {g} vs {w}"
        );
    }
}

#[test]
fn odd_shapes_overwrite_and_accumulate_match_f64() {
    let shapes = [
        (1, 1, 1),
        (5, 7, 3),
        (7, 17, 1),
        (6, 16, 256),
        (17, 33, 257),
        (150, 151, 770),
        (151, 150, 513),
        (1, 40, 770),
    ];
    for kernel in kernels() {
        for &(m, n, k) in &shapes {
            let a = values(m * k, 1, 1.0);
            let b = values(k * n, 2, 1.0);
            let bias = values(n, 3, 1.0);
            let pb = PackedB::from_rows_for(kernel, &b, k, n);
            let (ar, br) = (seen(kernel, &a), seen(kernel, &b));
            // The same B given transposed packs to the same thing.
            let mut bt = vec![0.0; k * n];
            for p in 0..k {
                for j in 0..n {
                    bt[j * k + p] = b[p * n + j];
                }
            }
            let pbt = PackedB::from_cols_for(kernel, &bt, k, n);
            assert!(pb.flat() == pbt.flat());
            let tol = 1e-6 * (k as f64).sqrt().max(1.0) * 4.0;
            let base = values(m * n, 4, 2.0);
            let what = format!("{kernel:?} {m}x{n}x{k}");
            for bias in [None, Some(&bias[..])] {
                let mut c = vec![f32::NAN; m * n];
                gemm(&mut c, n, &a, k, m, &pb, 0..k, 0..n, bias, false);
                check(
                    &c,
                    &naive(&vec![0.0; m * n], &ar, &br, m, n, k, bias),
                    tol,
                    &what,
                );
                let mut c = base.clone();
                gemm(&mut c, n, &a, k, m, &pb, 0..k, 0..n, bias, true);
                check(&c, &naive(&base, &ar, &br, m, n, k, bias), tol, &what);
            }
        }
    }
}

/// Sub-ranges of B's rows and (unaligned) columns, strided A and C, k = 0.
#[test]
fn sub_ranges_and_strides() {
    let (m, n, k) = (13, 45, 70);
    let b = values(k * n, 5, 1.0);
    let bias = values(n, 6, 1.0);
    for kernel in kernels() {
        let pb = PackedB::from_rows_for(kernel, &b, k, n);
        let br = seen(kernel, &b);
        for (ks, cols) in [
            (0..k, 0..n),
            (3..70, 5..40),
            (16..33, 16..32),
            (7..8, 44..45),
        ] {
            let (kk, nn) = (ks.len(), cols.len());
            let (lda, ldc) = (kk + 3, nn + 2);
            let a = values(m * lda, 7, 1.0);
            let ar = seen(kernel, &a);
            let mut c = values(m * ldc, 8, 1.0);
            let before = c.clone();
            gemm(
                &mut c,
                ldc,
                &a,
                lda,
                m,
                &pb,
                ks.clone(),
                cols.clone(),
                Some(&bias),
                true,
            );
            for i in 0..m {
                for j in 0..ldc {
                    let got = c[i * ldc + j];
                    if j >= nn {
                        assert_eq!(got.to_bits(), before[i * ldc + j].to_bits(), "padding");
                        continue;
                    }
                    let bj = cols.start + j;
                    let want: f64 = before[i * ldc + j] as f64
                        + bias[bj] as f64
                        + (0..kk)
                            .map(|p| ar[i * lda + p] as f64 * br[(ks.start + p) * n + bj] as f64)
                            .sum::<f64>();
                    assert!(
                        (got as f64 - want).abs() < 1e-5 * (1.0 + want.abs()),
                        "{kernel:?} {ks:?} {cols:?}"
                    );
                }
            }
        }
        // k = 0: C = bias (overwrite) or C + bias (accumulate).
        let mut c = vec![1.0f32; 2 * n];
        gemm(&mut c, n, &[], 0, 2, &pb, 4..4, 0..n, Some(&bias), true);
        assert!(c
            .iter()
            .zip(bias.iter().cycle())
            .all(|(c, b)| *c == 1.0 + b));
        gemm(&mut c, n, &[], 0, 2, &pb, 4..4, 0..n, None, false);
        assert!(c.iter().all(|&c| c == 0.0));
    }
}

#[test]
fn zeros_and_large_magnitudes() {
    let (m, n, k) = (9, 20, 40);
    for kernel in kernels() {
        let pb = PackedB::from_rows_for(kernel, &vec![0.0; k * n], k, n);
        let a = values(m * k, 1, 1e30);
        let mut c = vec![f32::NAN; m * n];
        gemm(&mut c, n, &a, k, m, &pb, 0..k, 0..n, None, false);
        assert!(c.iter().all(|&v| v == 0.0), "overwrite ignores old C");
        // Large but finite products: 1e18 · 1e18 summed over 40 terms stays below f32::MAX.
        let a = values(m * k, 2, 1e18);
        let b = values(k * n, 3, 1e18);
        let pb = PackedB::from_rows_for(kernel, &b, k, n);
        gemm(&mut c, n, &a, k, m, &pb, 0..k, 0..n, None, false);
        let want = naive(
            &vec![0.0; m * n],
            &seen(kernel, &a),
            &seen(kernel, &b),
            m,
            n,
            k,
            None,
        );
        for (&g, &w) in c.iter().zip(&want) {
            assert!(
                g.is_finite() && (g as f64 - w).abs() <= 1e-5 * 1e36 * k as f64,
                "{g} vs {w}"
            );
        }
    }
}

#[test]
fn threaded_equals_single_threaded_bit_for_bit() {
    let (m, n, k) = (150, 200, 300);
    let a = values(m * k, 1, 1.0);
    for kernel in kernels() {
        let pb = PackedB::from_rows_for(kernel, &values(k * n, 2, 1.0), k, n);
        let mut one = vec![0.0; m * n];
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        pool.install(|| gemm(&mut one, n, &a, k, m, &pb, 0..k, 0..n, None, false));
        for threads in [2, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let mut par = vec![0.0; m * n];
            pool.install(|| gemm(&mut par, n, &a, k, m, &pb, 0..k, 0..n, None, false));
            assert!(
                par.iter()
                    .zip(&one)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "{kernel:?} with {threads} threads"
            );
        }
    }
}

/// `post` sees every element of C once, with its row and column, after the product is
/// final (it sees the plain result), and what it writes is the result.
#[test]
fn post_sees_every_element_once_with_its_final_value() {
    use std::sync::atomic::{AtomicU32, Ordering};
    for kernel in kernels() {
        for (m, n, k, cols) in [
            (1, 1, 1, 0..1),
            (13, 130, 70, 3..129),
            (150, 200, 600, 0..200),
            (7, 64, 0, 0..64),
        ] {
            let a = values(m * k, 1, 1.0);
            let pb = PackedB::from_rows_for(kernel, &values(k * n, 2, 1.0), k, n);
            let bias = values(n, 3, 1.0);
            let nn = cols.len();
            let plain = gemm_new(&a, k, m, &pb, 0..k, cols.clone(), Some(&bias));
            let seen: Vec<AtomicU32> = (0..m * nn).map(|_| AtomicU32::new(0)).collect();
            let post = |row: usize, col: usize, v: &mut [f32]| {
                for (i, x) in v.iter_mut().enumerate() {
                    let at = row * nn + col + i;
                    seen[at].fetch_add(1, Ordering::Relaxed);
                    assert_eq!(x.to_bits(), plain[at].to_bits(), "{kernel:?} final value");
                    *x = -*x;
                }
            };
            let got = gemm_new_post(&a, k, m, &pb, 0..k, cols, Some(&bias), Some(&post));
            assert!(
                seen.iter().all(|c| c.load(Ordering::Relaxed) == 1),
                "{kernel:?}"
            );
            assert!(got.iter().zip(&plain).all(|(g, p)| *g == -*p));
        }
    }
}

#[test]
fn bf16_rounding_is_nearest_even() {
    assert_eq!(bf16_bits(1.0), 0x3f80);
    // 1 + 2^-8 is halfway between 1 and 1 + 2^-7: ties to even (1.0).
    assert_eq!(bf16_bits(1.0 + 1.0 / 256.0), 0x3f80);
    // 1 + 3·2^-8 is halfway between 1 + 2^-7 and 1 + 2^-6: ties to even (1 + 2^-6).
    assert_eq!(bf16_bits(1.0 + 3.0 / 256.0), 0x3f82);
    assert_eq!(bf16_bits(-2.5), 0xc020);
    assert!(round_bf16(f32::NAN).is_nan());
    assert_eq!(round_bf16(f32::INFINITY), f32::INFINITY);
    assert_eq!(round_bf16(f32::MAX), f32::INFINITY);
    // The vectorised pair conversion gives the same bits, odd length included.
    let src: Vec<f32> = (0..37).map(|i| (i as f32 - 18.3) * 1.37e-3).collect();
    let mut fast = vec![0u32; 19];
    let mut slow = vec![0u32; 19];
    to_bf16_pairs(&src, &mut fast);
    to_bf16_pairs_body(&src, &mut slow);
    assert_eq!(fast, slow);
    assert_eq!(fast[18], bf16_bits(src[36]) as u32);
    assert_eq!(
        fast[3],
        bf16_bits(src[6]) as u32 | (bf16_bits(src[7]) as u32) << 16
    );
}

#[test]
fn precision_resolution() {
    assert_eq!(Precision::resolve("f32"), Ok(Precision::F32));
    assert_eq!(Precision::resolve("bf16").is_ok(), Precision::Bf16.native());
    let auto = Precision::resolve("auto").unwrap();
    // bf16 only where native and measured faster.
    assert_eq!(
        auto == Precision::Bf16,
        Precision::Bf16.native() && bf16_speedup().unwrap() >= AUTO_BF16_MIN_SPEEDUP
    );
    assert_eq!(bf16_speedup().is_some(), Precision::Bf16.native());
    if let Some(s) = bf16_speedup() {
        eprintln!("bf16 measured {s:.2}× the f32 kernel's speed");
        assert!(s.is_finite() && s > 0.0);
    }
    assert!(Precision::resolve("fp8").is_err());
    let f32_layers = Compute::default().layer_kernel();
    // Native bf16, or f32 layers as before: never an emulated bf16.
    let want = if Precision::Bf16.native() {
        Some(Kernel::Avx512Bf16)
    } else {
        f32_layers
    };
    assert_eq!(Compute::new(Precision::Bf16).layer_kernel(), want);
    assert!(!Compute::default().describe().is_empty());
}

#[test]
fn settings_are_values() {
    let c = Compute::default();
    assert_eq!(c.engine, Engine::detect());
    assert_eq!(c.with_engine(Engine::Crate).layer_kernel(), None);
    let forced = c.with_kernel(Kernel::Portable).unwrap();
    assert_eq!(forced.layer_kernel(), Some(Kernel::Portable));
    assert_eq!(
        forced.with_engine(Engine::Crate).layer_kernel(),
        Some(Kernel::Portable)
    );
    // Built on another thread, a model gets what it is given, not that thread's f32.
    let bf = Compute::new(Precision::Bf16);
    let there = std::thread::spawn(move || bf.layer_kernel())
        .join()
        .unwrap();
    assert_eq!(there, bf.layer_kernel());
}

/// The AMX product as the SDM defines `tdpbf16ps`, written per element of C from B's rows and
/// A's columns, without the packing, tiling or steps of `amx.rs`: A's row and B's rows paired
/// from `ks.start` (an odd start pairs A's first column with B's row before it, as `pack_a`
/// does), blocks of `kc` pairs, 16-pair instructions with a low and a high lane, padding
/// pairs as zeros, and C stored as `Tile::store_scalar` stores it.
#[allow(clippy::too_many_arguments)]
fn amx_model(
    c: &mut [f32],
    a: &[f32],
    m: usize,
    b: &[f32],
    bk: usize,
    bn: usize,
    ks: Range<usize>,
    cols: Range<usize>,
    bias: Option<&[f32]>,
    accumulate: bool,
) {
    let daz = |x: f32| {
        if x.is_subnormal() {
            0.0f32.copysign(x)
        } else {
            x
        }
    };
    let ftz = daz;
    let bf = |x: f32| daz(round_bf16(x));
    let (k, shift) = (ks.len(), ks.start % 2);
    let (q0, kq) = (ks.start / 2, (ks.len() + shift).div_ceil(2));
    let kc = Kernel::AmxEmulated.kc();
    let n = cols.len();
    for i in 0..m {
        // A's column of the low and high half of pair p.
        let a_at = |col: isize| {
            if (0..k as isize).contains(&col) {
                bf(a[i * k + col as usize])
            } else {
                0.0
            }
        };
        for (jj, j) in cols.clone().enumerate() {
            let b_at = |row: usize| if row < bk { bf(b[row * bn + j]) } else { 0.0 };
            for kb in (0..kq).step_by(kc) {
                let block = kc.min(kq - kb);
                let mut acc = 0.0f32;
                for s in (0..block.div_ceil(16)).map(|s| kb + 16 * s) {
                    let (mut lo, mut hi) = (0.0f32, 0.0f32);
                    for p in s..s + 16 {
                        let (a0, a1, b0, b1) = if p < kb + block {
                            let col = 2 * p as isize - shift as isize;
                            let row = 2 * (q0 + p);
                            (a_at(col), a_at(col + 1), b_at(row), b_at(row + 1))
                        } else {
                            (0.0, 0.0, 0.0, 0.0)
                        };
                        lo = ftz(a0.mul_add(b0, lo));
                        hi = ftz(a1.mul_add(b1, hi));
                    }
                    acc = ftz(acc + ftz(lo + hi));
                }
                let first = kb == 0;
                let v = acc
                    + if first {
                        bias.map_or(0.0, |b| b[j])
                    } else {
                        0.0
                    };
                let dst = &mut c[i * n + jj];
                *dst = if !first || accumulate { *dst + v } else { v };
            }
        }
    }
}

#[test]
fn amx_emulation_is_the_instruction_bit_for_bit() {
    // Odd shapes and every edge: partial row tiles and column panels, calls of one pair, k
    // past two blocks, sub-ranges starting at odd rows and columns, bias and accumulate; and
    // values that round to bf16 denormals (read as zero), huge values and exact cancellations.
    let shapes = [
        (1, 1, 1, 0..1, 0..1),
        (17, 70, 33, 0..33, 0..70),
        (37, 130, 301, 0..301, 0..130),
        (16, 64, 512, 3..300, 5..64),
        (40, 200, 700, 1..700, 64..200),
    ];
    for ((m, n, bk, ks, cols), special) in shapes
        .into_iter()
        .flat_map(|s| [(s.clone(), false), (s, true)])
    {
        let k = ks.len();
        // Products of many magnitudes, so that the order of the additions shows in the bits.
        let spread = |v: Vec<f32>| -> Vec<f32> {
            v.iter()
                .enumerate()
                .map(|(i, x)| x * (1 << (i % 9)) as f32 / 97.0 + x / 3.0)
                .collect()
        };
        let mut a = spread(values(m * k, 7, 1.0));
        let mut b = spread(values(bk * n, 8, 1.0));
        if special {
            for (i, x) in a.iter_mut().enumerate().step_by(13) {
                *x = if i % 2 == 0 { 3e-39 } else { -1e30 };
            }
            for (i, x) in b.iter_mut().enumerate().step_by(11) {
                *x = if i % 2 == 0 { -2e-39 } else { 1e-30 };
            }
        }
        let bias = values(n, 9, 1.0);
        let packed = PackedB::from_rows_for(Kernel::AmxEmulated, &b, bk, n);
        for (bias, accumulate) in [(None, false), (Some(&bias[..]), false), (None, true)] {
            let base = values(m * cols.len(), 10, 2.0);
            let mut got = base.clone();
            let mut want = base.clone();
            gemm(
                &mut got,
                cols.len(),
                &a,
                k,
                m,
                &packed,
                ks.clone(),
                cols.clone(),
                bias,
                accumulate,
            );
            amx_model(
                &mut want,
                &a,
                m,
                &b,
                bk,
                n,
                ks.clone(),
                cols.clone(),
                bias,
                accumulate,
            );
            for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                assert!(
                    g.to_bits() == w.to_bits(),
                    "{m}x{n}, B rows {ks:?}, columns {cols:?}, bias {}, accumulate {accumulate}: element {i}: {g} against the instruction's {w}",
                    bias.is_some()
                );
            }
        }
    }
}

#[test]
fn amx_is_available_only_after_the_system_and_the_self_check_agree() {
    match amx_status() {
        Ok(()) => {
            assert!(Kernel::Amx.available());
            assert_eq!(Kernel::best(Precision::Bf16), Some(Kernel::Amx));
        }
        Err(why) => {
            assert!(!Kernel::Amx.available());
            assert!(!why.is_empty());
            assert_ne!(Kernel::best(Precision::Bf16), Some(Kernel::Amx));
            // The emulation runs everywhere; a model never gets it unless forced.
            assert!(Kernel::AmxEmulated.available());
        }
    }
    assert_ne!(Kernel::best(Precision::Bf16), Some(Kernel::AmxEmulated));
}
