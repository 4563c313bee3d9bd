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
//! The QDQ lowering (`lower/quantized.rs`) lays the weights out; the plan's int8 steps call
//! [`Int8Kernel::dense`] once per dense row and [`Window::product`] once per convolution
//! output pixel, whose window is read in place from the padded map, one segment per kernel
//! row ([`Segments`]), or, for the cameras' one-channel layers, gathered with one 8-byte
//! load and store per row (a `memcpy` call per 5-byte row was more than the V5's first
//! layer could afford; rows rounded up to quads waste 3 of every 10).
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

    pub(crate) fn inputs(&self) -> usize {
        self.inputs
    }

    pub(crate) fn outputs(&self) -> usize {
        self.outputs
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

/// Where a product's inputs lie: `starts.len()` segments of `4 * quads` bytes each, segment
/// `r` from `x[starts[r]]` on, read one after the other as one vector of
/// [`QuadPanels::padded_inputs`] bytes. A dense row is one segment; a convolution window is
/// one segment per kernel row, read in place from the padded map (its rows rounded up to
/// whole quads: the extra bytes belong to the next pixel and meet zero weights).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Segments<'a> {
    pub starts: &'a [usize],
    pub quads: usize,
}

impl Segments<'_> {
    /// Every segment inside `x`, and as many quads in all as the weights have: checked once
    /// per call, so the loops' reads are in bounds.
    fn check(&self, x: &[u8], weights: &QuadPanels) {
        let len = 4 * self.quads;
        assert!(
            self.starts.len() * len == weights.padded_inputs()
                && self
                    .starts
                    .iter()
                    .all(|&start| start.checked_add(len).is_some_and(|end| end <= x.len())),
            "int8 segments outside their input"
        );
    }

    /// The four bytes of quad `q` (counted over all segments) as one little-endian word.
    #[inline(always)]
    fn quad(&self, x: &[u8], segment: usize, q: usize) -> u32 {
        quad(&x[self.starts[segment]..], q)
    }
}

/// `acc = W x` in exact integers, any CPU: the reference the vector kernels equal.
pub(crate) fn dense_portable(
    x: &[u8],
    segments: Segments<'_>,
    weights: &QuadPanels,
    acc: &mut [i32],
) {
    segments.check(x, weights);
    let width = weights.width;
    for (panel, out) in acc.chunks_mut(width).enumerate() {
        let w = weights.panel(panel);
        let mut sums = [0i32; 64];
        let sums = &mut sums[..width.min(64)];
        for segment in 0..segments.starts.len() {
            for q in 0..segments.quads {
                let bytes = segments.quad(x, segment, q).to_le_bytes();
                if bytes == [0; 4] {
                    continue;
                }
                let base = (segment * segments.quads + q) * width;
                for (column, sum) in sums.iter_mut().enumerate() {
                    let ws = &w[(base + column) * 4..(base + column) * 4 + 4];
                    for (&xv, &wv) in bytes.iter().zip(ws) {
                        *sum += i32::from(xv) * i32::from(wv);
                    }
                }
            }
        }
        out.copy_from_slice(&sums[..out.len()]);
    }
}

