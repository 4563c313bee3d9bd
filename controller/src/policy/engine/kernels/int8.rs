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
//! four inputs ("quad"), each output's four weights side by side, so one spread of the four
//! input bytes over the lanes meets `width` outputs' weights in `width / 4` vector registers
//! (16 outputs in four 128-bit registers; AVX2: 32 in four 256-bit ones). Inputs are read
//! sixteen bytes (four quads, a "group") at a time, so a layer's inputs are rounded up to
//! whole groups with zero weights; a group of sixteen zero inputs (common after ReLU and
//! max-pooling) is skipped with its weights.
//!
//! One call computes the largest of several products `W x_r` per output ([`Int8Kernel::largest`]):
//! a dense row is one `x`; a convolution hands over the windows of a max-pool's cell (four
//! for the CNN's 2x2 pools) copied one after the other by [`Window::gather`], so the pool's
//! maximum is taken in vector registers and the call, its checks and the panel set-up are
//! paid once per pooled output instead of once per pixel.
//!
//! History, measured with callgrind (cross/README.md): one call per pixel with the window
//! read in place (a segment per kernel row) and one quad per broadcast cost 8.07 M
//! instructions per CNN forward on the V5, more than the float engine's 5.95 M.
// The vector kernels are `unsafe`: intrinsics of a `#[target_feature]` the caller checked.
#![allow(unsafe_code)]

#[cfg(target_arch = "x86")]
use std::arch::x86::*;
#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

/// The largest weight magnitude the kernels take: `pmaddubsw` cannot saturate below it.
pub(crate) const MAX_WEIGHT: i8 = 64;

/// Inputs are read in groups of this many bytes (four quads, one 128-bit load).
pub(crate) const GROUP: usize = 16;

/// A weight outside -64..64: the 16-bit pair sums of `pmaddubsw` could saturate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct WeightOutOfRange {
    pub output: usize,
    pub input: usize,
    pub value: i8,
}

/// 64 bytes of weights on a 64-byte boundary: one quad of a 16-wide panel, half of a 32-wide
/// one. Aligned so that the SSSE3 kernel's `pmaddubsw` reads its weights as a memory operand
/// (a legacy-encoded SSE instruction takes only aligned ones), which leaves the V5's eight
/// vector registers to the sums.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(C, align(64))]
struct WeightBlock([i8; 64]);

