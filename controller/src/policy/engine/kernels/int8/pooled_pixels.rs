//! The cameras' int8 first layers vectorised over pooled pixels: one channel of codes in, four
//! outputs, a 5-wide kernel with stride 2, the 2x2 max-pool with stride 2 after it.
//!
//! Why a kernel of its own: the window kernels copy each output pixel's 25 codes into a
//! window of 32 and multiply it with a panel of four outputs, a quarter of the products
//! padding, and the copies cost as much again. That layer was two thirds of the robot
//! package's int8 forward pass (callgrind, host SSSE3: 0.60 M of 0.92 M instructions).
//!
//! How: the four convolution outputs under pooled pixel `q` read the columns `4q + 2dx + kx`
//! (`dx` the output's column in the pool window, `kx` the tap): so sixteen consecutive codes
//! from column `4q` hold, for four pooled pixels side by side, taps 0-3 of the window's left
//! output (`dx = 0`), and sixteen from `4q + 4` hold its tap 4 and taps 2-4 of the right one
//! (`dx = 1`; taps 0-1 of which are in the first load's upper pair). `pmaddubsw` with weights
//! laid out per four codes (`[w0 w1 w2 w3]`, `[w4 0 0 0]`, `[0 0 w0 w1]`, `[w2 w3 w4 0]`)
//! and `pmaddwd` with ones give each pooled pixel's partial sum of one kernel row in its
//! 32-bit lane. Two loads a kernel row serve both outputs of the window and all four
//! channels; no window is copied. The pool is a lane-wise maximum of the window's four sums.
//!
//! The sums are the exact integer sums the window kernels compute (no weight reaches 64, so
//! `pmaddubsw` cannot saturate: [`super::MAX_WEIGHT`]): the epilogue after them gives the same
//! numbers bit for bit.
//!
//! Where a layer's weights allow it ([`PooledPixelWeights::sums_fit_16_bits`], checked when
//! the layer is loaded), an output's two `pmaddubsw` of a kernel row are added in 16 bits
//! before the one `pmaddwd` that widens them: six multiplies a kernel row and output where
//! eight were. The V6's Silvermont issues every multiply (and `pshufd`) on one port, two
//! cycles each, so the multiplies bound this kernel there (llvm-mca `silvermont`).
// The vector kernels are `unsafe`: intrinsics of a `#[target_feature]` the caller checked.
#![allow(unsafe_code)]

use std::arch::x86_64::*;

/// The outputs the kernel computes.
pub(crate) const OUTPUTS: usize = 4;
/// The kernel's width.
const KERNEL_WIDTH: usize = 5;
/// Pooled pixels a vector holds (four 32-bit lanes).
const LANES: usize = 4;

/// Sixteen weights on a 16-byte boundary: a `pmaddubsw` memory operand.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(C, align(16))]
struct Lanes([i8; 16]);

/// A layer's weights laid out for the kernel: for each kernel row and output, the four
/// vectors of the module's doc, each four codes' weights repeated over the four lanes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct PooledPixelWeights {
    /// `[ky][output][4]`
    vectors: Vec<Lanes>,
    rows: usize,
    /// The code map's width (padded).
    padded_width: usize,
    /// Whether each output's two products of a code pair's lanes ([`Self::sums_fit_16_bits`])
    /// stay inside 16 bits for every code.
    sums_fit_16_bits: bool,
}

