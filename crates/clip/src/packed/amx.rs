//! Intel AMX-BF16 for the bf16 products: `tdpbf16ps` on 16 × 16 tiles of C (`tile`), and the
//! instruction computed in software, bit for bit as the SDM defines it (`tile_emulated`).
//!
//! **Layout.** The bf16 kernels' own panels are AMX's operand layout, so nothing is packed
//! anew: a B panel is `[⌈k/2⌉][64]` u32 (pair q of column j holds B[2q][j] in its low half and
//! B[2q + 1][j] in its high half), and a B tile is 16 of its pair rows × 16 columns, 64 bytes a
//! row at a stride of 256 bytes; A is rows of pairs `[rows][kq]` u32 (`pack_a`, 16 rows per
//! panel here), and an A tile is 16 rows × 16 pairs at the stride of A's rows. A micro-tile is
//! 16 rows × 64 columns of C: four C tiles (tmm0–3) accumulate, per step of 16 pairs, the
//! products of one A tile (tmm4) with four B tiles (tmm5–7, then tmm5 again). A call's last
//! step of fewer than 16 pairs reads zero-padded copies (`Tail`); zero pairs add exact zeros.
//! The accumulated 16 × 64 tile is stored to memory and added into C by the scalar store every
//! kernel's edges use (`Tile::store_scalar`), so bias, accumulation and partial tiles follow
//! one code path.
//!
//! **Numerics** (Intel SDM, TDPBF16PS): per row of C and per instruction, two f32 lanes per
//! column start at zero and accumulate the low and the high bf16 products over the 16 pairs in
//! k order (fused multiply-add, round to nearest even, denormal inputs read as zero, denormal
//! results flushed to zero); their sum is then added to C. `tdpbf16ps_emulated` is that
//! definition, and `tile_emulated` runs it over the same steps as `tile`, so `Kernel::AmxEmulated`
//! is the exact model of `Kernel::Amx`: every CPU tests the AMX path's layout code through it,
//! and where the CPU has AMX a test compares the two bit for bit.
//!
//! **At run time** `status` grants the tile state (`t2tf_core::platform::amx_tiles`: CPUID, XCR0,
//! Linux's `arch_prctl`), then multiplies a small product with odd edges through `gemm` with
//! both kernels; `Kernel::Amx` is available only when they agree. Whether `auto` then picks it
//! is the calibration's call (`precision.rs`).
//!
//! **Untuned.** The tile shape (one A and four B tile loads per four `tdpbf16ps`) and a
//! `ldtilecfg` per call were chosen for the layout, on a machine without AMX; `bench_clip`
//! prints an AMX row wherever the CPU has it, which is where they are to be tuned.

use std::sync::OnceLock;

use super::{Tile, NR_MAX};

/// Rows of C per micro-tile: a tile register's 16 rows.
pub(crate) const ROWS: usize = 16;
/// k pairs per `tdpbf16ps` (an A tile row is 64 bytes of pairs).
const PAIRS: usize = 16;
/// Columns of C per tile register.
const COLS: usize = 16;
/// Columns of a micro-tile (a whole B panel: four C tiles).
const NR: usize = NR_MAX;
/// Most steps of one call: `Kernel::kc()` (128 pairs) in 16-pair steps.
const MAX_STEPS: usize = 8;

/// One `tdpbf16ps` step of a micro-tile: its A tile (16 rows of 16 pairs, `a_stride` bytes
/// apart) and the start of its 16 pair rows of the B panel (256 bytes apart). `repr(C)`: the
/// assembly loop reads the fields at offsets 0, 8 and 16.
#[repr(C)]
#[derive(Clone, Copy)]
struct Step {
    a: *const u32,
    a_stride: usize,
    b: *const u32,
}

/// Zero-padded copies of a call's last, partial step.
#[repr(C, align(64))]
struct Tail {
    a: [u32; ROWS * PAIRS],
    b: [u32; PAIRS * NR],
}

/// A micro-tile's accumulators in memory, `[ROWS][NR]`.
#[repr(C, align(64))]
struct Acc([f32; ROWS * NR]);