/// [`dense_portable`] with SSSE3 (`pmaddubsw`, `pmaddwd`): panels of 16 outputs, held in
/// four registers (with the input broadcast, a weight vector, the ones and a product: the
/// V5's eight). Bounds are checked once per segment, not per quad.
///
/// # Safety
/// The CPU must have SSSE3; `weights.width()` must be 16.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
#[target_feature(enable = "ssse3")]
pub(crate) unsafe fn dense_ssse3(
    x: &[u8],
    segments: Segments<'_>,
    weights: &QuadPanels,
    acc: &mut [i32],
) {
    debug_assert_eq!(weights.width, 16);
    segments.check(x, weights);
    assert_eq!(acc.len(), weights.outputs);
    let ones = _mm_set1_epi16(1);
    let row = 4 * segments.quads;
    for (panel, out) in acc.chunks_mut(16).enumerate() {
        let w = weights.panel(panel);
        let (mut s0, mut s1, mut s2, mut s3) = (
            _mm_setzero_si128(),
            _mm_setzero_si128(),
            _mm_setzero_si128(),
            _mm_setzero_si128(),
        );
        for (segment, &start) in segments.starts.iter().enumerate() {
            let inputs = &x[start..start + row];
            let panel_row = &w[segment * row * 16..(segment + 1) * row * 16];
            for (bytes, quad_weights) in inputs.chunks_exact(4).zip(panel_row.chunks_exact(64)) {
                let bytes = u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]);
                if bytes == 0 {
                    continue;
                }
                let xs = _mm_set1_epi32(bytes as i32);
                let base = quad_weights.as_ptr().cast::<__m128i>();
                // SAFETY: `quad_weights` is 64 bytes (an exact chunk); each load reads 16 of
                // them, unaligned.
                let (w0, w1, w2, w3) = unsafe {
                    (
                        _mm_loadu_si128(base),
                        _mm_loadu_si128(base.add(1)),
                        _mm_loadu_si128(base.add(2)),
                        _mm_loadu_si128(base.add(3)),
                    )
                };
                s0 = _mm_add_epi32(s0, _mm_madd_epi16(_mm_maddubs_epi16(xs, w0), ones));
                s1 = _mm_add_epi32(s1, _mm_madd_epi16(_mm_maddubs_epi16(xs, w1), ones));
                s2 = _mm_add_epi32(s2, _mm_madd_epi16(_mm_maddubs_epi16(xs, w2), ones));
                s3 = _mm_add_epi32(s3, _mm_madd_epi16(_mm_maddubs_epi16(xs, w3), ones));
            }
        }
        if let Ok(out) = <&mut [i32; 16]>::try_from(&mut *out) {
            let target = out.as_mut_ptr().cast::<__m128i>();
            // SAFETY: four stores of four lanes into the 16 of `out`.
            unsafe {
                _mm_storeu_si128(target, s0);
                _mm_storeu_si128(target.add(1), s1);
                _mm_storeu_si128(target.add(2), s2);
                _mm_storeu_si128(target.add(3), s3);
            }
        } else {
            let mut lanes = [0i32; 16];
            let target = lanes.as_mut_ptr().cast::<__m128i>();
            // SAFETY: as above, into `lanes`.
            unsafe {
                _mm_storeu_si128(target, s0);
                _mm_storeu_si128(target.add(1), s1);
                _mm_storeu_si128(target.add(2), s2);
                _mm_storeu_si128(target.add(3), s3);
            }
            for (o, &lane) in out.iter_mut().zip(&lanes) {
                *o = lane;
            }
        }
    }
}

/// [`dense_portable`] with AVX2 (`vpmaddubsw`, `vpmaddwd`): panels of 32 outputs.
///
/// # Safety
/// The CPU must have AVX2; `weights.width()` must be 32.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn dense_avx2(
    x: &[u8],
    segments: Segments<'_>,
    weights: &QuadPanels,
    acc: &mut [i32],
) {
    debug_assert_eq!(weights.width, 32);
    segments.check(x, weights);
    assert_eq!(acc.len(), weights.outputs);
    let ones = _mm256_set1_epi16(1);
    let row = 4 * segments.quads;
    for (panel, out) in acc.chunks_mut(32).enumerate() {
        let w = weights.panel(panel);
        let (mut s0, mut s1, mut s2, mut s3) = (
            _mm256_setzero_si256(),
            _mm256_setzero_si256(),
            _mm256_setzero_si256(),
            _mm256_setzero_si256(),
        );
        for (segment, &start) in segments.starts.iter().enumerate() {
            let inputs = &x[start..start + row];
            let panel_row = &w[segment * row * 32..(segment + 1) * row * 32];
            for (bytes, quad_weights) in inputs.chunks_exact(4).zip(panel_row.chunks_exact(128)) {
                let bytes = u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]);
                if bytes == 0 {
                    continue;
                }
                let xs = _mm256_set1_epi32(bytes as i32);
                let base = quad_weights.as_ptr().cast::<__m256i>();
                // SAFETY: `quad_weights` is 128 bytes (an exact chunk); each load reads 32
                // of them, unaligned.
                let (w0, w1, w2, w3) = unsafe {
                    (
                        _mm256_loadu_si256(base),
                        _mm256_loadu_si256(base.add(1)),
                        _mm256_loadu_si256(base.add(2)),
                        _mm256_loadu_si256(base.add(3)),
                    )
                };
                s0 = _mm256_add_epi32(s0, _mm256_madd_epi16(_mm256_maddubs_epi16(xs, w0), ones));
                s1 = _mm256_add_epi32(s1, _mm256_madd_epi16(_mm256_maddubs_epi16(xs, w1), ones));
                s2 = _mm256_add_epi32(s2, _mm256_madd_epi16(_mm256_maddubs_epi16(xs, w2), ones));
                s3 = _mm256_add_epi32(s3, _mm256_madd_epi16(_mm256_maddubs_epi16(xs, w3), ones));
            }
        }
        let mut lanes = [0i32; 32];
        let target = lanes.as_mut_ptr().cast::<__m256i>();
        // SAFETY: four stores of eight lanes into the 32 of `lanes`.
        unsafe {
            _mm256_storeu_si256(target, s0);
            _mm256_storeu_si256(target.add(1), s1);
            _mm256_storeu_si256(target.add(2), s2);
            _mm256_storeu_si256(target.add(3), s3);
        }
        for (o, &lane) in out.iter_mut().zip(&lanes) {
            *o = lane;
        }
    }
}