impl PooledPixelWeights {
    /// From `ordered`, `[out][ky][kx]` (one input channel), where the layer is the kernel's:
    /// one input channel, four outputs, a kernel 5 wide, stride 2. `None` where not.
    pub(crate) fn new(
        ordered: &[i8],
        [outputs, channels]: [usize; 2],
        kernel: [usize; 2],
        stride: [usize; 2],
        padded_width: usize,
    ) -> Option<Self> {
        let [rows, width] = kernel;
        if outputs != OUTPUTS
            || channels != 1
            || width != KERNEL_WIDTH
            || stride != [2, 2]
            || rows == 0
            || ordered.len() != outputs * rows * width
        {
            return None;
        }
        let mut vectors = Vec::with_capacity(rows * OUTPUTS * 4);
        for ky in 0..rows {
            for o in 0..OUTPUTS {
                let w = &ordered[(o * rows + ky) * width..][..width];
                for quad in [
                    [w[0], w[1], w[2], w[3]],
                    [w[4], 0, 0, 0],
                    [0, 0, w[0], w[1]],
                    [w[2], w[3], w[4], 0],
                ] {
                    let mut lanes = [0; 16];
                    for lane in lanes.chunks_exact_mut(4) {
                        lane.copy_from_slice(&quad);
                    }
                    vectors.push(Lanes(lanes));
                }
            }
        }
        let sums_fit_16_bits = vectors.chunks_exact(2).all(|pair| {
            let [Lanes(a), Lanes(b)] = [pair[0], pair[1]];
            (0..2).all(|p| sum_fits_16_bits([a[2 * p], a[2 * p + 1], b[2 * p], b[2 * p + 1]]))
        });
        Some(Self {
            vectors,
            rows,
            padded_width,
            sums_fit_16_bits,
        })
    }

    /// Whether the kernel adds an output's two `pmaddubsw` of a kernel row in 16 bits: where
    /// for every row, output and side (the window's left and right output, whose taps are
    /// split over the two loads) the four weights that meet in one 16-bit lane of the sum
    /// give a sum inside `i16` for every code from 0 to 255. Then the 16-bit sum is the exact
    /// one, and one `pmaddwd` widens it where two did.
    pub(crate) fn sums_fit_16_bits(&self) -> bool {
        self.sums_fit_16_bits
    }

    /// Whether the kernel computes a pool of this shape: 2x2 windows, stride 2, pooled rows at
    /// least a vector wide, and every code it reads inside `codes` (`codes_len` bytes).
    pub(crate) fn takes_pool(&self, pool: [[usize; 2]; 3], codes_len: usize) -> bool {
        let [kernel, stride, [ph, pw]] = pool;
        kernel == [2, 2]
            && stride == [2, 2]
            && ph > 0
            && pw >= LANES
            // The last row read, and the last block's second load (16 codes from 4q + 4).
            && (4 * (ph - 1) + 2 + self.rows)
                .checked_mul(self.padded_width)
                .is_some_and(|end| end <= codes_len)
            && 4 * (pw - LANES) + 4 + 16 <= self.padded_width
    }
}

/// Whether `weights` times any four codes from 0 to 255 sums to a value an `i16` holds.
fn sum_fits_16_bits(weights: [i8; 4]) -> bool {
    let code = i32::from(u8::MAX);
    let most: i32 = weights.iter().map(|&w| i32::from(w).max(0) * code).sum();
    let least: i32 = weights.iter().map(|&w| i32::from(w).min(0) * code).sum();
    most <= i32::from(i16::MAX) && least >= i32::from(i16::MIN)
}

