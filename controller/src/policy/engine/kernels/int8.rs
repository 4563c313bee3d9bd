//! Integer arithmetic for int8 policies (DESIGN.md, "Policies": `precision = "int8"`): unsigned
//! 8-bit activations times signed 8-bit weights, summed exactly in 32 bits.
//!
//! The building block is the sum of four products, as x86 computes it without VNNI: SSSE3's
//! `pmaddubsw` multiplies sixteen u8 by sixteen s8 and adds neighbouring pairs into 16-bit
//! lanes, `pmaddwd` with ones adds neighbouring 16-bit lanes into 32 bits, `paddd`
//! accumulates (AVX2: the same three on 32 bytes). `pmaddubsw` saturates its 16-bit pair
//! sums; weights within -64..64 keep every pair within 2 x 255 x 64 = 32,640 < 32,767, so
//! saturation cannot happen and the vector kernels equal the scalar integer sum bit for bit.
//! [`QuadPanels::new`] refuses weights outside that range (`dribble_models.quantize` makes
//! them with onnxruntime's `reduce_range`); the tests prove the equality on the worst cases.
//!
//! Layout: a layer's weights in panels of `width` outputs, `[panel][quad][width][4]`: for each
//! four inputs ("quad"), each output's four weights side by side, so one broadcast of the
//! four input bytes meets `width` outputs' weights in `width / 4` vector registers (SSSE3:
//! 16 outputs in four registers; AVX2: 32). A quad whose four inputs are all zero (most of
//! them after ReLU and max-pooling) is skipped with its weights, as the float dense kernel
//! skips zero inputs.
//!
//! The QDQ lowering is what calls these (issue 29, in progress); until then only the tests do.
#![cfg_attr(not(test), allow(dead_code))]
// The vector kernels are `unsafe`: intrinsics of a `#[target_feature]` the caller checked.
#![allow(unsafe_code)]

#[cfg(target_arch = "x86")]
use std::arch::x86::*;
#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

/// The largest weight magnitude the kernels take: `pmaddubsw` cannot saturate below it.
pub(crate) const MAX_WEIGHT: i8 = 64;

/// A weight outside -64..64: the 16-bit pair sums of `pmaddubsw` could saturate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct WeightOutOfRange {
    pub output: usize,
    pub input: usize,
    pub value: i8,
}

/// Int8 weights `[panel][quad][width][4]`; inputs are taken in quads, the last one padded
/// with zero weights, and outputs in panels of `width`, the last padded with zero columns.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct QuadPanels {
    values: Vec<i8>,
    inputs: usize,
    outputs: usize,
    width: usize,
}

impl QuadPanels {
    /// From `rows`, `[out][in]` (`outputs` rows of `inputs`), in panels of `width` outputs
    /// (a multiple of 4).
    pub(crate) fn new(
        rows: &[i8],
        outputs: usize,
        inputs: usize,
        width: usize,
    ) -> Result<Self, WeightOutOfRange> {
        debug_assert!(
            width.is_multiple_of(4) && (4..=64).contains(&width) && rows.len() == outputs * inputs
        );
        let quads = inputs.div_ceil(4);
        let panels = outputs.div_ceil(width);
        let mut values = vec![0; panels * quads * width * 4];
        for (o, row) in rows.chunks_exact(inputs.max(1)).take(outputs).enumerate() {
            let (panel, column) = (o / width, o % width);
            for (i, &w) in row.iter().enumerate() {
                if !(-MAX_WEIGHT..=MAX_WEIGHT).contains(&w) {
                    return Err(WeightOutOfRange {
                        output: o,
                        input: i,
                        value: w,
                    });
                }
                values[((panel * quads + i / 4) * width + column) * 4 + i % 4] = w;
            }
        }
        Ok(Self {
            values,
            inputs,
            outputs,
            width,
        })
    }

    /// Inputs rounded up to whole quads: the length the input slice must have.
    pub(crate) fn padded_inputs(&self) -> usize {
        self.inputs.div_ceil(4) * 4
    }

    fn panel(&self, panel: usize) -> &[i8] {
        let size = self.padded_inputs() * self.width;
        &self.values[panel * size..(panel + 1) * size]
    }
}