/// Which int8 dense kernel a plan calls, chosen once at load for the instruction set it was
/// lowered for and checked against this CPU there: AVX2 (panels of 32 outputs) where the
/// float kernels are AVX2 or AVX-512, SSSE3 (16) on the SSSE3 and SSE4.2 sets (the V5 and
/// V6 Atoms), the portable one on SSE2 and the portable set. The field is private, so a
/// kernel this CPU lacks cannot be named.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Int8Kernel(Kind);

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Portable,
    Ssse3,
    Avx2,
}

impl Int8Kernel {
    pub(crate) const PORTABLE: Self = Self(Kind::Portable);

    /// SSSE3's kernel where this CPU has SSSE3, else the portable one.
    pub(crate) fn ssse3() -> Self {
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        if std::arch::is_x86_feature_detected!("ssse3") {
            return Self(Kind::Ssse3);
        }
        Self::PORTABLE
    }

    /// AVX2's kernel where this CPU has AVX2, else the widest it has.
    pub(crate) fn avx2() -> Self {
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        if std::arch::is_x86_feature_detected!("avx2") {
            return Self(Kind::Avx2);
        }
        Self::ssse3()
    }

    pub(crate) fn name(self) -> &'static str {
        match self.0 {
            Kind::Portable => "portable",
            Kind::Ssse3 => "ssse3",
            Kind::Avx2 => "avx2",
        }
    }

    /// The panel width its weights must be laid out in.
    pub(crate) fn width(self) -> usize {
        match self.0 {
            Kind::Portable | Kind::Ssse3 => 16,
            Kind::Avx2 => 32,
        }
    }

    /// `acc = W x` in exact integers, `x` read as `segments` say; `weights` laid out for
    /// this kernel ([`Self::width`]).
    #[inline]
    pub(crate) fn product(
        self,
        x: &[u8],
        segments: Segments<'_>,
        weights: &QuadPanels,
        acc: &mut [i32],
    ) {
        assert_eq!(weights.width, self.width());
        match self.0 {
            Kind::Portable => dense_portable(x, segments, weights, acc),
            #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
            // SAFETY: a `Kind::Ssse3` is made only where SSSE3 was detected; width checked.
            Kind::Ssse3 => unsafe { dense_ssse3(x, segments, weights, acc) },
            #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
            // SAFETY: a `Kind::Avx2` is made only where AVX2 was detected; width checked.
            Kind::Avx2 => unsafe { dense_avx2(x, segments, weights, acc) },
            #[cfg(not(any(target_arch = "x86", target_arch = "x86_64")))]
            _ => dense_portable(x, segments, weights, acc),
        }
    }

    /// [`Self::product`] of one dense row: `x` holds [`QuadPanels::padded_inputs`] bytes.
    #[inline]
    pub(crate) fn dense(self, x: &[u8], weights: &QuadPanels, acc: &mut [i32]) {
        let segments = Segments {
            starts: &[0],
            quads: weights.padded_inputs() / 4,
        };
        self.product(x, segments, weights, acc);
    }
}