/// The row `py` of pooled sums, `sums[q * 4 + o]` for the `pw` pooled pixels `q` and each
/// output `o`: the largest of the pool window's four exact integer sums. `pmaxsd` selects
/// SSE4.1's maximum (the V6 and every AVX2 CPU), else SSSE3's comparison and masks.
/// `FIT_16_BITS` adds each output's two products in 16 bits: only where
/// [`PooledPixelWeights::sums_fit_16_bits`].
///
/// # Safety
/// The CPU must have SSSE3 (and SSE4.1 with `pmaxsd`), and
/// [`PooledPixelWeights::takes_pool`] must hold for `[[2, 2], [2, 2], [ph, pw]]` with `py <
/// ph` and `codes.len()`.
#[inline(always)]
unsafe fn pooled_row<const PMAXSD: bool, const FIT_16_BITS: bool>(
    weights: &PooledPixelWeights,
    codes: &[u8],
    py: usize,
    pw: usize,
    sums: &mut [i32],
) {
    let rows = weights.rows;
    let row_bytes = weights.padded_width;
    let vectors = weights.vectors.as_ptr().cast::<__m128i>();
    let sums = &mut sums[..pw * OUTPUTS];
    // SAFETY (every intrinsic below): the caller's CPU has SSSE3 (and SSE4.1 where
    // `PMAXSD`); the loads stay inside `codes` by `takes_pool` (rows up to `4 * py + 2 +
    // rows - 1`, columns up to `4 * (pw - 4) + 4 + 15`), the weights inside `vectors`
    // (`[ky][output][4]`, `ky < rows`).
    unsafe {
        let ones = _mm_set1_epi16(1);
        let mut start = 0;
        loop {
            // The last block overlaps the one before where the row is not a whole number of
            // blocks (its pixels computed twice, identically).
            let q = start.min(pw - LANES);
            let mut best = [_mm_set1_epi32(i32::MIN); OUTPUTS];
            for dy in 0..2 {
                // [dx][output]
                let mut acc = [[_mm_setzero_si128(); OUTPUTS]; 2];
                for ky in 0..rows {
                    let at = (4 * py + 2 * dy + ky) * row_bytes + 4 * q;
                    let first = _mm_loadu_si128(codes.as_ptr().add(at).cast());
                    let second = _mm_loadu_si128(codes.as_ptr().add(at + 4).cast());
                    let w = vectors.add(ky * OUTPUTS * 4);
                    let [left_sums, right_sums] = &mut acc;
                    let outputs = left_sums.iter_mut().zip(right_sums.iter_mut());
                    for (o, (left_sum, right_sum)) in outputs.enumerate() {
                        let w = w.add(o * 4);
                        if FIT_16_BITS {
                            let left = _mm_add_epi16(
                                _mm_maddubs_epi16(first, _mm_load_si128(w)),
                                _mm_maddubs_epi16(second, _mm_load_si128(w.add(1))),
                            );
                            let right = _mm_add_epi16(
                                _mm_maddubs_epi16(first, _mm_load_si128(w.add(2))),
                                _mm_maddubs_epi16(second, _mm_load_si128(w.add(3))),
                            );
                            *left_sum = _mm_add_epi32(*left_sum, _mm_madd_epi16(left, ones));
                            *right_sum = _mm_add_epi32(*right_sum, _mm_madd_epi16(right, ones));
                            continue;
                        }
                        let left = _mm_add_epi32(
                            _mm_madd_epi16(_mm_maddubs_epi16(first, _mm_load_si128(w)), ones),
                            _mm_madd_epi16(
                                _mm_maddubs_epi16(second, _mm_load_si128(w.add(1))),
                                ones,
                            ),
                        );
                        let right = _mm_add_epi32(
                            _mm_madd_epi16(
                                _mm_maddubs_epi16(first, _mm_load_si128(w.add(2))),
                                ones,
                            ),
                            _mm_madd_epi16(
                                _mm_maddubs_epi16(second, _mm_load_si128(w.add(3))),
                                ones,
                            ),
                        );
                        *left_sum = _mm_add_epi32(*left_sum, left);
                        *right_sum = _mm_add_epi32(*right_sum, right);
                    }
                }
                for o in 0..OUTPUTS {
                    best[o] = max::<PMAXSD>(best[o], max::<PMAXSD>(acc[0][o], acc[1][o]));
                }
            }
            // Four outputs of four pixels into four pixels of four outputs.
            let low01 = _mm_unpacklo_epi32(best[0], best[1]);
            let low23 = _mm_unpacklo_epi32(best[2], best[3]);
            let high01 = _mm_unpackhi_epi32(best[0], best[1]);
            let high23 = _mm_unpackhi_epi32(best[2], best[3]);
            let block = &mut sums[q * OUTPUTS..][..LANES * OUTPUTS];
            let pixels = [
                _mm_unpacklo_epi64(low01, low23),
                _mm_unpackhi_epi64(low01, low23),
                _mm_unpacklo_epi64(high01, high23),
                _mm_unpackhi_epi64(high01, high23),
            ];
            for (pixel, out) in pixels.into_iter().zip(block.chunks_exact_mut(OUTPUTS)) {
                _mm_storeu_si128(out.as_mut_ptr().cast(), pixel);
            }
            if q + LANES >= pw {
                break;
            }
            start += LANES;
        }
    }
}

