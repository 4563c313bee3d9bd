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
        Some(Self {
            vectors,
            rows,
            padded_width,
        })
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

/// The row `py` of pooled sums, `sums[q * 4 + o]` for the `pw` pooled pixels `q` and each
/// output `o`: the largest of the pool window's four exact integer sums. `pmaxsd` selects
/// SSE4.1's maximum (the V6 and every AVX2 CPU), else SSSE3's comparison and masks.
///
/// # Safety
/// The CPU must have SSSE3 (and SSE4.1 with `pmaxsd`), and
/// [`PooledPixelWeights::takes_pool`] must hold for `[[2, 2], [2, 2], [ph, pw]]` with `py <
/// ph` and `codes.len()`.
#[inline(always)]
unsafe fn pooled_row<const PMAXSD: bool>(
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
            // SAFETY: the caller's promise.
            unsafe { pooled_row::<$pmaxsd>(weights, codes, py, pw, sums) }
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

    fn check(codes: &[u8], ordered: &[i8], padded: [usize; 2], pooled: [usize; 2]) {
        let weights = PooledPixelWeights::new(ordered, [OUTPUTS, 1], [5, 5], [2, 2], padded[1])
            .expect("the kernel's layer");
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
            let ordered: Vec<i8> = (0..OUTPUTS * 25)
                .map(|_| (next() % 129) as i8 - 64)
                .collect();
            check(&codes, &ordered, padded, pooled);
        }
        // The worst case for the 16-bit pair sums: every code 255, every weight -64 or 64.
        let codes = vec![255; 28 * 40];
        for weight in [-64, 64] {
            check(&codes, &[weight; OUTPUTS * 25], [28, 40], [6, 9]);
        }
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