/// The shape of an int8 convolution's input and window: `codes` is the zero-bordered map
/// `[padded_h][padded_w][c]` (the border holds the zero point, the integer of 0.0). A window
/// is read one of two ways, chosen by [`Window::new`]:
/// - in place: each kernel row is one segment ([`Segments`]), the weights' rows are
///   `[ky][kx * c, rounded up to whole quads]`;
/// - gathered, where kernel rows are short and rounding each up to whole quads would waste
///   quads (the cameras' one-channel 5x5 layers: rows of 5 bytes take 2 quads each, 10 a
///   window, where the window's 25 bytes fill 7): the rows are copied one after the other
///   into one run of bytes, 8 bytes a row (one load and one store; a row's extra bytes are
///   overwritten by the next row, the last one's meet zero weights), and the weights are
///   `[ky * kx * c, rounded up to whole quads]`. The copy costs about what one quad does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Window {
    pub padded_width: usize,
    pub channels: usize,
    pub kernel: [usize; 2],
    pub stride: [usize; 2],
    pub gather: bool,
}

/// The bytes one gathered row copies.
const GATHERED_ROW: usize = 8;

impl Window {
    /// A window read the cheaper way: gathered where that takes fewer quads.
    pub(crate) fn new(
        padded_width: usize,
        channels: usize,
        kernel: [usize; 2],
        stride: [usize; 2],
    ) -> Self {
        let mut window = Self {
            padded_width,
            channels,
            kernel,
            stride,
            gather: false,
        };
        let gathered_quads = (kernel[0] * window.row()).div_ceil(4);
        window.gather = window.row() <= GATHERED_ROW && gathered_quads < kernel[0] * window.quads();
        window
    }

    /// The bytes of one kernel row of a window.
    pub(crate) fn row(&self) -> usize {
        self.kernel[1] * self.channels
    }

    /// Quads per kernel row read in place, rounded up.
    pub(crate) fn quads(&self) -> usize {
        self.row().div_ceil(4)
    }

    /// The weights' inputs: every kernel row rounded up to whole quads, or (gathered) the
    /// whole window rounded up once.
    pub(crate) fn padded_len(&self) -> usize {
        if self.gather {
            (self.kernel[0] * self.row()).div_ceil(4) * 4
        } else {
            self.kernel[0] * self.quads() * 4
        }
    }

    /// How many bytes past the map a bottom-right window's last row reads (rounding up to
    /// quads, or the 8 bytes a gathered row copies): the codes buffer holds them too.
    pub(crate) fn slack(&self) -> usize {
        if self.gather {
            GATHERED_ROW - self.row()
        } else {
            self.quads() * 4 - self.row()
        }
    }

    /// The scratch a gathered window is copied into (empty where windows are read in place).
    pub(crate) fn scratch(&self) -> Vec<u8> {
        if self.gather {
            vec![
                0;
                self.padded_len()
                    .max((self.kernel[0] - 1) * self.row() + GATHERED_ROW)
            ]
        } else {
            Vec::new()
        }
    }

    /// `rows`, `[out][ky][kx * c]`, laid out as the kernels read this window: each output's
    /// [`Self::padded_len`] weights, zero where they meet padding.
    pub(crate) fn weights(&self, rows: &[i8], outputs: usize) -> Vec<i8> {
        let (row, kh) = (self.row(), self.kernel[0]);
        let step = if self.gather { row } else { self.quads() * 4 };
        let mut laid_out = vec![0; outputs * self.padded_len()];
        for (o, weights) in rows
            .chunks_exact((kh * row).max(1))
            .take(outputs)
            .enumerate()
        {
            for (ky, kernel_row) in weights.chunks_exact(row.max(1)).enumerate() {
                laid_out[o * self.padded_len() + ky * step..][..row].copy_from_slice(kernel_row);
            }
        }
        laid_out
    }

    /// Where each kernel row of output pixel `(y, x)`'s window starts in the map.
    #[inline(always)]
    pub(crate) fn starts(&self, [y, x]: [usize; 2], starts: &mut [usize]) {
        for (ky, start) in starts.iter_mut().enumerate() {
            *start = ((y * self.stride[0] + ky) * self.padded_width + x * self.stride[1])
                * self.channels;
        }
    }