/// The steps of a call over `kq` pairs: full steps read in place, a last partial one from
/// `tail`, zero-padded.
///
/// # Safety
/// `a` holds `ROWS` rows of at least `kq` u32s, `lda` apart; `b` holds `kq` rows of `NR` u32s.
unsafe fn steps(
    kq: usize,
    a: *const u32,
    lda: usize,
    b: *const u32,
    tail: &mut Tail,
) -> ([Step; MAX_STEPS], usize) {
    assert!(
        (1..=MAX_STEPS * PAIRS).contains(&kq),
        "amx: {kq} pairs per call"
    );
    let empty = Step {
        a: std::ptr::null(),
        a_stride: 0,
        b: std::ptr::null(),
    };
    let mut list = [empty; MAX_STEPS];
    let full = kq / PAIRS;
    for (s, step) in list.iter_mut().enumerate().take(full) {
        *step = Step {
            a: a.wrapping_add(s * PAIRS),
            a_stride: lda * 4,
            b: b.wrapping_add(s * PAIRS * NR),
        };
    }
    let rest = kq - full * PAIRS;
    if rest == 0 {
        return (list, full);
    }
    tail.a.fill(0);
    tail.b.fill(0);
    for r in 0..ROWS {
        // SAFETY: row r of A holds kq u32s (the caller's contract).
        let src = unsafe { std::slice::from_raw_parts(a.add(r * lda + full * PAIRS), rest) };
        tail.a[r * PAIRS..][..rest].copy_from_slice(src);
    }
    // SAFETY: B holds kq rows of NR u32s (the caller's contract).
    let src = unsafe { std::slice::from_raw_parts(b.add(full * PAIRS * NR), rest * NR) };
    tail.b[..rest * NR].copy_from_slice(src);
    list[full] = Step {
        a: tail.a.as_ptr(),
        a_stride: PAIRS * 4,
        b: tail.b.as_ptr(),
    };
    (list, full + 1)
}

/// A bf16 (the low 16 bits) widened to f32, a denormal read as zero of its sign.
#[inline(always)]
fn daz(bits: u32) -> f32 {
    let x = bits << 16;
    if x & 0x7f80_0000 == 0 {
        f32::from_bits(x & 0x8000_0000)
    } else {
        f32::from_bits(x)
    }
}

/// A denormal result flushed to zero of its sign.
#[inline(always)]
fn ftz(x: f32) -> f32 {
    if x.is_subnormal() {
        f32::from_bits(x.to_bits() & 0x8000_0000)
    } else {
        x
    }
}

/// One `tdpbf16ps` on C tile `j` of `acc` (columns `16j ..`), as the SDM defines it: with
/// AVX2 and FMA where the CPU has them (the same bits: a fused multiply-add rounds once either
/// way; without them `f32::mul_add` is a library call per element).
///
/// # Safety
/// `step`'s A tile holds 16 rows of 16 u32s and its B rows 16 rows of `NR` u32s.
unsafe fn tdpbf16ps_emulated(acc: &mut Acc, j: usize, step: &Step) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU has AVX2 and FMA (checked above); the rest is the caller's.
        return unsafe { tdpbf16ps_fma(acc, j, step) };
    }
    // SAFETY: the caller's.
    unsafe { tdpbf16ps_body(acc, j, step) }
}

/// `tdpbf16ps_body` compiled for AVX2 and FMA.
///
/// # Safety
/// As `tdpbf16ps_emulated`; the CPU has AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn tdpbf16ps_fma(acc: &mut Acc, j: usize, step: &Step) {
    // SAFETY: the caller's.
    unsafe { tdpbf16ps_body(acc, j, step) }
}

/// The instruction's definition (see `tdpbf16ps_emulated`).
///
/// # Safety
/// As `tdpbf16ps_emulated`.
#[inline(always)]
unsafe fn tdpbf16ps_body(acc: &mut Acc, j: usize, step: &Step) {
    for m in 0..ROWS {
        // SAFETY: row m of the A tile (the caller's contract).
        let arow: &[u32] = unsafe {
            std::slice::from_raw_parts(step.a.cast::<u8>().add(m * step.a_stride).cast(), PAIRS)
        };
        let mut lo = [0.0f32; COLS];
        let mut hi = [0.0f32; COLS];
        for (k, &av) in arow.iter().enumerate() {
            let (a0, a1) = (daz(av & 0xffff), daz(av >> 16));
            // SAFETY: pair row k of the B rows, columns 16j .. 16j + 16 (the caller's contract).
            let brow = unsafe { std::slice::from_raw_parts(step.b.add(k * NR + j * COLS), COLS) };
            for n in 0..COLS {
                lo[n] = ftz(a0.mul_add(daz(brow[n] & 0xffff), lo[n]));
                hi[n] = ftz(a1.mul_add(daz(brow[n] >> 16), hi[n]));
            }
        }
        let row = &mut acc.0[m * NR + j * COLS..][..COLS];
        for n in 0..COLS {
            row[n] = ftz(row[n] + ftz(lo[n] + hi[n]));
        }
    }
}

