//! The AVX2 int8 kernels (hosts): panels of 32 outputs, and two rows at a time for layers
//! of at most 16.
// The vector kernels are `unsafe`: intrinsics of a `#[target_feature]` the caller checked.
#![allow(unsafe_code)]

#[cfg(target_arch = "x86")]
use std::arch::x86::*;
#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

use super::panels::{QuadPanels, write_sums};
use super::{GROUP, ZeroGroups};

/// One group of sixteen input bytes (`xs`, 256 bits: the same sixteen bytes in both halves,
/// or two rows' sixteen, one per half) times a group's 16 weight vectors at `base` into four
/// 256-bit sums: per quad one `vpshufd` spread, then per weight vector `vpmaddubsw` (the
/// weights its memory operand), `vpmaddwd` with ones, `vpaddd`.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
macro_rules! avx2_group {
    ($xs:expr, $base:expr, $ones:expr, [$s0:ident, $s1:ident, $s2:ident, $s3:ident]) => {{
        let (xs, base, ones) = ($xs, $base, $ones);
        macro_rules! quad {
            ($xq:expr, $w:expr) => {{
                let (xq, w) = ($xq, $w);
                $s0 = _mm256_add_epi32(
                    $s0,
                    _mm256_madd_epi16(_mm256_maddubs_epi16(xq, _mm256_loadu_si256(w)), ones),
                );
                $s1 = _mm256_add_epi32(
                    $s1,
                    _mm256_madd_epi16(_mm256_maddubs_epi16(xq, _mm256_loadu_si256(w.add(1))), ones),
                );
                $s2 = _mm256_add_epi32(
                    $s2,
                    _mm256_madd_epi16(_mm256_maddubs_epi16(xq, _mm256_loadu_si256(w.add(2))), ones),
                );
                $s3 = _mm256_add_epi32(
                    $s3,
                    _mm256_madd_epi16(_mm256_maddubs_epi16(xq, _mm256_loadu_si256(w.add(3))), ones),
                );
            }};
        }
        quad!(_mm256_shuffle_epi32::<0x00>(xs), base);
        quad!(_mm256_shuffle_epi32::<0x55>(xs), base.add(4));
        quad!(_mm256_shuffle_epi32::<0xaa>(xs), base.add(8));
        quad!(_mm256_shuffle_epi32::<0xff>(xs), base.add(12));
    }};
}

/// [`u8s8_max_product_scalar`] with AVX2 (`vpmaddubsw`, `vpmaddwd`): panels of 32 outputs in four
/// registers; a group of sixteen input bytes copied to both 128-bit halves and each quad
/// spread over all lanes with `vpshufd`, so one spread serves 32 outputs' four products.
///
/// # Safety
/// The CPU must have AVX2; `weights.width()` must be 32.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn u8s8_max_product_32c_avx2(
    x: &[u8],
    weights: &QuadPanels,
    acc: &mut [i32],
    zeros: ZeroGroups,
) {
    assert!(weights.width == 32 && !weights.pairs);
    let (cells, rows) = weights.cells_in(x, acc);
    let row = weights.padded_inputs();
    let groups = row / GROUP;
    let ones = _mm256_set1_epi16(1);
    let cell_rows = x
        .chunks_exact(rows * row)
        .zip(acc.chunks_mut(weights.outputs));
    for (x, acc) in cell_rows.take(cells) {
        for (panel, out) in acc.chunks_mut(32).enumerate() {
            let w = weights.panel(panel);
            assert_eq!(w.len(), groups * GROUP * 32);
            let vectors = w.as_ptr().cast::<__m256i>();
            let mut largest = [_mm256_set1_epi32(i32::MIN); 4];
            for inputs in x.chunks_exact(row).take(rows) {
                let (mut s0, mut s1, mut s2, mut s3) = (
                    _mm256_setzero_si256(),
                    _mm256_setzero_si256(),
                    _mm256_setzero_si256(),
                    _mm256_setzero_si256(),
                );
                for g in 0..groups {
                    // SAFETY: group `g` of the row (`groups * 16` bytes) and its 16 weight
                    // vectors of the panel (`groups * 512` bytes, asserted above).
                    unsafe {
                        let xs = _mm256_broadcastsi128_si256(_mm_loadu_si128(
                            inputs.as_ptr().add(g * GROUP).cast::<__m128i>(),
                        ));
                        if zeros == ZeroGroups::Skip && _mm256_testz_si256(xs, xs) != 0 {
                            continue;
                        }
                        avx2_group!(xs, vectors.add(g * 16), ones, [s0, s1, s2, s3]);
                    }
                }
                for (most, sums) in largest.iter_mut().zip([s0, s1, s2, s3]) {
                    *most = _mm256_max_epi32(*most, sums);
                }
            }
            write_sums::<32>(out, |target| {
                // SAFETY: four stores of eight lanes into the 32 `i32` at `target`.
                unsafe {
                    for (k, most) in largest.into_iter().enumerate() {
                        _mm256_storeu_si256(target.cast::<__m256i>().add(k), most);
                    }
                }
            });
        }
    }
}