/// The lane-wise maximum of two vectors of `i32`: SSE4.1's `pmaxsd`, or a comparison and
/// masks.
#[inline(always)]
unsafe fn max<const PMAXSD: bool>(a: __m128i, b: __m128i) -> __m128i {
    // SAFETY: the caller's CPU has SSE4.1 where `PMAXSD`, SSE2 always.
    unsafe {
        if PMAXSD {
            _mm_max_epi32(a, b)
        } else {
            let greater = _mm_cmpgt_epi32(a, b);
            _mm_or_si128(_mm_and_si128(greater, a), _mm_andnot_si128(greater, b))
        }
    }
}

/// [`pooled_row`] compiled for the target features `features`, its maximum SSE4.1's
/// `pmaxsd` where `PMAXSD` (one function each: `#[target_feature]` takes no generics).
///
/// # Safety (each function)
/// As [`pooled_row`], the CPU with the features named.
macro_rules! pooled_row_compiled_for {
    ($($(#[$doc:meta])* $name:ident: $features:literal, $pmaxsd:literal;)*) => {$(
        $(#[$doc])*
        #[target_feature(enable = $features)]
        pub(super) unsafe fn $name(
            weights: &PooledPixelWeights,
            codes: &[u8],
            py: usize,
            pw: usize,
            sums: &mut [i32],
        ) {
            // SAFETY: the caller's promise; the 16-bit sums only where the weights allow.
            unsafe {
                if weights.sums_fit_16_bits() {
                    pooled_row::<$pmaxsd, true>(weights, codes, py, pw, sums)
                } else {
                    pooled_row::<$pmaxsd, false>(weights, codes, py, pw, sums)
                }
            }
        }
    )*};
}

pooled_row_compiled_for! {
    /// [`pooled_row`] compiled for SSSE3.
    ///
    /// # Safety
    /// As [`pooled_row`], the CPU with SSSE3.
    pooled_row_ssse3: "ssse3", false;
    /// [`pooled_row`] compiled for SSE4.1 (with SSSE3's `pmaddubsw`).
    ///
    /// # Safety
    /// As [`pooled_row`], the CPU with SSSE3 and SSE4.1.
    pooled_row_sse41: "ssse3,sse4.1", true;
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The pool window's largest exact sum, one product at a time.
    fn reference(
        codes: &[u8],
        width: usize,
        ordered: &[i8],
        rows: usize,
        [ph, pw]: [usize; 2],
    ) -> Vec<i32> {
        let mut sums = vec![0; ph * pw * OUTPUTS];
        for py in 0..ph {
            for q in 0..pw {
                for o in 0..OUTPUTS {
                    let mut best = i32::MIN;
                    for (dy, dx) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                        let (y, x) = (2 * py + dy, 2 * q + dx);
                        let mut sum = 0;
                        for ky in 0..rows {
                            for kx in 0..KERNEL_WIDTH {
                                let code = i32::from(codes[(2 * y + ky) * width + 2 * x + kx]);
                                sum +=
                                    code * i32::from(ordered[(o * rows + ky) * KERNEL_WIDTH + kx]);
                            }
                        }
                        best = best.max(sum);
                    }
                    sums[(py * pw + q) * OUTPUTS + o] = best;
                }
            }
        }
        sums
    }

    fn check(
        codes: &[u8],
        ordered: &[i8],
        padded: [usize; 2],
        pooled: [usize; 2],
        fit_16_bits: bool,
    ) {
        let weights = PooledPixelWeights::new(ordered, [OUTPUTS, 1], [5, 5], [2, 2], padded[1])
            .expect("the kernel's layer");
        assert_eq!(
            weights.sums_fit_16_bits(),
            fit_16_bits,
            "which sums the kernel takes"
        );
        let pool = [[2, 2], [2, 2], pooled];
        assert!(weights.takes_pool(pool, codes.len()));
        let expected = reference(codes, padded[1], ordered, 5, pooled);
        for pmaxsd in [false, true] {
            if pmaxsd && !std::arch::is_x86_feature_detected!("sse4.1") {
                continue;
            }
            let mut sums = vec![0; pooled[1] * OUTPUTS];
            for py in 0..pooled[0] {
                // SAFETY: SSSE3 (and SSE4.1) checked; `takes_pool` holds.
                unsafe {
                    if pmaxsd {
                        pooled_row_sse41(&weights, codes, py, pooled[1], &mut sums);
                    } else {
                        pooled_row_ssse3(&weights, codes, py, pooled[1], &mut sums);
                    }
                }
                let row = &expected[py * pooled[1] * OUTPUTS..][..pooled[1] * OUTPUTS];
                assert_eq!(sums, row, "pooled row {py}, pmaxsd {pmaxsd}");
            }
        }
    }

    #[test]
    fn pooled_pixel_sums_are_the_exact_integer_sums_of_every_window() {
        if !std::arch::is_x86_feature_detected!("ssse3") {
            return;
        }
        // The robot package's two camera layers (padded 124x164 and 64x84, pooled 30x40 and
        // 15x20: a row of five blocks, and one whose last block overlaps), random codes and
        // weights.
        let mut state = 0x2545_f491_u32;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state
        };
        for (padded, pooled) in [
            ([124, 164], [30, 40]),
            ([64, 84], [15, 20]),
            ([28, 40], [6, 9]),
        ] {
            let codes: Vec<u8> = (0..padded[0] * padded[1]).map(|_| next() as u8).collect();
            // Weights from -64 to 64, a row's taps 0, 1 and 4 (which meet in one lane) 64
            // (the 16-bit sums refused), and from -42 to 42 (taken: 3 x 42 x 255 = 32,130).
            let mut wide: Vec<i8> = (0..OUTPUTS * 25)
                .map(|_| ((next() % 129) as i32 - 64) as i8)
                .collect();
            for tap in [0, 1, 4] {
                wide[tap] = 64;
            }
            let narrow: Vec<i8> = (0..OUTPUTS * 25)
                .map(|_| (next() % 85) as i8 - 42)
                .collect();
            check(&codes, &wide, padded, pooled, false);
            check(&codes, &narrow, padded, pooled, true);
        }
        // The worst cases for the 16-bit sums: every code 255 and every weight -64 or 64
        // (refused), -42 or 42 (taken, at most 32,130 of 32,767).
        let codes = vec![255; 28 * 40];
        for (weight, fit) in [(-64, false), (64, false), (-42, true), (42, true)] {
            check(&codes, &[weight; OUTPUTS * 25], [28, 40], [6, 9], fit);
        }
        // Just past the limit in one lane: taps 0, 1 and 4 of one row, 3 x 43 x 255 = 32,895.
        let mut edge = [0i8; OUTPUTS * 25];
        edge[..5].copy_from_slice(&[43, 43, 0, 0, 43]);
        check(&codes, &edge, [28, 40], [6, 9], false);
    }

    #[test]
    fn layers_and_pools_that_are_not_the_kernels_are_refused() {
        let ordered = [1i8; OUTPUTS * 25];
        assert!(PooledPixelWeights::new(&ordered, [OUTPUTS, 1], [5, 5], [1, 1], 84).is_none());
        assert!(PooledPixelWeights::new(&ordered[..75], [3, 1], [5, 5], [2, 2], 84).is_none());
        assert!(
            PooledPixelWeights::new(&ordered[..80], [OUTPUTS, 1], [5, 4], [2, 2], 84).is_none()
        );
        let weights = PooledPixelWeights::new(&ordered, [OUTPUTS, 1], [5, 5], [2, 2], 84)
            .expect("the kernel's");
        assert!(weights.takes_pool([[2, 2], [2, 2], [15, 20]], 64 * 84));
        assert!(!weights.takes_pool([[3, 3], [3, 3], [10, 13]], 64 * 84));
        assert!(
            !weights.takes_pool([[2, 2], [2, 2], [15, 3]], 64 * 84),
            "narrower than a block"
        );
        assert!(
            // Fifteen pooled rows read 4 x 14 + 2 + 5 = 63 rows of codes.
            !weights.takes_pool([[2, 2], [2, 2], [15, 20]], 63 * 84 - 1),
            "codes too short"
        );
        assert!(
            !weights.takes_pool([[2, 2], [2, 2], [15, 21]], 64 * 84),
            "past the row"
        );
    }
}