/// The four input bytes of quad `q` as one little-endian word.
#[inline(always)]
fn quad(x: &[u8], q: usize) -> u32 {
    u32::from_le_bytes([x[4 * q], x[4 * q + 1], x[4 * q + 2], x[4 * q + 3]])
}

/// `acc = W x` in exact integers, any CPU: the reference the vector kernels equal.
/// `x` holds [`QuadPanels::padded_inputs`] values (the padding zero), `acc` the outputs.
pub(crate) fn dense_portable(x: &[u8], weights: &QuadPanels, acc: &mut [i32]) {
    let width = weights.width;
    let quads = weights.padded_inputs() / 4;
    for (panel, out) in acc.chunks_mut(width).enumerate() {
        let w = weights.panel(panel);
        let mut sums = [0i32; 64];
        let sums = &mut sums[..width.min(64)];
        for q in 0..quads {
            if quad(x, q) == 0 {
                continue;
            }
            let xs = &x[4 * q..4 * q + 4];
            for (column, sum) in sums.iter_mut().enumerate() {
                let ws = &w[(q * width + column) * 4..(q * width + column) * 4 + 4];
                for (&xv, &wv) in xs.iter().zip(ws) {
                    *sum += i32::from(xv) * i32::from(wv);
                }
            }
        }
        out.copy_from_slice(&sums[..out.len()]);
    }
}

/// [`dense_portable`] with SSSE3 (`pmaddubsw`, `pmaddwd`): panels of 16 outputs.
///
/// # Safety
/// The CPU must have SSSE3; `weights.width()` must be 16.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
#[target_feature(enable = "ssse3")]
pub(crate) unsafe fn dense_ssse3(x: &[u8], weights: &QuadPanels, acc: &mut [i32]) {
    debug_assert_eq!(weights.width, 16);
    let quads = weights.padded_inputs() / 4;
    assert!(x.len() >= quads * 4 && acc.len() == weights.outputs);
    let ones = _mm_set1_epi16(1);
    for (panel, out) in acc.chunks_mut(16).enumerate() {
        let w = weights.panel(panel);
        let mut sums = [_mm_setzero_si128(); 4];
        for q in 0..quads {
            let bytes = quad(x, q);
            if bytes == 0 {
                continue;
            }
            let xs = _mm_set1_epi32(bytes as i32);
            let base = w[q * 64..q * 64 + 64].as_ptr().cast::<__m128i>();
            for (v, sum) in sums.iter_mut().enumerate() {
                // SAFETY: `base` points at the quad's 64 weight bytes (a slice bounds-checked
                // above); `v < 4` reads 16 of them, unaligned.
                let ws = unsafe { _mm_loadu_si128(base.add(v)) };
                let pairs = _mm_maddubs_epi16(xs, ws);
                *sum = _mm_add_epi32(*sum, _mm_madd_epi16(pairs, ones));
            }
        }
        let mut lanes = [0i32; 16];
        for (v, sum) in sums.iter().enumerate() {
            // SAFETY: four lanes of 32 bits into `lanes[4 v..4 v + 4]`, inside its 16.
            unsafe { _mm_storeu_si128(lanes[4 * v..].as_mut_ptr().cast(), *sum) };
        }
        out.copy_from_slice(&lanes[..out.len()]);
    }
}

/// [`dense_portable`] with AVX2 (`vpmaddubsw`, `vpmaddwd`): panels of 32 outputs.
///
/// # Safety
/// The CPU must have AVX2; `weights.width()` must be 32.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn dense_avx2(x: &[u8], weights: &QuadPanels, acc: &mut [i32]) {
    debug_assert_eq!(weights.width, 32);
    let quads = weights.padded_inputs() / 4;
    assert!(x.len() >= quads * 4 && acc.len() == weights.outputs);
    let ones = _mm256_set1_epi16(1);
    for (panel, out) in acc.chunks_mut(32).enumerate() {
        let w = weights.panel(panel);
        let mut sums = [_mm256_setzero_si256(); 4];
        for q in 0..quads {
            let bytes = quad(x, q);
            if bytes == 0 {
                continue;
            }
            let xs = _mm256_set1_epi32(bytes as i32);
            let base = w[q * 128..q * 128 + 128].as_ptr().cast::<__m256i>();
            for (v, sum) in sums.iter_mut().enumerate() {
                // SAFETY: `base` points at the quad's 128 weight bytes (bounds-checked
                // above); `v < 4` reads 32 of them, unaligned.
                let ws = unsafe { _mm256_loadu_si256(base.add(v)) };
                let pairs = _mm256_maddubs_epi16(xs, ws);
                *sum = _mm256_add_epi32(*sum, _mm256_madd_epi16(pairs, ones));
            }
        }
        let mut lanes = [0i32; 32];
        for (v, sum) in sums.iter().enumerate() {
            // SAFETY: eight lanes of 32 bits into `lanes[8 v..8 v + 8]`, inside its 32.
            unsafe { _mm256_storeu_si256(lanes[8 * v..].as_mut_ptr().cast(), *sum) };
        }
        out.copy_from_slice(&lanes[..out.len()]);
    }
}