    /// `sums = W window` of the window whose rows start at `starts`, read as this window is
    /// ([`Self::new`]); `scratch` is [`Self::scratch`].
    #[inline(always)]
    pub(crate) fn product(
        &self,
        kernel: Int8Kernel,
        codes: &[u8],
        starts: &[usize],
        scratch: &mut [u8],
        weights: &QuadPanels,
        sums: &mut [i32],
    ) {
        if self.gather {
            let row = self.row();
            for (ky, &start) in starts.iter().enumerate() {
                let mut bytes = [0u8; GATHERED_ROW];
                bytes.copy_from_slice(&codes[start..start + GATHERED_ROW]);
                scratch[ky * row..ky * row + GATHERED_ROW].copy_from_slice(&bytes);
            }
            // The bytes after the window (the last row's extra bytes, or an earlier pixel's)
            // meet zero weights: they are left as they are.
            kernel.dense(&scratch[..self.padded_len()], weights, sums);
        } else {
            let segments = Segments {
                starts,
                quads: self.quads(),
            };
            kernel.product(codes, segments, weights, sums);
        }
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
        let one = Segments {
            starts: &[0],
            quads: padded.len() / 4,
        };
        let mut results = Vec::new();
        for width in [4, 8, 16] {
            let weights = QuadPanels::new(rows, outputs, inputs, width).expect("in range");
            let mut acc = vec![0; outputs];
            dense_portable(&padded, one, &weights, &mut acc);
            results.push(("portable", acc));
        }
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        {
            if std::arch::is_x86_feature_detected!("ssse3") {
                let weights = QuadPanels::new(rows, outputs, inputs, 16).expect("in range");
                let mut acc = vec![0; outputs];
                // SAFETY: SSSE3 detected; width 16.
                unsafe { dense_ssse3(&padded, one, &weights, &mut acc) };
                results.push(("ssse3", acc));
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                let weights = QuadPanels::new(rows, outputs, inputs, 32).expect("in range");
                let mut acc = vec![0; outputs];
                // SAFETY: AVX2 detected; width 32.
                unsafe { dense_avx2(&padded, one, &weights, &mut acc) };
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
    fn a_convolution_read_in_place_equals_the_integer_definition() {
        let mut rng = Lcg(5);
        for (ph, pw, c, oc, [kh, kw], stride) in [
            (13, 17, 3, 10, [5, 5], [2, 2]),
            (9, 11, 1, 16, [5, 5], [2, 2]),
            (7, 7, 8, 33, [3, 3], [1, 1]),
        ] {
            let chosen = Window::new(pw, c, [kh, kw], stride);
            // The one-channel 5x5 window is gathered, the others read in place.
            assert_eq!(chosen.gather, c == 1, "{c} channels");
            // Both ways where both can be: a gathered row copies 8 bytes.
            let ways = [false, true].map(|gather| Window { gather, ..chosen });
            for window in ways.into_iter().filter(|w| !w.gather || w.row() <= 8) {
                // The map's codes, then the slack a last window row reads past it.
                let mut codes: Vec<u8> = (0..ph * pw * c).map(|_| rng.next() as u8).collect();
                codes.extend((0..window.slack()).map(|_| rng.next() as u8));
                let rows: Vec<i8> = (0..oc * kh * kw * c)
                    .map(|_| ((rng.next() % 129) as i16 - 64) as i8)
                    .collect();
                let laid_out = window.weights(&rows, oc);
                let (oh, ow) = ((ph - kh) / stride[0] + 1, (pw - kw) / stride[1] + 1);
                for kernel in [
                    Int8Kernel::PORTABLE,
                    Int8Kernel::ssse3(),
                    Int8Kernel::avx2(),
                ] {
                    let weights =
                        QuadPanels::new(&laid_out, oc, window.padded_len(), kernel.width())
                            .expect("in range");
                    let mut starts = vec![0; kh];
                    let mut sums = vec![0i32; oc];
                    // Stale bytes in the scratch must not matter.
                    let mut scratch = window.scratch();
                    scratch.fill(0xa5);
                    for (y, x) in (0..oh).flat_map(|y| (0..ow).map(move |x| (y, x))) {
                        window.starts([y, x], &mut starts);
                        window.product(kernel, &codes, &starts, &mut scratch, &weights, &mut sums);
                        for (o, &sum) in sums.iter().enumerate() {
                            let mut expected = 0i64;
                            for ky in 0..kh {
                                for kx in 0..kw {
                                    for i in 0..c {
                                        let pixel =
                                            ((y * stride[0] + ky) * pw + x * stride[1] + kx) * c;
                                        let w = rows[((o * kh + ky) * kw + kx) * c + i];
                                        expected += i64::from(codes[pixel + i]) * i64::from(w);
                                    }
                                }
                            }
                            assert_eq!(
                                i64::from(sum),
                                expected,
                                "{}, gathered {}: ({y}, {x}) output {o}",
                                kernel.name(),
                                window.gather
                            );
                        }
                    }
                }
            }
        }
    }
}