/// Int8 weights `[panel][quad][width][4]`; inputs are taken in whole groups of sixteen, the
/// last one padded with zero weights, and outputs in panels of `width`, the last padded with
/// zero columns. Every quad of a panel of 16 or 32 starts on a 64-byte boundary.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct QuadPanels {
    blocks: Vec<WeightBlock>,
    len: usize,
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
        let quads = inputs.div_ceil(GROUP) * GROUP / 4;
        let panels = outputs.div_ceil(width);
        let len = panels * quads * width * 4;
        let mut blocks = vec![WeightBlock([0; 64]); len.div_ceil(64)];
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
                let at = ((panel * quads + i / 4) * width + column) * 4 + i % 4;
                blocks[at / 64].0[at % 64] = w;
            }
        }
        Ok(Self {
            blocks,
            len,
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

    /// Inputs rounded up to whole groups: the length of each `x` the kernels read.
    pub(crate) fn padded_inputs(&self) -> usize {
        self.inputs.div_ceil(GROUP) * GROUP
    }

    /// The weights as one run of bytes, `[panel][quad][width][4]`.
    fn values(&self) -> &[i8] {
        // SAFETY: `WeightBlock` is 64 `i8` with no padding (`repr(C)`, size 64), so the
        // blocks are `64 * blocks.len()` initialised bytes, of which `len` are used.
        unsafe { std::slice::from_raw_parts(self.blocks.as_ptr().cast::<i8>(), self.len) }
    }

    fn panel(&self, panel: usize) -> &[i8] {
        let size = self.padded_inputs() * self.width;
        &self.values()[panel * size..(panel + 1) * size]
    }

    /// How many rows of [`Self::padded_inputs`] bytes `x` holds; panics where `x` is not
    /// whole rows or `acc` not one sum per output (checked once per call, so the loops'
    /// reads are in bounds).
    fn rows_in(&self, x: &[u8], acc: &[i32]) -> usize {
        let row = self.padded_inputs();
        assert!(
            row > 0 && x.len().is_multiple_of(row) && !x.is_empty() && acc.len() == self.outputs,
            "int8 product of {} bytes against rows of {row}",
            x.len()
        );
        x.len() / row
    }
}

/// `acc[o] = max over rows r of (W x_r)[o]` in exact integers, `x` holding the rows one after
/// the other, any CPU: the reference the vector kernels equal.
pub(crate) fn largest_portable(x: &[u8], weights: &QuadPanels, acc: &mut [i32]) {
    let rows = weights.rows_in(x, acc);
    let (width, row) = (weights.width, weights.padded_inputs());
    for (panel, out) in acc.chunks_mut(width).enumerate() {
        let w = weights.panel(panel);
        let mut largest = [i32::MIN; 64];
        for r in 0..rows {
            let mut sums = [0i32; 64];
            let sums = &mut sums[..width.min(64)];
            for (q, bytes) in x[r * row..(r + 1) * row].chunks_exact(4).enumerate() {
                if bytes == [0; 4] {
                    continue;
                }
                for (column, sum) in sums.iter_mut().enumerate() {
                    let ws = &w[(q * width + column) * 4..(q * width + column) * 4 + 4];
                    for (&xv, &wv) in bytes.iter().zip(ws) {
                        *sum += i32::from(xv) * i32::from(wv);
                    }
                }
            }
            for (most, &sum) in largest.iter_mut().zip(sums.iter()) {
                *most = (*most).max(sum);
            }
        }
        out.copy_from_slice(&largest[..out.len()]);
    }
}

/// One quad's products into one panel's sums, with intrinsics: `xq` holds the quad's four
/// input bytes in every 32-bit lane, `$w` points at the quad's weights (aligned), the sums are
/// 32-bit lanes. `pmaddubsw` leaves 16-bit pair sums (which cannot saturate: [`MAX_WEIGHT`]),
/// `pmaddwd` with ones adds neighbouring pairs into 32 bits, `paddd` accumulates.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
macro_rules! sse_quad {
    ($xq:expr, $w:expr, $ones:expr, [$s0:ident, $s1:ident, $s2:ident, $s3:ident]) => {{
        let (xq, w) = ($xq, $w);
        $s0 = _mm_add_epi32(
            $s0,
            _mm_madd_epi16(_mm_maddubs_epi16(xq, _mm_load_si128(w)), $ones),
        );
        $s1 = _mm_add_epi32(
            $s1,
            _mm_madd_epi16(_mm_maddubs_epi16(xq, _mm_load_si128(w.add(1))), $ones),
        );
        $s2 = _mm_add_epi32(
            $s2,
            _mm_madd_epi16(_mm_maddubs_epi16(xq, _mm_load_si128(w.add(2))), $ones),
        );
        $s3 = _mm_add_epi32(
            $s3,
            _mm_madd_epi16(_mm_maddubs_epi16(xq, _mm_load_si128(w.add(3))), $ones),
        );
    }};
}

/// One row of `$groups` groups into the four sums of a 16-wide panel, the whole loop in
/// assembly (legacy SSE encoding, for the Atoms): per group one unaligned load and a test
/// that skips sixteen zero inputs, then per quad and weight vector `pshufd` (the spread
/// quad, also the copy `pmaddubsw` overwrites), `pmaddubsw` with the aligned weights as its
/// memory operand, `pmaddwd` with ones, `paddd`: 64 instructions a group in seven vector
/// registers. Why assembly: on the V5's eight registers the compiler interleaved a group's
/// quads and spilled sums to the stack (about 40 % more instructions a group), and around
/// per-quad `asm!` blocks it set its loop up again after every group it computed (about a
/// dozen instructions a group); here the loop costs five. The same instructions as
/// [`sse_quad`], so the same sums.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
macro_rules! row_asm {
    ($bytes:expr, $vectors:expr, $groups:expr, $ones:expr, [$s0:ident, $s1:ident, $s2:ident, $s3:ident]) => {
        // Inside the caller's `unsafe` block, whose contract gives: `$groups * 16` bytes at
        // `$bytes`, `$groups * 16` vectors at `$vectors` (aligned). Reads only those,
        // writes only the named registers and the flags; no stack. Nothing runs for 0
        // groups.
        if $groups > 0 {
            core::arch::asm!(
            "2:",
            "movdqu {xs}, xmmword ptr [{x}]",
            "pxor {t}, {t}",
            "pcmpeqb {t}, {xs}",
            "pmovmskb {mask:e}, {t}",
            "cmp {mask:e}, 0xffff",
            "je 3f",
            "pshufd {t}, {xs}, 0x00",
            "pmaddubsw {t}, xmmword ptr [{w} + 0]",
            "pmaddwd {t}, {ones}",
            "paddd {s0}, {t}",
            "pshufd {t}, {xs}, 0x00",
            "pmaddubsw {t}, xmmword ptr [{w} + 16]",
            "pmaddwd {t}, {ones}",
            "paddd {s1}, {t}",
            "pshufd {t}, {xs}, 0x00",
            "pmaddubsw {t}, xmmword ptr [{w} + 32]",
            "pmaddwd {t}, {ones}",
            "paddd {s2}, {t}",
            "pshufd {t}, {xs}, 0x00",
            "pmaddubsw {t}, xmmword ptr [{w} + 48]",
            "pmaddwd {t}, {ones}",
            "paddd {s3}, {t}",
            "pshufd {t}, {xs}, 0x55",
            "pmaddubsw {t}, xmmword ptr [{w} + 64]",
            "pmaddwd {t}, {ones}",
            "paddd {s0}, {t}",
            "pshufd {t}, {xs}, 0x55",
            "pmaddubsw {t}, xmmword ptr [{w} + 80]",
            "pmaddwd {t}, {ones}",
            "paddd {s1}, {t}",
            "pshufd {t}, {xs}, 0x55",
            "pmaddubsw {t}, xmmword ptr [{w} + 96]",
            "pmaddwd {t}, {ones}",
            "paddd {s2}, {t}",
            "pshufd {t}, {xs}, 0x55",
            "pmaddubsw {t}, xmmword ptr [{w} + 112]",
            "pmaddwd {t}, {ones}",
            "paddd {s3}, {t}",
            "pshufd {t}, {xs}, 0xaa",
            "pmaddubsw {t}, xmmword ptr [{w} + 128]",
            "pmaddwd {t}, {ones}",
            "paddd {s0}, {t}",
            "pshufd {t}, {xs}, 0xaa",
            "pmaddubsw {t}, xmmword ptr [{w} + 144]",
            "pmaddwd {t}, {ones}",
            "paddd {s1}, {t}",
            "pshufd {t}, {xs}, 0xaa",
            "pmaddubsw {t}, xmmword ptr [{w} + 160]",
            "pmaddwd {t}, {ones}",
            "paddd {s2}, {t}",
            "pshufd {t}, {xs}, 0xaa",
            "pmaddubsw {t}, xmmword ptr [{w} + 176]",
            "pmaddwd {t}, {ones}",
            "paddd {s3}, {t}",
            "pshufd {t}, {xs}, 0xff",
            "pmaddubsw {t}, xmmword ptr [{w} + 192]",
            "pmaddwd {t}, {ones}",
            "paddd {s0}, {t}",
            "pshufd {t}, {xs}, 0xff",
            "pmaddubsw {t}, xmmword ptr [{w} + 208]",
            "pmaddwd {t}, {ones}",
            "paddd {s1}, {t}",
            "pshufd {t}, {xs}, 0xff",
            "pmaddubsw {t}, xmmword ptr [{w} + 224]",
            "pmaddwd {t}, {ones}",
            "paddd {s2}, {t}",
            "pshufd {t}, {xs}, 0xff",
            "pmaddubsw {t}, xmmword ptr [{w} + 240]",
            "pmaddwd {t}, {ones}",
            "paddd {s3}, {t}",
            "3:",
            "add {x}, 16",
            "add {w}, 256",
            "dec {n}",
            "jnz 2b",
            x = inout(reg) $bytes => _,
            w = inout(reg) $vectors => _,
            n = inout(reg) $groups => _,
            mask = out(reg) _,
            xs = out(xmm_reg) _,
            t = out(xmm_reg) _,
            ones = in(xmm_reg) $ones,
            s0 = inout(xmm_reg) $s0,
            s1 = inout(xmm_reg) $s1,
            s2 = inout(xmm_reg) $s2,
            s3 = inout(xmm_reg) $s3,
            options(readonly, nostack),
            )
        }
    };
}

/// The larger of two vectors of four `i32`, with SSE2 only (`pmaxsd` is SSE4.1, which the
/// V5's Atom lacks).
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
#[inline(always)]
fn max_epi32_sse2(a: __m128i, b: __m128i) -> __m128i {
    // SAFETY: SSE2 is part of every x86 target this crate builds for (i686 and x86-64).
    unsafe {
        let greater = _mm_cmpgt_epi32(a, b);
        _mm_or_si128(_mm_and_si128(greater, a), _mm_andnot_si128(greater, b))
    }
}

/// [`largest_portable`] on 128-bit vectors, panels of 16 outputs held in four registers. The
/// inputs are read a group (sixteen bytes) at a time: one load, one test that skips sixteen
/// zero inputs, and `pshufd` to spread each quad over the lanes, which also gives
/// `pmaddubsw` the copy it overwrites; the weights are its aligned memory operand. That is
/// four instructions per sixteen outputs of a quad, with the sums, the input, the ones and
/// one product in seven of the V5's eight registers. Each row's sums then go into the
/// running maxima (in memory on the V5: once per row, not per quad).
///
/// Stamped out twice with the same body: for SSSE3 (the Atoms), and for AVX2 machines'
/// layers of at most 16 outputs, where a 32-wide panel would be half zeros (the same code in
/// VEX encoding).
macro_rules! sse_panels_of_16 {
    ($(#[$doc:meta])* $name:ident, $feature:literal, $row:ident) => {
        $(#[$doc])*
        ///
        /// # Safety
        #[doc = concat!("The CPU must have ", $feature, "; `weights.width()` must be 16.")]
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        #[target_feature(enable = $feature)]
        pub(crate) unsafe fn $name(x: &[u8], weights: &QuadPanels, acc: &mut [i32]) {
            assert_eq!(weights.width, 16);
            let rows = weights.rows_in(x, acc);
            let row = weights.padded_inputs();
            let ones = _mm_set1_epi16(1);
            let groups = row / GROUP;
            for (panel, out) in acc.chunks_mut(16).enumerate() {
                let w = weights.panel(panel);
                assert!(w.as_ptr().cast::<WeightBlock>().is_aligned());
                // A group's weights: four quads of 64 bytes, 16 vectors.
                assert_eq!(w.len(), groups * GROUP * 16);
                let panel_vectors = w.as_ptr().cast::<__m128i>();
                let mut largest = [_mm_set1_epi32(i32::MIN); 4];
                for inputs in x.chunks_exact(row).take(rows) {
                    let (mut s0, mut s1, mut s2, mut s3) = (
                        _mm_setzero_si128(),
                        _mm_setzero_si128(),
                        _mm_setzero_si128(),
                        _mm_setzero_si128(),
                    );
                    // SAFETY: `inputs` is a whole row of `groups * GROUP` bytes and the panel
                    // holds `groups` groups' 16 aligned vectors (asserted above).
                    unsafe {
                        $row!(inputs.as_ptr(), panel_vectors, groups, ones, [s0, s1, s2, s3]);
                    }
                    for (most, sums) in largest.iter_mut().zip([s0, s1, s2, s3]) {
                        *most = max_epi32_sse2(*most, sums);
                    }
                }
                let mut lanes = [0i32; 16];
                let target = lanes.as_mut_ptr().cast::<__m128i>();
                // SAFETY: four stores of four lanes into the 16 of `lanes`.
                unsafe {
                    for (k, most) in largest.into_iter().enumerate() {
                        _mm_storeu_si128(target.add(k), most);
                    }
                }
                out.copy_from_slice(&lanes[..out.len()]);
            }
        }
    };
}

/// One group's four quads with intrinsics ([`sse_quad`]), which the compiler encodes as VEX
/// in an AVX2 function (no copies needed: three-operand forms).
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
macro_rules! group_intrinsics {
    ($xs:expr, $base:expr, $ones:expr, [$s0:ident, $s1:ident, $s2:ident, $s3:ident]) => {{
        let (xs, base) = ($xs, $base);
        sse_quad!(
            _mm_shuffle_epi32::<0x00>(xs),
            base,
            $ones,
            [$s0, $s1, $s2, $s3]
        );
        sse_quad!(
            _mm_shuffle_epi32::<0x55>(xs),
            base.add(4),
            $ones,
            [$s0, $s1, $s2, $s3]
        );
        sse_quad!(
            _mm_shuffle_epi32::<0xaa>(xs),
            base.add(8),
            $ones,
            [$s0, $s1, $s2, $s3]
        );
        sse_quad!(
            _mm_shuffle_epi32::<0xff>(xs),
            base.add(12),
            $ones,
            [$s0, $s1, $s2, $s3]
        );
    }};
}

/// One row into a 16-wide panel's sums with intrinsics ([`group_intrinsics`] per group that
/// is not all zeros): the AVX2 machines' 16-wide layers.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
macro_rules! row_intrinsics {
    ($bytes:expr, $vectors:expr, $groups:expr, $ones:expr, [$s0:ident, $s1:ident, $s2:ident, $s3:ident]) => {{
        let (bytes, vectors) = ($bytes, $vectors);
        for g in 0..$groups {
            let xs = _mm_loadu_si128(bytes.add(g * GROUP).cast::<__m128i>());
            if _mm_movemask_epi8(_mm_cmpeq_epi8(xs, _mm_setzero_si128())) == 0xffff {
                continue;
            }
            group_intrinsics!(xs, vectors.add(g * 16), $ones, [$s0, $s1, $s2, $s3]);
        }
    }};
}

// In assembly on both robots' builds. Callgrind, int8 CNN forward: V5 6.46 M -> 5.57 M,
// V6 4.86 M -> 4.64 M; the host's generic x86-64 build counts a little more with it (5.01 M
// -> 5.14 M) and is not what the robot runs.
sse_panels_of_16!(
    /// [`largest_portable`] with SSSE3 (`pmaddubsw`, `pmaddwd`), panels of 16 outputs.
    largest_ssse3,
    "ssse3",
    row_asm
);
sse_panels_of_16!(
    /// [`largest_ssse3`]'s code on an AVX2 machine (VEX-encoded), for layers of at most 16
    /// outputs.
    largest_avx2_16,
    "avx2",
    row_intrinsics
);

/// [`largest_portable`] with AVX2 (`vpmaddubsw`, `vpmaddwd`): panels of 32 outputs in four
/// registers; a group of sixteen input bytes copied to both 128-bit halves and each quad
/// spread over all lanes with `vpshufd`, so one spread serves 32 outputs' four products.
///
/// # Safety
/// The CPU must have AVX2; `weights.width()` must be 32.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn largest_avx2(x: &[u8], weights: &QuadPanels, acc: &mut [i32]) {
    assert_eq!(weights.width, 32);
    let rows = weights.rows_in(x, acc);
    let row = weights.padded_inputs();
    let ones = _mm256_set1_epi16(1);
    macro_rules! quad {
        ($xq:expr, $w:expr, [$s0:ident, $s1:ident, $s2:ident, $s3:ident]) => {{
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
    for (panel, out) in acc.chunks_mut(32).enumerate() {
        let w = weights.panel(panel);
        let mut largest = [_mm256_set1_epi32(i32::MIN); 4];
        for inputs in x.chunks_exact(row).take(rows) {
            let (mut s0, mut s1, mut s2, mut s3) = (
                _mm256_setzero_si256(),
                _mm256_setzero_si256(),
                _mm256_setzero_si256(),
                _mm256_setzero_si256(),
            );
            for (group, group_weights) in inputs.chunks_exact(GROUP).zip(w.chunks_exact(GROUP * 32))
            {
                // SAFETY: `group` is 16 bytes and `group_weights` 512 (exact chunks), read
                // unaligned.
                unsafe {
                    let xs = _mm_loadu_si128(group.as_ptr().cast::<__m128i>());
                    if _mm_movemask_epi8(_mm_cmpeq_epi8(xs, _mm_setzero_si128())) == 0xffff {
                        continue;
                    }
                    let xs = _mm256_broadcastsi128_si256(xs);
                    let base = group_weights.as_ptr().cast::<__m256i>();
                    quad!(_mm256_shuffle_epi32::<0x00>(xs), base, [s0, s1, s2, s3]);
                    quad!(
                        _mm256_shuffle_epi32::<0x55>(xs),
                        base.add(4),
                        [s0, s1, s2, s3]
                    );
                    quad!(
                        _mm256_shuffle_epi32::<0xaa>(xs),
                        base.add(8),
                        [s0, s1, s2, s3]
                    );
                    quad!(
                        _mm256_shuffle_epi32::<0xff>(xs),
                        base.add(12),
                        [s0, s1, s2, s3]
                    );
                }
            }
            for (most, sums) in largest.iter_mut().zip([s0, s1, s2, s3]) {
                *most = _mm256_max_epi32(*most, sums);
            }
        }
        let mut lanes = [0i32; 32];
        let target = lanes.as_mut_ptr().cast::<__m256i>();
        // SAFETY: four stores of eight lanes into the 32 of `lanes`.
        unsafe {
            for (k, most) in largest.into_iter().enumerate() {
                _mm256_storeu_si256(target.add(k), most);
            }
        }
        out.copy_from_slice(&lanes[..out.len()]);
    }
}

/// Which int8 kernel a plan calls, chosen once at load for the instruction set it was
/// lowered for and checked against this CPU there: AVX2 (panels of 32 outputs, or 16 for
/// layers that narrow) where the float kernels are AVX2 or AVX-512, SSSE3 (16) on the SSSE3
/// and SSE4.2 sets (the V5 and V6 Atoms), the portable one on SSE2 and the portable set. The
/// field is private, so a kernel this CPU lacks cannot be named.
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

    /// The panel width a layer of `outputs` outputs is laid out in for this kernel: 16, or on
    /// AVX2 32 where the layer has more than 16 (a 32-wide panel of a 16-output layer would
    /// be half zeros, so those take the 16-wide code in AVX2's encoding).
    pub(crate) fn width_for(self, outputs: usize) -> usize {
        match self.0 {
            Kind::Avx2 if outputs > 16 => 32,
            _ => 16,
        }
    }

    /// `acc[o] = max over rows r of (W x_r)[o]` in exact integers, `x` holding whole rows of
    /// [`QuadPanels::padded_inputs`] bytes one after the other; `weights` laid out for this
    /// kernel ([`Self::width_for`]). One row is a plain product.
    #[inline]
    pub(crate) fn largest(self, x: &[u8], weights: &QuadPanels, acc: &mut [i32]) {
        assert_eq!(weights.width, self.width_for(weights.outputs));
        match (self.0, weights.width) {
            #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
            // SAFETY: a `Kind::Ssse3` is made only where SSSE3 was detected; width checked.
            (Kind::Ssse3, _) => unsafe { largest_ssse3(x, weights, acc) },
            #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
            // SAFETY: a `Kind::Avx2` is made only where AVX2 was detected; width checked.
            (Kind::Avx2, 32) => unsafe { largest_avx2(x, weights, acc) },
            #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
            // SAFETY: as above; 16 wide.
            (Kind::Avx2, _) => unsafe { largest_avx2_16(x, weights, acc) },
            _ => largest_portable(x, weights, acc),
        }
    }
}

/// The shape of an int8 convolution's input and window: the codes are the zero-bordered map
/// `[padded_h][padded_w][c]` (the border holds the zero point, the integer of 0.0). A window
/// is copied out of the map into a run of [`Self::padded_len`] bytes, kernel row after kernel
/// row, where the weights `[ky][kx][c]` meet it (zero weights after). Rows of at most 8 bytes
/// (the cameras' one-channel 5x5 layers: 5) are copied with one 8-byte load and store each:
/// the extra bytes are overwritten by the next row, the last row's lie inside the run and
/// meet zero weights (a `memcpy` call per 5-byte row was more than the V5's first layer
/// could afford); longer rows with one slice copy each.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Window {
    pub padded_width: usize,
    pub channels: usize,
    pub kernel: [usize; 2],
    pub stride: [usize; 2],
}

/// Rows up to this many bytes are copied 8 bytes at a time.
const SHORT_ROW: usize = 8;

impl Window {
    pub(crate) fn new(
        padded_width: usize,
        channels: usize,
        kernel: [usize; 2],
        stride: [usize; 2],
    ) -> Self {
        Self {
            padded_width,
            channels,
            kernel,
            stride,
        }
    }

    /// The bytes of one kernel row of a window.
    pub(crate) fn row(&self) -> usize {
        self.kernel[1] * self.channels
    }

    /// The bytes a window's copy spans: its rows, and the last short row's 8-byte store.
    fn extent(&self) -> usize {
        let rows = self.kernel[0] * self.row();
        if self.row() <= SHORT_ROW && self.kernel[0] > 0 {
            rows.max((self.kernel[0] - 1) * self.row() + SHORT_ROW)
        } else {
            rows
        }
    }

    /// The weights' inputs and the bytes of one copied window: its extent rounded up to
    /// whole groups of 16.
    pub(crate) fn padded_len(&self) -> usize {
        self.extent().div_ceil(GROUP) * GROUP
    }

    /// How many bytes past the map a bottom-right window's last short row reads (its 8-byte
    /// load): the codes buffer holds them too.
    pub(crate) fn slack(&self) -> usize {
        if self.row() <= SHORT_ROW {
            SHORT_ROW - self.row()
        } else {
            0
        }
    }

    /// `rows`, `[out][ky][kx * c]`, laid out as a copied window is: each output's
    /// [`Self::padded_len`] weights, zero after the window.
    pub(crate) fn weights(&self, rows: &[i8], outputs: usize) -> Vec<i8> {
        let len = self.kernel[0] * self.row();
        let mut laid_out = vec![0; outputs * self.padded_len()];
        for (o, weights) in rows.chunks_exact(len.max(1)).take(outputs).enumerate() {
            laid_out[o * self.padded_len()..][..len].copy_from_slice(weights);
        }
        laid_out
    }

    /// Copies the window of output pixel `(y, x)` out of `codes` into `out`
    /// ([`Self::padded_len`] bytes); the bytes after the window are left as they are (they
    /// meet zero weights). Bounds are checked once per window, not per row (the V5's first
    /// layer copies 24,000 rows a forward).
    #[inline(always)]
    pub(crate) fn gather(&self, codes: &[u8], [y, x]: [usize; 2], out: &mut [u8]) {
        let (row, kh) = (self.row(), self.kernel[0]);
        let pitch = self.padded_width * self.channels;
        let first = ((y * self.stride[0]) * self.padded_width + x * self.stride[1]) * self.channels;
        let out = &mut out[..self.padded_len()];
        if kh == 0 {
            return;
        }
        if row > SHORT_ROW {
            for (ky, target) in out.chunks_exact_mut(row).take(kh).enumerate() {
                target.copy_from_slice(&codes[first + ky * pitch..][..row]);
            }
            return;
        }
        let end = kh
            .checked_sub(1)
            .and_then(|rows| rows.checked_mul(pitch))
            .and_then(|offset| offset.checked_add(first))
            .and_then(|start| start.checked_add(SHORT_ROW));
        assert!(
            end.is_some_and(|end| end <= codes.len()) && (kh - 1) * row + SHORT_ROW <= out.len(),
            "int8 window outside its map"
        );
        for ky in 0..kh {
            // SAFETY: row `ky` reads `codes[first + ky * pitch..][..8]`, inside `codes` as
            // the last row's end is (checked above), and writes `out[ky * row..][..8]`,
            // inside `out` as the last row's is (checked above; `padded_len` covers it).
            unsafe {
                let bytes = codes
                    .as_ptr()
                    .add(first + ky * pitch)
                    .cast::<[u8; SHORT_ROW]>()
                    .read_unaligned();
                out.as_mut_ptr()
                    .add(ky * row)
                    .cast::<[u8; SHORT_ROW]>()
                    .write_unaligned(bytes);
            }
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

    /// Every kernel this CPU runs, on the rows `xs` (each padded to whole groups) and the
    /// weights `rows`: the largest product per output.
    fn every_kernel(
        xs: &[Vec<u8>],
        rows: &[i8],
        outputs: usize,
        inputs: usize,
    ) -> Vec<(&'static str, Vec<i32>)> {
        let padded: Vec<u8> = xs
            .iter()
            .flat_map(|x| {
                let mut x = x.clone();
                x.resize(inputs.div_ceil(GROUP) * GROUP, 0);
                x
            })
            .collect();
        let mut results = Vec::new();
        for width in [4, 8, 16] {
            let weights = QuadPanels::new(rows, outputs, inputs, width).expect("in range");
            let mut acc = vec![0; outputs];
            largest_portable(&padded, &weights, &mut acc);
            results.push(("portable", acc));
        }
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        {
            if std::arch::is_x86_feature_detected!("ssse3") {
                let weights = QuadPanels::new(rows, outputs, inputs, 16).expect("in range");
                let mut acc = vec![0; outputs];
                // SAFETY: SSSE3 detected; width 16.
                unsafe { largest_ssse3(&padded, &weights, &mut acc) };
                results.push(("ssse3", acc));
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                let weights = QuadPanels::new(rows, outputs, inputs, 32).expect("in range");
                let mut acc = vec![0; outputs];
                // SAFETY: AVX2 detected; width 32.
                unsafe { largest_avx2(&padded, &weights, &mut acc) };
                results.push(("avx2", acc));
                let weights = QuadPanels::new(rows, outputs, inputs, 16).expect("in range");
                let mut acc = vec![0; outputs];
                // SAFETY: AVX2 detected; width 16.
                unsafe { largest_avx2_16(&padded, &weights, &mut acc) };
                results.push(("avx2, 16 wide", acc));
            }
        }
        results
    }

    /// The largest of the definition's products over the rows `xs`.
    fn largest_reference(xs: &[Vec<u8>], rows: &[i8], outputs: usize, inputs: usize) -> Vec<i32> {
        let products: Vec<Vec<i32>> = xs
            .iter()
            .map(|x| reference(x, rows, outputs, inputs))
            .collect();
        (0..outputs)
            .map(|o| products.iter().map(|p| p[o]).max().expect("a row"))
            .collect()
    }

    #[test]
    fn every_kernel_equals_the_integer_definition_on_random_layers() {
        let mut rng = Lcg(29);
        // Whole groups of sixteen inputs and groups padded with zero weights; one row (a
        // dense layer) and the four windows of a 2x2 pool.
        let layers = [
            (128, 2560),
            (3, 128),
            (37, 13),
            (16, 4),
            (1, 1),
            (33, 7),
            (20, 30),
            (16, 25),
            (48, 100),
        ];
        for (outputs, inputs) in layers {
            let rows: Vec<i8> = (0..outputs * inputs)
                .map(|_| ((rng.next() % 129) as i16 - 64) as i8)
                .collect();
            for count in [1, 4] {
                // Half the inputs zero, as after ReLU, and every other run of 24 inputs
                // zero, so that skipped groups of 16 are tested too.
                let xs: Vec<Vec<u8>> = (0..count)
                    .map(|_| {
                        (0..inputs)
                            .map(|i| {
                                if rng.next().is_multiple_of(2) || (i / 24) % 2 == 1 {
                                    0
                                } else {
                                    rng.next() as u8
                                }
                            })
                            .collect()
                    })
                    .collect();
                let expected = largest_reference(&xs, &rows, outputs, inputs);
                for (kernel, acc) in every_kernel(&xs, &rows, outputs, inputs) {
                    assert_eq!(
                        acc, expected,
                        "{kernel}, {outputs}x{inputs}, {count} row(s)"
                    );
                }
            }
        }
    }

    #[test]
    fn the_worst_cases_of_pmaddubsw_do_not_saturate() {
        // Every input 255 against every weight at an end of the range: each 16-bit pair sum
        // is then +-32,640, the largest magnitudes the range allows; mixed signs in a row
        // and alternating patterns too. A saturating sum (or a kernel that adds pairs in 16
        // bits) would differ from the definition here. Two rows: the largest of a sum and
        // its negative (all-negative sums must win over nothing).
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
            for xs in [vec![x.clone()], vec![x.clone(), x.clone()]] {
                let expected = largest_reference(&xs, &rows, outputs, inputs);
                for (kernel, acc) in every_kernel(&xs, &rows, outputs, inputs) {
                    assert_eq!(acc, expected, "{kernel}, pattern {p}");
                }
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
    fn a_row_count_the_weights_do_not_divide_is_refused() {
        let weights = QuadPanels::new(&[1; 3 * 20], 3, 20, 16).expect("in range");
        assert_eq!(weights.padded_inputs(), 32);
        let mut acc = [0; 3];
        for x in [vec![0u8; 31], vec![0u8; 33], Vec::new()] {
            let refused = std::panic::catch_unwind(|| {
                largest_portable(&x, &weights, &mut acc.clone());
            });
            assert!(refused.is_err(), "{} bytes", x.len());
        }
        largest_portable(&[1; 64], &weights, &mut acc);
        assert_eq!(acc, [20; 3]);
    }

    #[test]
    fn pooled_windows_of_a_convolution_equal_the_integer_definition() {
        let mut rng = Lcg(5);
        for (ph, pw, c, oc, [kh, kw], stride) in [
            (13, 17, 3, 10, [5, 5], [2, 2]),
            (9, 11, 1, 16, [5, 5], [2, 2]),
            (7, 7, 8, 33, [3, 3], [1, 1]),
            (8, 8, 1, 4, [4, 4], [1, 1]),
        ] {
            let window = Window::new(pw, c, [kh, kw], stride);
            assert!(window.padded_len().is_multiple_of(GROUP));
            // The map's codes, then the slack a last window row reads past it.
            let mut codes: Vec<u8> = (0..ph * pw * c).map(|_| rng.next() as u8).collect();
            codes.extend((0..window.slack()).map(|_| rng.next() as u8));
            let rows: Vec<i8> = (0..oc * kh * kw * c)
                .map(|_| ((rng.next() % 129) as i16 - 64) as i8)
                .collect();
            let laid_out = window.weights(&rows, oc);
            let (oh, ow) = ((ph - kh) / stride[0] + 1, (pw - kw) / stride[1] + 1);
            let definition = |y: usize, x: usize, o: usize| -> i64 {
                let mut sum = 0i64;
                for ky in 0..kh {
                    for kx in 0..kw {
                        for i in 0..c {
                            let pixel = ((y * stride[0] + ky) * pw + x * stride[1] + kx) * c;
                            let w = rows[((o * kh + ky) * kw + kx) * c + i];
                            sum += i64::from(codes[pixel + i]) * i64::from(w);
                        }
                    }
                }
                sum
            };
            for kernel in [
                Int8Kernel::PORTABLE,
                Int8Kernel::ssse3(),
                Int8Kernel::avx2(),
            ] {
                let weights =
                    QuadPanels::new(&laid_out, oc, window.padded_len(), kernel.width_for(oc))
                        .expect("in range");
                let len = window.padded_len();
                // Stale bytes in the scratch must not matter.
                let mut windows = vec![0xa5u8; 4 * len];
                let mut sums = vec![0i32; oc];
                // Each 2x2 cell of pixels (the last row and column alone where odd).
                for (y, x) in (0..oh)
                    .step_by(2)
                    .flat_map(|y| (0..ow).step_by(2).map(move |x| (y, x)))
                {
                    let pixels: Vec<[usize; 2]> = [[y, x], [y, x + 1], [y + 1, x], [y + 1, x + 1]]
                        .into_iter()
                        .filter(|&[py, px]| py < oh && px < ow)
                        .collect();
                    for (i, &pixel) in pixels.iter().enumerate() {
                        window.gather(&codes, pixel, &mut windows[i * len..(i + 1) * len]);
                    }
                    kernel.largest(&windows[..pixels.len() * len], &weights, &mut sums);
                    for (o, &sum) in sums.iter().enumerate() {
                        let expected = pixels
                            .iter()
                            .map(|&[py, px]| definition(py, px, o))
                            .max()
                            .expect("a pixel");
                        assert_eq!(
                            i64::from(sum),
                            expected,
                            "{}, {c} channels: cell ({y}, {x}) output {o}",
                            kernel.name(),
                        );
                    }
                }
            }
        }
    }
}