/// A layer's integer sums back to what its QDQ graph computes next: `(acc + bias) * scale[o]`
/// with `scale[o] = s_x * s_w[o]` (dequantized, for a float layer after it) or that divided by
/// the next activation's scale, rounded half to even and clamped to u8 (requantized; ReLU is
/// the clamp at 0 where the zero point is 0). One function for every instruction set, so
/// that they agree bit for bit after the sums too.
pub(crate) fn dequantize(acc: &[i32], bias: &[i32], scale: &[f32], out: &mut [f32]) {
    for (((y, &a), &b), &s) in out.iter_mut().zip(acc).zip(bias).zip(scale) {
        *y = (a + b) as f32 * s;
    }
}

/// See [`dequantize`]; `multiplier[o] = s_x * s_w[o] / s_y`, zero point `zero`.
pub(crate) fn requantize(acc: &[i32], bias: &[i32], multiplier: &[f32], zero: u8, out: &mut [u8]) {
    for (((y, &a), &b), &m) in out.iter_mut().zip(acc).zip(bias).zip(multiplier) {
        let value = ((a + b) as f32 * m).round_ties_even() + f32::from(zero);
        *y = value.clamp(0.0, 255.0) as u8;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The definition: `[out][in]` rows, one product at a time, in i64 so nothing can wrap.
    fn reference(x: &[u8], rows: &[i8], outputs: usize, inputs: usize) -> Vec<i32> {
        (0..outputs)
            .map(|o| {
                let sum: i64 = (0..inputs)
                    .map(|i| i64::from(x[i]) * i64::from(rows[o * inputs + i]))
                    .sum();
                i32::try_from(sum).expect("fits")
            })
            .collect()
    }

    struct Lcg(u64);

    impl Lcg {
        fn next(&mut self) -> u64 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            self.0 >> 33
        }
    }

    /// Every kernel this CPU runs, on `x` (padded to whole quads) and `rows`.
    fn every_kernel(
        x: &[u8],
        rows: &[i8],
        outputs: usize,
        inputs: usize,
    ) -> Vec<(&'static str, Vec<i32>)> {
        let mut padded = x.to_vec();
        padded.resize(inputs.div_ceil(4) * 4, 0);
        let mut results = Vec::new();
        for width in [4, 8, 16] {
            let weights = QuadPanels::new(rows, outputs, inputs, width).expect("in range");
            let mut acc = vec![0; outputs];
            dense_portable(&padded, &weights, &mut acc);
            results.push(("portable", acc));
        }
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        {
            if std::arch::is_x86_feature_detected!("ssse3") {
                let weights = QuadPanels::new(rows, outputs, inputs, 16).expect("in range");
                let mut acc = vec![0; outputs];
                // SAFETY: SSSE3 detected; width 16.
                unsafe { dense_ssse3(&padded, &weights, &mut acc) };
                results.push(("ssse3", acc));
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                let weights = QuadPanels::new(rows, outputs, inputs, 32).expect("in range");
                let mut acc = vec![0; outputs];
                // SAFETY: AVX2 detected; width 32.
                unsafe { dense_avx2(&padded, &weights, &mut acc) };
                results.push(("avx2", acc));
            }
        }
        results
    }

    #[test]
    fn every_kernel_equals_the_integer_definition_on_random_layers() {
        let mut rng = Lcg(29);
        for (outputs, inputs) in [(128, 2560), (3, 128), (37, 13), (16, 4), (1, 1), (33, 7)] {
            let rows: Vec<i8> = (0..outputs * inputs)
                .map(|_| ((rng.next() % 129) as i16 - 64) as i8)
                .collect();
            // Half the inputs zero, as after ReLU, so that skipped quads are tested too.
            let x: Vec<u8> = (0..inputs)
                .map(|_| {
                    if rng.next().is_multiple_of(2) {
                        0
                    } else {
                        rng.next() as u8
                    }
                })
                .collect();
            let expected = reference(&x, &rows, outputs, inputs);
            for (kernel, acc) in every_kernel(&x, &rows, outputs, inputs) {
                assert_eq!(acc, expected, "{kernel}, {outputs}x{inputs}");
            }
        }
    }

    #[test]
    fn the_worst_cases_of_pmaddubsw_do_not_saturate() {
        // Every input 255 against every weight at an end of the range: each 16-bit pair sum
        // is then +-32,640, the largest magnitudes the range allows; mixed signs in a row
        // and alternating patterns too. A saturating sum (or a kernel that adds pairs in 16
        // bits) would differ from the definition here.
        let inputs = 2560;
        let outputs = 32;
        let x = vec![255u8; inputs];
        let patterns: [&dyn Fn(usize, usize) -> i8; 4] = [
            &|_, _| MAX_WEIGHT,
            &|_, _| -MAX_WEIGHT,
            &|o, i| {
                if (o + i).is_multiple_of(2) {
                    MAX_WEIGHT
                } else {
                    -MAX_WEIGHT
                }
            },
            &|o, i| {
                if (i / 2 + o).is_multiple_of(2) {
                    MAX_WEIGHT
                } else {
                    -MAX_WEIGHT
                }
            },
        ];
        for (p, pattern) in patterns.iter().enumerate() {
            let rows: Vec<i8> = (0..outputs * inputs)
                .map(|k| pattern(k / inputs, k % inputs))
                .collect();
            let expected = reference(&x, &rows, outputs, inputs);
            for (kernel, acc) in every_kernel(&x, &rows, outputs, inputs) {
                assert_eq!(acc, expected, "{kernel}, pattern {p}");
            }
        }
        assert_eq!(
            reference(&[255; 2560], &[64; 2560], 1, 2560),
            [255 * 64 * 2560]
        );
    }

    #[test]
    fn weights_pmaddubsw_could_saturate_on_are_refused() {
        let mut rows = vec![0i8; 8 * 5];
        rows[3 * 5 + 2] = -65;
        assert_eq!(
            QuadPanels::new(&rows, 8, 5, 8),
            Err(WeightOutOfRange {
                output: 3,
                input: 2,
                value: -65
            })
        );
        rows[3 * 5 + 2] = 127;
        assert!(QuadPanels::new(&rows, 8, 5, 8).is_err());
        rows[3 * 5 + 2] = -64;
        assert!(QuadPanels::new(&rows, 8, 5, 8).is_ok());
    }

    #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
    #[test]
    fn a_full_range_weight_would_saturate_pmaddubsw() {
        // Why the range is refused: with -128..127 weights two products of 255 overflow the
        // 16-bit pair sum, and `pmaddubsw` answers 32,767 instead of 64,770.
        if !std::arch::is_x86_feature_detected!("ssse3") {
            return;
        }
        // SAFETY: SSSE3 detected.
        let lane = unsafe {
            let pairs = _mm_maddubs_epi16(_mm_set1_epi8(-1), _mm_set1_epi8(127));
            _mm_extract_epi16::<0>(pairs)
        };
        assert_eq!(lane, 32_767);
        assert_eq!(255 * 127 * 2, 64_770);
    }

    #[test]
    fn requantizing_rounds_half_to_even_and_clamps_to_u8() {
        let acc = [5, 15, 25, -40, 10_000, 0];
        let bias = [0, 0, 0, 0, 0, 1];
        let mut out = [0u8; 6];
        requantize(&acc, &bias, &[0.1; 6], 0, &mut out);
        // 0.5 -> 0, 1.5 -> 2, 2.5 -> 2, negative -> 0 (ReLU), 1000 -> 255, 0.1 -> 0.
        assert_eq!(out, [0, 2, 2, 0, 255, 0]);
        let mut floats = [0f32; 2];
        dequantize(&[3, -4], &[1, 1], &[0.5, 0.25], &mut floats);
        assert_eq!(floats, [2.0, -0.75]);
    }
}