/// [`u8s8_max_product_scalar`] with AVX2 for layers of at most 16 outputs ([`QuadPanels::pairs`]):
/// two rows at once, one per 128-bit half, so each `vpmaddubsw` computes four outputs' four
/// products for both rows, where 128-bit code on one row leaves half of every instruction
/// unused. A last row without a partner is paired with itself (the largest is the same).
/// At the end each output's largest of its two halves. Callgrind, host, int8 CNN forward:
/// the 16-wide layers' kernel about 1.2 M instructions with 128-bit code, 0.6 M here
/// (cross/README.md, "int8, fifth round").
///
/// # Safety
/// The CPU must have AVX2; `weights` must be laid out by [`QuadPanels::pairs`].
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn u8s8_max_product_2x16c_avx2(
    x: &[u8],
    weights: &QuadPanels,
    acc: &mut [i32],
    zeros: ZeroGroups,
) {
    assert!(weights.pairs && weights.width == 32 && weights.outputs <= 16);
    let (cells, rows) = weights.cells_in(x, acc);
    let row = weights.padded_inputs();
    let groups = row / GROUP;
    let w = weights.panel(0);
    assert_eq!(w.len(), groups * GROUP * 32);
    let vectors = w.as_ptr().cast::<__m256i>();
    let ones = _mm256_set1_epi16(1);
    let cell_rows = x
        .chunks_exact(rows * row)
        .zip(acc.chunks_mut(weights.outputs));
    for (x, acc) in cell_rows.take(cells) {
        let mut largest = [_mm256_set1_epi32(i32::MIN); 4];
        for first in (0..rows).step_by(2) {
            let a = x[first * row..].as_ptr();
            let b = x[(first + 1).min(rows - 1) * row..].as_ptr();
            let (mut s0, mut s1, mut s2, mut s3) = (
                _mm256_setzero_si256(),
                _mm256_setzero_si256(),
                _mm256_setzero_si256(),
                _mm256_setzero_si256(),
            );
            for g in 0..groups {
                // SAFETY: rows `first` and `first + 1` (or `first` again) are whole rows of
                // `groups * 16` bytes inside the cell's `x` (`cells_in`), and the panel holds
                // `groups` groups' 16 weight vectors (asserted above).
                unsafe {
                    let xs = _mm256_inserti128_si256::<1>(
                        _mm256_castsi128_si256(_mm_loadu_si128(a.add(g * GROUP).cast::<__m128i>())),
                        _mm_loadu_si128(b.add(g * GROUP).cast::<__m128i>()),
                    );
                    if zeros == ZeroGroups::Skip && _mm256_testz_si256(xs, xs) != 0 {
                        continue;
                    }
                    avx2_group!(xs, vectors.add(g * 16), ones, [s0, s1, s2, s3]);
                }
            }
            for (most, sums) in largest.iter_mut().zip([s0, s1, s2, s3]) {
                *most = _mm256_max_epi32(*most, sums);
            }
        }
        write_sums::<16>(acc, |target| {
            // SAFETY: four stores of four lanes into the 16 `i32` at `target`.
            unsafe {
                for (k, most) in largest.into_iter().enumerate() {
                    let halves = _mm_max_epi32(
                        _mm256_castsi256_si128(most),
                        _mm256_extracti128_si256::<1>(most),
                    );
                    _mm_storeu_si128(target.cast::<__m128i>().add(k), halves);
                }
            }
        });
    }
}