/// The AMX micro-tile computed in software: `tile`'s steps and numerics, on any CPU.
///
/// # Safety
/// As `Tile::store_scalar`; `a` holds `ROWS` rows of at least `kq` u32s, `lda` apart, and `b`
/// `kq` rows of `NR` u32s.
pub(super) unsafe fn tile_emulated(
    kq: usize,
    a: *const u32,
    lda: usize,
    b: *const u32,
    crow: *mut f32,
    ldc: usize,
    t: &Tile,
) {
    debug_assert_eq!(t.nr, NR);
    let mut tail = Tail {
        a: [0; ROWS * PAIRS],
        b: [0; PAIRS * NR],
    };
    // SAFETY: forwarded from the caller.
    let (list, len) = unsafe { steps(kq, a, lda, b, &mut tail) };
    let mut acc = Acc([0.0; ROWS * NR]);
    for step in &list[..len] {
        for j in 0..NR / COLS {
            // SAFETY: `steps` made every step's tiles readable.
            unsafe { tdpbf16ps_emulated(&mut acc, j, step) };
        }
    }
    // SAFETY: forwarded from the caller.
    unsafe { t.store_scalar(&acc.0, crow, ldc) }
}

/// The tile configuration (`ldtilecfg`'s 64 bytes): palette 1, and every tile register used
/// (tmm0–7) 16 rows of 64 bytes.
#[cfg(target_arch = "x86_64")]
#[repr(C, align(64))]
struct Config([u8; 64]);

#[cfg(target_arch = "x86_64")]
static CONFIG: Config = {
    let mut c = [0u8; 64];
    c[0] = 1;
    let mut t = 0;
    while t < 8 {
        // Bytes 16 + 2t: the tile's bytes per row (u16, little-endian); byte 48 + t: its rows.
        c[16 + 2 * t] = 64;
        c[48 + t] = ROWS as u8;
        t += 1;
    }
    Config(c)
};

/// One micro-tile on the AMX units: 16 rows × 64 columns of C from `kq` pairs.
///
/// # Safety
/// As `tile_emulated`; and the system has granted this process the tile state
/// (`t2tf_core::platform::amx_tiles`), which `status` checks before `Kernel::Amx` counts as
/// available.
#[cfg(target_arch = "x86_64")]
pub(super) unsafe fn tile(
    kq: usize,
    a: *const u32,
    lda: usize,
    b: *const u32,
    crow: *mut f32,
    ldc: usize,
    t: &Tile,
) {
    debug_assert_eq!(t.nr, NR);
    let mut tail = Tail {
        a: [0; ROWS * PAIRS],
        b: [0; PAIRS * NR],
    };
    // SAFETY: forwarded from the caller.
    let (list, len) = unsafe { steps(kq, a, lda, b, &mut tail) };
    let mut acc = Acc([0.0; ROWS * NR]);
    // SAFETY: the CPU has AMX-TILE and AMX-BF16 and the system granted the tile state (the
    // caller's contract); each step's A tile is 16 rows of 64 readable bytes at its stride,
    // its B tiles 16 rows of 64 readable bytes at 256-byte stride (`steps`); `acc` holds 16
    // rows of 256 bytes; len ≥ 1. The tile registers are not used by compiled code, and the
    // block releases them (`tilerelease`) before it ends.
    unsafe {
        std::arch::asm!(
            "ldtilecfg [{cfg}]",
            "tilezero tmm0",
            "tilezero tmm1",
            "tilezero tmm2",
            "tilezero tmm3",
            "2:",
            "mov {pa}, [{list}]",
            "mov {sa}, [{list} + 8]",
            "mov {pb}, [{list} + 16]",
            "tileloadd tmm4, [{pa} + {sa}*1]",
            "tileloadd tmm5, [{pb} + {row}*1]",
            "tdpbf16ps tmm0, tmm4, tmm5",
            "tileloadd tmm6, [{pb} + {row}*1 + 64]",
            "tdpbf16ps tmm1, tmm4, tmm6",
            "tileloadd tmm7, [{pb} + {row}*1 + 128]",
            "tdpbf16ps tmm2, tmm4, tmm7",
            "tileloadd tmm5, [{pb} + {row}*1 + 192]",
            "tdpbf16ps tmm3, tmm4, tmm5",
            "add {list}, 24",
            "dec {n}",
            "jnz 2b",
            "tilestored [{c} + {row}*1], tmm0",
            "tilestored [{c} + {row}*1 + 64], tmm1",
            "tilestored [{c} + {row}*1 + 128], tmm2",
            "tilestored [{c} + {row}*1 + 192], tmm3",
            "tilerelease",
            cfg = in(reg) CONFIG.0.as_ptr(),
            list = inout(reg) list.as_ptr() => _,
            n = inout(reg) len => _,
            pa = out(reg) _,
            sa = out(reg) _,
            pb = out(reg) _,
            row = in(reg) NR * 4,
            c = in(reg) acc.0.as_mut_ptr(),
            out("tmm0") _,
            out("tmm1") _,
            out("tmm2") _,
            out("tmm3") _,
            out("tmm4") _,
            out("tmm5") _,
            out("tmm6") _,
            out("tmm7") _,
            options(nostack),
        );
    }
    // SAFETY: forwarded from the caller.
    unsafe { t.store_scalar(&acc.0, crow, ldc) }
}

/// Whether `Kernel::Amx` may run here, or why not: the system grants this process the tile
/// state, and a self-check product agrees with the emulation. Computed once per process, on
/// first use (a few milliseconds).
pub fn status() -> Result<(), String> {
    static STATUS: OnceLock<Result<(), String>> = OnceLock::new();
    STATUS
        .get_or_init(|| {
            t2tf_core::platform::amx_tiles()?;
            self_check()
        })
        .clone()
}

/// A product with every edge of the layout (a partial last row tile, a partial last column
/// panel, two k-blocks, a partial step, bias) on the AMX units and in the emulation, through
/// the whole `gemm` path (packing, blocking, threads, stores). They should agree bit for bit;
/// the check allows float rounding (an error of a few ulps of Σ|a·b|), so that it rejects a
/// wrong layout, not a difference in the order of the instruction's additions (which the
/// tests on AMX machines look for, bit for bit).
fn self_check() -> Result<(), String> {
    use super::{gemm, Kernel, PackedB};
    let (m, k, n) = (37, 301, 130);
    let value = |i: usize, seed: usize| (((i + seed) * 2654435761) % 2001) as f32 / 1000.0 - 1.0;
    let a: Vec<f32> = (0..m * k).map(|i| value(i, 1)).collect();
    let b: Vec<f32> = (0..k * n).map(|i| value(i, 2)).collect();
    let bias: Vec<f32> = (0..n).map(|i| value(i, 3)).collect();
    let run = |kernel| {
        let packed = PackedB::from_rows_unchecked(kernel, &b, k, n);
        let mut c = vec![0.0f32; m * n];
        gemm(&mut c, n, &a, k, m, &packed, 0..k, 0..n, Some(&bias), false);
        c
    };
    let hardware = run(Kernel::Amx);
    let emulated = run(Kernel::AmxEmulated);
    // |a|, |b| ≤ 1: Σ|a·b| ≤ k.
    let tolerance = 8.0 * k as f32 * f32::EPSILON;
    for (i, (h, e)) in hardware.iter().zip(&emulated).enumerate() {
        if (h - e).abs() > tolerance || h.is_nan() {
            return Err(format!(
                "the AMX self-check failed: element {i} is {h}, its emulation {e}"
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn denormals_are_read_and_written_as_zero() {
        // The smallest bf16 denormal, positive and negative, and the smallest normal.
        assert_eq!(daz(0x0001).to_bits(), 0);
        assert_eq!(daz(0x8001).to_bits(), 0x8000_0000);
        assert_eq!(daz(0x0080), f32::MIN_POSITIVE);
        assert_eq!(ftz(f32::MIN_POSITIVE / 2.0).to_bits(), 0);
        assert_eq!(ftz(-f32::MIN_POSITIVE / 2.0).to_bits(), 0x8000_0000);
        assert_eq!(ftz(f32::MIN_POSITIVE), f32::MIN_POSITIVE);
    }

    #[test]
    fn the_configuration_is_palette_1_with_eight_16_by_64_byte_tiles() {
        #[cfg(target_arch = "x86_64")]
        {
            let c = &CONFIG.0;
            assert_eq!(c[0], 1);
            for t in 0..8 {
                assert_eq!(u16::from_le_bytes([c[16 + 2 * t], c[17 + 2 * t]]), 64);
                assert_eq!(c[48 + t], 16);
            }
            assert!(c[32..48].iter().all(|&x| x == 0) && c[56..].iter().all(|&x| x == 0));
        }
    }
}
