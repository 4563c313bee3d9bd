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
//! One call computes, for each of several cells, the largest of its products `W x_r` per
//! output ([`Int8Kernel::largest`]): a dense row is one cell of one `x`; a convolution hands
//! over a whole row of max-pool cells (four windows each for the CNN's 2x2 pools), copied one
//! after the other by [`Window::gather_cells`], so the pool's maximum is taken in vector
//! registers and the call, its checks and the set-up are paid once per row of outputs. On
//! AVX2, layers of at most 16 outputs are laid out in [`QuadPanels::pairs`] and computed two
//! rows at a time, one per 128-bit half; on SSSE3 (both Naos), layers of at most 8 outputs in
//! panels of 8 ([`largest_ssse3_8`]), not half-empty panels of 16.
//!
//! History, measured with callgrind (cross/README.md): one call per pixel with the window
//! read in place (a segment per kernel row) and one quad per broadcast cost 8.07 M
//! instructions per CNN forward on the V5, more than the float engine's 5.95 M.
// The vector kernels are `unsafe`: intrinsics of a `#[target_feature]` the caller checked.
#![allow(unsafe_code)]

use super::super::layout::Grid;
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
/// zero columns. Every quad of a panel of 16 or 32 starts on a 64-byte boundary (of 8, on a
/// 32-byte one; of 4, on a 16-byte one; every panel on a 64-byte one).
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct QuadPanels {
    blocks: Vec<WeightBlock>,
    len: usize,
    inputs: usize,
    outputs: usize,
    width: usize,
    /// [`Self::pairs`]' layout: one 32-wide panel whose 256-bit vectors hold four outputs'
    /// weights twice, for two rows at once.
    pairs: bool,
    /// [`Self::tail_quads`].
    tail_quads: usize,
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
        let mut last_nonzero = None;
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
                if w != 0 {
                    last_nonzero = last_nonzero.max(Some(i));
                }
            }
        }
        // The last group's quads up to the last nonzero weight (at least one).
        let last_group = quads.saturating_sub(4);
        let tail_quads = match last_nonzero {
            Some(i) if i / 4 >= last_group => i / 4 - last_group + 1,
            _ => 1,
        };
        Ok(Self {
            blocks,
            len,
            inputs,
            outputs,
            width,
            pairs: false,
            tail_quads,
        })
    }

    /// At most 16 outputs laid out for [`largest_avx2_pairs`]: one 32-wide panel in which
    /// column `8k + j` holds output `4k + j % 4`, so each 256-bit vector of a quad holds four
    /// outputs' weights in both 128-bit halves, one half per row of a pair.
    pub(crate) fn pairs(
        rows: &[i8],
        outputs: usize,
        inputs: usize,
    ) -> Result<Self, WeightOutOfRange> {
        debug_assert!(outputs <= 16 && rows.len() == outputs * inputs);
        let mut doubled = vec![0i8; 32 * inputs];
        for (column, target) in doubled.chunks_exact_mut(inputs.max(1)).enumerate() {
            let output = 4 * (column / 8) + column % 4;
            if output < outputs {
                target.copy_from_slice(&rows[output * inputs..(output + 1) * inputs]);
            }
        }
        let mut panels = Self::new(&doubled, 32, inputs, 32).map_err(|error| WeightOutOfRange {
            output: 4 * (error.output / 8) + error.output % 4,
            ..error
        })?;
        panels.outputs = outputs;
        panels.pairs = true;
        Ok(panels)
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

    /// How many of the last group's four quads the SSSE3 kernels compute (1 to 4): those up to
    /// the last that holds a nonzero weight of any output. The quads after it add nothing
    /// whatever the inputs: a convolution's window is laid out in whole groups with zero
    /// weights after it (a camera's 5x5 window of one channel is 25 bytes of 32: 3 quads).
    pub(crate) fn tail_quads(&self) -> usize {
        self.tail_quads
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

    /// How many cells `acc` holds (`outputs` sums each) and how many rows of
    /// [`Self::padded_inputs`] bytes `x` holds per cell; panics where `acc` is not whole
    /// cells or `x` not the same whole number of rows for each (checked once per call, so
    /// the loops' reads are in bounds).
    fn cells_in(&self, x: &[u8], acc: &[i32]) -> (usize, usize) {
        let row = self.padded_inputs();
        let cells = acc.len() / self.outputs.max(1);
        assert!(
            row > 0
                && cells > 0
                && acc.len() == cells * self.outputs
                && x.len().is_multiple_of(cells * row)
                && x.len() >= cells * row,
            "int8 product of {} bytes into {} sums against rows of {row}",
            x.len(),
            acc.len()
        );
        (cells, x.len() / (cells * row))
    }
}

/// `acc[o] = max over rows r of (W x_r)[o]` in exact integers, `x` holding the rows one after
/// the other, any CPU: the reference the vector kernels equal. Where `acc` holds several
/// cells of `outputs` sums, `x` holds each cell's rows in turn, the same number for each
/// (one call for a row of max-pool cells or of pixels: the checks and the set-up once).
pub(crate) fn largest_portable(x: &[u8], weights: &QuadPanels, acc: &mut [i32]) {
    assert!(!weights.pairs, "int8 weights laid out for AVX2's pairs");
    let (cells, rows) = weights.cells_in(x, acc);
    let (width, row) = (weights.width, weights.padded_inputs());
    let cell_rows = x
        .chunks_exact(rows * row)
        .zip(acc.chunks_mut(weights.outputs));
    for (x, acc) in cell_rows.take(cells) {
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
}

/// One product of a group in assembly text: `pshufd` spreads quad `$quad` of the group over
/// the lanes (also the copy `pmaddubsw` overwrites), `pmaddubsw` with the aligned weights at
/// `{w} + $offset` as its memory operand, `pmaddwd` with ones, `paddd` into the sum register
/// `$sum`. The panels below are these four instructions per quad and sum register.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
macro_rules! product {
    ($quad:literal, $offset:literal, $sum:literal) => {
        concat!(
            "pshufd {t}, {xs}, ",
            $quad,
            "\n",
            "pmaddubsw {t}, xmmword ptr [{w} + ",
            $offset,
            "]\n",
            "pmaddwd {t}, {ones}\n",
            "paddd {",
            $sum,
            "}, {t}\n",
        )
    };
}

/// The first `$quads` quads (1 to 4) of one group's products for a 16-wide panel, in assembly
/// text ([`product`] per quad and weight vector, into `{s0}`..`{s3}`): 16 instructions a quad,
/// 64 for a whole group, in seven vector registers. Fewer than four only for a row's last
/// group, whose other quads hold nothing but padding ([`row_asm`]).
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
macro_rules! products16 {
    (1) => {
        concat!(
            product!("0x00", "0", "s0"),
            product!("0x00", "16", "s1"),
            product!("0x00", "32", "s2"),
            product!("0x00", "48", "s3"),
        )
    };
    (2) => {
        concat!(
            products16!(1),
            product!("0x55", "64", "s0"),
            product!("0x55", "80", "s1"),
            product!("0x55", "96", "s2"),
            product!("0x55", "112", "s3"),
        )
    };
    (3) => {
        concat!(
            products16!(2),
            product!("0xaa", "128", "s0"),
            product!("0xaa", "144", "s1"),
            product!("0xaa", "160", "s2"),
            product!("0xaa", "176", "s3"),
        )
    };
    (4) => {
        concat!(
            products16!(3),
            product!("0xff", "192", "s0"),
            product!("0xff", "208", "s1"),
            product!("0xff", "224", "s2"),
            product!("0xff", "240", "s3"),
        )
    };
}

/// [`products16`] for a panel of 8 outputs in two registers `{s0}`, `{s1}` (the spread is made
/// twice, as `pmaddubsw` overwrites it): 32 instructions a group where a 16-wide panel of an
/// 8-output layer would spend 64 on half zero weights.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
macro_rules! products8 {
    (1) => {
        concat!(product!("0x00", "0", "s0"), product!("0x00", "16", "s1"))
    };
    (2) => {
        concat!(
            products8!(1),
            product!("0x55", "32", "s0"),
            product!("0x55", "48", "s1")
        )
    };
    (3) => {
        concat!(
            products8!(2),
            product!("0xaa", "64", "s0"),
            product!("0xaa", "80", "s1")
        )
    };
    (4) => {
        concat!(
            products8!(3),
            product!("0xff", "96", "s0"),
            product!("0xff", "112", "s1")
        )
    };
}

/// [`products16`] for a panel of 4 outputs in one register `{s0}`: 16 instructions a group,
/// where an 8-wide panel of a 4-output layer (the bottom camera's first layer in the narrow
/// CNN) spends 32, half on zero weights.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
macro_rules! products4 {
    (1) => {
        product!("0x00", "0", "s0")
    };
    (2) => {
        concat!(products4!(1), product!("0x55", "16", "s0"))
    };
    (3) => {
        concat!(products4!(2), product!("0xaa", "32", "s0"))
    };
    (4) => {
        concat!(products4!(3), product!("0xff", "48", "s0"))
    };
}

/// One row of `$groups` groups into the sums of a panel (`products16` into four registers,
/// `products8` into two, `products4` into one), the whole row in assembly (legacy SSE
/// encoding, for the Atoms): the groups before the last in a loop, per group one unaligned
/// load, with `skip` a test that skips sixteen zero inputs (six instructions that pay only
/// where such groups are common: after ReLU and max-pooling, not in a camera's pixels), then
/// the products; the last group after the loop, without the test and with only its first
/// `$tail` quads (1 to 4): the row's inputs are padded to whole groups with zero weights, so
/// the quads past the inputs add nothing (a 5x5 window of one channel, 25 bytes, spends 3 of
/// the last group's 4). Why assembly: on the V5's eight registers the compiler interleaved a
/// group's quads and spilled sums to the stack (about 40 % more instructions a group), and
/// around per-quad `asm!` blocks it set its loop up again after every group it computed
/// (about a dozen instructions a group); here the loop costs four.
///
/// Inside the caller's `unsafe` block, whose contract gives: `$groups >= 1`, `$groups * 16`
/// bytes at `$bytes`, `$groups * N` aligned vectors at `$vectors`. Reads only those, writes
/// only the named registers and the flags; no stack.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
macro_rules! row_asm {
    (skip, $($rest:tt)*) => {
        row_asm!(@row concat!(
            "pxor {t}, {t}\n",
            "pcmpeqb {t}, {xs}\n",
            "pmovmskb {mask:e}, {t}\n",
            "cmp {mask:e}, 0xffff\n",
            "je 3f\n",
        ), $($rest)*, mask = out(reg) _,)
    };
    (compute, $($rest:tt)*) => {
        row_asm!(@row "", $($rest)*,)
    };
    (@row $test:expr, $products:ident, $tail:tt, $step:literal, $bytes:expr, $vectors:expr,
        $groups:expr, $ones:expr, [$($s:ident),+], $($extra:tt)*) => {
        core::arch::asm!(
            "test {n}, {n}",
            "jz 4f",
            "2:",
            "movdqu {xs}, xmmword ptr [{x}]",
            $test,
            $products!(4),
            "3:",
            "add {x}, 16",
            concat!("add {w}, ", $step),
            "dec {n}",
            "jnz 2b",
            "4:",
            "movdqu {xs}, xmmword ptr [{x}]",
            $products!($tail),
            x = inout(reg) $bytes => _,
            w = inout(reg) $vectors => _,
            n = inout(reg) $groups - 1 => _,
            xs = out(xmm_reg) _,
            t = out(xmm_reg) _,
            ones = in(xmm_reg) $ones,
            $($s = inout(xmm_reg) $s,)+
            $($extra)*
            options(readonly, nostack),
        )
    };
}

/// Each sum register into the running maxima at `$largest` (aligned, one vector per register).
/// `sse2` (the V5's Atom has no SSE4.1 and so no `pmaxsd`): per register a copy, `pcmpgtd`
/// against the maximum in memory, `pand`, `pandn` from memory, `por`, the store: six
/// instructions, where the compiler, keeping four maxima and four sums in the V5's eight
/// registers, moved them through the stack (about 45 instructions a row of a 16-wide panel,
/// callgrind). `sse41` (the V6): `pmaxsd` from memory and the store, two. The sum registers
/// are left holding the maxima.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
macro_rules! merge_largest {
    (@register sse2, $s:literal, $offset:literal) => {
        concat!(
            "movdqa {t}, {", $s, "}\n",
            "pcmpgtd {t}, xmmword ptr [{m} + ", $offset, "]\n",
            "pand {", $s, "}, {t}\n",
            "pandn {t}, xmmword ptr [{m} + ", $offset, "]\n",
            "por {", $s, "}, {t}\n",
            "movdqa xmmword ptr [{m} + ", $offset, "], {", $s, "}\n",
        )
    };
    (@register sse41, $s:literal, $offset:literal) => {
        concat!(
            "pmaxsd {", $s, "}, xmmword ptr [{m} + ", $offset, "]\n",
            "movdqa xmmword ptr [{m} + ", $offset, "], {", $s, "}\n",
        )
    };
    // The block: the maxima's address, SSE2's temporary, the sum registers.
    (@asm sse2, $text:expr, $largest:expr, $($sums:tt)*) => {
        core::arch::asm!($text, m = in(reg) $largest, t = out(xmm_reg) _, $($sums)* options(nostack, preserves_flags))
    };
    (@asm sse41, $text:expr, $largest:expr, $($sums:tt)*) => {
        core::arch::asm!($text, m = in(reg) $largest, $($sums)* options(nostack, preserves_flags))
    };
    ($set:ident, $largest:expr, [$s0:ident]) => {
        merge_largest!(@asm $set, merge_largest!(@register $set, "s0", "0"), $largest,
            s0 = inout(xmm_reg) $s0 => _,)
    };
    ($set:ident, $largest:expr, [$s0:ident, $s1:ident]) => {
        merge_largest!(@asm $set, concat!(
            merge_largest!(@register $set, "s0", "0"),
            merge_largest!(@register $set, "s1", "16"),
        ), $largest, s0 = inout(xmm_reg) $s0 => _, s1 = inout(xmm_reg) $s1 => _,)
    };
    ($set:ident, $largest:expr, [$s0:ident, $s1:ident, $s2:ident, $s3:ident]) => {
        merge_largest!(@asm $set, concat!(
            merge_largest!(@register $set, "s0", "0"),
            merge_largest!(@register $set, "s1", "16"),
            merge_largest!(@register $set, "s2", "32"),
            merge_largest!(@register $set, "s3", "48"),
        ), $largest, s0 = inout(xmm_reg) $s0 => _, s1 = inout(xmm_reg) $s1 => _,
            s2 = inout(xmm_reg) $s2 => _, s3 = inout(xmm_reg) $s3 => _,)
    };
}

/// Gives `store` a place for a panel's `N` sums: `out` itself where it holds exactly `N`, else
/// a scratch array whose first `out.len()` are then copied into `out` (a last, narrower
/// panel). `store` writes at most `N` sums through the pointer.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
#[inline(always)]
fn write_sums<const N: usize>(out: &mut [i32], store: impl FnOnce(*mut i32)) {
    if out.len() == N {
        store(out.as_mut_ptr());
    } else {
        let mut lanes = [0i32; N];
        store(lanes.as_mut_ptr());
        out.copy_from_slice(&lanes[..out.len()]);
    }
}

/// One SSSE3 kernel: `unsafe fn $name::<TAIL, SSE41>(x, weights, acc, zeros)`, panels of
/// `$width` outputs in the sum registers `[$s..]` (`$width / 4` of them), each row's groups by
/// `$products` (`$step` bytes of weights a group) in [`row_asm`], the last group's first
/// `TAIL` quads only (`TAIL` must be [`QuadPanels::tail_quads`]), the row's sums merged into
/// the running maxima ([`merge_largest`]: with `pmaxsd` where `SSE41`), the cells, panels and
/// rows walked by [`ssse3_panels`]; the zero-group test as `zeros` says. The three widths
/// differ only in these arguments; [`largest_ssse3_any`] picks the function for a layout.
/// (The macro is defined on every target, so that its uses resolve; the functions it writes
/// are x86's.)
macro_rules! ssse3_kernel {
    ($(#[$doc:meta])* $name:ident, $products:ident, $step:literal, $width:literal, $registers:literal,
        [$($s:ident),+]) => {
        $(#[$doc])*
        ///
        /// # Safety
        #[doc = concat!("The CPU must have SSSE3, and SSE4.1 where `SSE41`; `weights.width()` must be ", stringify!($width), ".")]
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        #[target_feature(enable = "ssse3")]
        pub(crate) unsafe fn $name<const TAIL: usize, const SSE41: bool>(
            x: &[u8],
            weights: &QuadPanels,
            acc: &mut [i32],
            zeros: ZeroGroups,
        ) {
            assert_eq!(TAIL, weights.tail_quads(), "the last group's quads");
            let ones = _mm_set1_epi16(1);
            // SAFETY (both rows): `ssse3_panels` hands over one whole row of `groups >= 1`
            // groups, the panel's `groups` groups of `$width` aligned vectors and
            // `$registers` aligned maxima; it checks the layout; the quads past `TAIL` in the
            // last group have zero weights (checked above); the caller's contract gives SSSE3
            // and, where `SSE41`, SSE4.1.
            match zeros {
                ZeroGroups::Skip => {
                    let row = ssse3_row!(skip, $products, $step, ones, [$($s),+]);
                    unsafe { ssse3_panels::<$width, $registers>(x, weights, acc, row) }
                }
                ZeroGroups::Compute => {
                    let row = ssse3_row!(compute, $products, $step, ones, [$($s),+]);
                    unsafe { ssse3_panels::<$width, $registers>(x, weights, acc, row) }
                }
            }
        }
    };
}

/// The row closure of an [`ssse3_kernel`]: zeroed sums, the row's groups in [`row_asm`]
/// (`$zeros`: `skip` or `compute`; the last group's first `TAIL` quads), the sums merged into
/// the maxima at `largest` (`SSE41`: with `pmaxsd`). `TAIL` and `SSE41` are the kernel's
/// constants, so each kernel keeps one arm of each choice.
macro_rules! ssse3_row {
    ($zeros:ident, $products:ident, $step:literal, $ones:ident, [$($s:ident),+]) => {
        |inputs: *const u8, vectors: *const __m128i, groups: usize, largest: *mut __m128i| unsafe {
            $(let mut $s = _mm_setzero_si128();)+
            match TAIL {
                1 => row_asm!($zeros, $products, 1, $step, inputs, vectors, groups, $ones, [$($s),+]),
                2 => row_asm!($zeros, $products, 2, $step, inputs, vectors, groups, $ones, [$($s),+]),
                3 => row_asm!($zeros, $products, 3, $step, inputs, vectors, groups, $ones, [$($s),+]),
                _ => row_asm!($zeros, $products, 4, $step, inputs, vectors, groups, $ones, [$($s),+]),
            }
            if SSE41 {
                merge_largest!(sse41, largest, [$($s),+]);
            } else {
                merge_largest!(sse2, largest, [$($s),+]);
            }
        }
    };
}

/// The SSSE3 kernel for `weights`' layout (panels of 4, 8 or 16) and its last group's quads
/// ([`QuadPanels::tail_quads`]), merging with `pmaxsd` where `sse41`.
///
/// # Safety
/// The CPU must have SSSE3, and SSE4.1 where `sse41`.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
pub(crate) unsafe fn largest_ssse3_any(
    x: &[u8],
    weights: &QuadPanels,
    acc: &mut [i32],
    zeros: ZeroGroups,
    sse41: bool,
) {
    macro_rules! tails {
        ($kernel:ident, $sse41:literal) => {
            // SAFETY: the caller's contract; each kernel checks its width and tail.
            match weights.tail_quads() {
                1 => unsafe { $kernel::<1, $sse41>(x, weights, acc, zeros) },
                2 => unsafe { $kernel::<2, $sse41>(x, weights, acc, zeros) },
                3 => unsafe { $kernel::<3, $sse41>(x, weights, acc, zeros) },
                _ => unsafe { $kernel::<4, $sse41>(x, weights, acc, zeros) },
            }
        };
    }
    match (weights.width, sse41) {
        (4, false) => tails!(largest_ssse3_4, false),
        (4, true) => tails!(largest_ssse3_4, true),
        (8, false) => tails!(largest_ssse3_8, false),
        (8, true) => tails!(largest_ssse3_8, true),
        (_, false) => tails!(largest_ssse3, false),
        (_, true) => tails!(largest_ssse3, true),
    }
}

ssse3_kernel!(
    /// [`largest_portable`] with SSSE3 (`pmaddubsw`, `pmaddwd`) on 128-bit vectors, panels of
    /// 16 outputs held in four registers. The inputs are read a group (sixteen bytes) at a
    /// time: one load, with [`ZeroGroups::Skip`] one test that skips sixteen zero inputs, and
    /// `pshufd` to spread each quad over the lanes, which also gives `pmaddubsw` the copy it
    /// overwrites; the weights are its aligned memory operand. That is four instructions per
    /// sixteen outputs of a quad, with the sums, the input, the ones and one product in seven
    /// of the V5's eight registers. Each row's sums then go into the running maxima in memory
    /// ([`merge_largest`]). The row loop is in assembly ([`row_asm`]; callgrind, int8 CNN
    /// forward: V5 6.46 M -> 5.57 M, V6 4.86 M -> 4.64 M).
    largest_ssse3, products16, "256", 16, 4, [s0, s1, s2, s3]
);

ssse3_kernel!(
    /// [`largest_ssse3`] for layers of at most 8 outputs: one panel of 8 in two registers
    /// ([`products8`]).
    largest_ssse3_8, products8, "128", 8, 2, [s0, s1]
);

ssse3_kernel!(
    /// [`largest_ssse3`] for layers of at most 4 outputs: one panel of 4 in one register
    /// ([`products4`]).
    largest_ssse3_4, products4, "64", 4, 1, [s0]
);

/// The cell, panel and row loops of the SSSE3 kernels: for each cell of `acc` and each panel
/// of `N` outputs (`R = N / 4` registers), `row_sums(inputs, vectors, groups, largest)` sums
/// one row of the cell's inputs against the panel's weights (its loop in assembly) and
/// merges the sums into the `R` running maxima at `largest` (aligned). The layout and the
/// sizes are checked once per call, and the loops walk pointers: with slices and iterators
/// the compiler worked out each cell's chunks again, a division included (about 75
/// instructions a cell of the V5's 8-wide kernel, callgrind).
///
/// # Safety
/// `row_sums` may read `groups * GROUP` bytes at `inputs`, `groups * N` aligned vectors at
/// `vectors` and `R` aligned vectors at `largest`, and write the latter, and no more; this
/// function checks the layout (`N` wide, aligned, whole groups) and hands it only such rows,
/// panels and maxima.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
#[inline(always)]
unsafe fn ssse3_panels<const N: usize, const R: usize>(
    x: &[u8],
    weights: &QuadPanels,
    acc: &mut [i32],
    row_sums: impl Fn(*const u8, *const __m128i, usize, *mut __m128i),
) {
    assert!(weights.width == N && R * 4 == N && !weights.pairs);
    let (cells, rows) = weights.cells_in(x, acc);
    let row = weights.padded_inputs();
    let groups = row / GROUP;
    assert!(groups > 0);
    let outputs = weights.outputs;
    let panels = outputs.div_ceil(N);
    // A panel: `groups` groups of `N` vectors of 16 bytes; whole panels, the first aligned
    // (so every one is: a panel is a multiple of 128 bytes).
    let panel_len = groups * GROUP * N;
    let values = weights.values();
    assert!(
        values.len() == panels * panel_len
            && values.as_ptr().cast::<WeightBlock>().is_aligned()
            && panel_len.is_multiple_of(16)
    );
    for cell in 0..cells {
        // SAFETY: `cells_in` checked that `x` holds `cells * rows` rows of `row` bytes.
        let cell_x = unsafe { x.as_ptr().add(cell * rows * row) };
        let cell_acc = &mut acc[cell * outputs..(cell + 1) * outputs];
        for panel in 0..panels {
            // SAFETY: panel `panel` of the `panels` checked above.
            let vectors = unsafe { values.as_ptr().add(panel * panel_len).cast::<__m128i>() };
            // SAFETY: SSE2 is part of every x86 target this crate builds for (i686, x86-64).
            let mut largest = [unsafe { _mm_set1_epi32(i32::MIN) }; R];
            for r in 0..rows {
                // SAFETY: row `r` of the cell, the panel, the maxima: `row_sums`' contract.
                unsafe { row_sums(cell_x.add(r * row), vectors, groups, largest.as_mut_ptr()) };
            }
            let out = &mut cell_acc[panel * N..((panel + 1) * N).min(outputs)];
            write_sums::<N>(out, |target| {
                // SAFETY: `R` stores of four lanes into the `N` `i32` at `target`.
                unsafe {
                    for (k, most) in largest.iter().enumerate() {
                        _mm_storeu_si128(target.cast::<__m128i>().add(k), *most);
                    }
                }
            });
        }
    }
}

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

/// [`largest_portable`] with AVX2 (`vpmaddubsw`, `vpmaddwd`): panels of 32 outputs in four
/// registers; a group of sixteen input bytes copied to both 128-bit halves and each quad
/// spread over all lanes with `vpshufd`, so one spread serves 32 outputs' four products.
///
/// # Safety
/// The CPU must have AVX2; `weights.width()` must be 32.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn largest_avx2(
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

/// [`largest_portable`] with AVX2 for layers of at most 16 outputs ([`QuadPanels::pairs`]):
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
pub(crate) unsafe fn largest_avx2_pairs(
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

/// Whether a kernel tests each group of sixteen inputs and skips the groups that are all
/// zero with their weights. The same sums either way; the test costs a few instructions a
/// group and pays where whole groups of zeros are common (after ReLU and max-pooling, and in
/// a dense layer's features, about 40 % zeros), not in a camera's pixels, where it almost
/// never skips (callgrind, V5, narrow int8 CNN on the test pattern: none of the 12,000
/// first-layer groups a tick).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum ZeroGroups {
    Skip,
    Compute,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Int8Kernel(Kind);

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Portable,
    Ssse3,
    /// The SSSE3 kernels with SSE4.1's `pmaxsd` for the maxima (the V6).
    Sse41,
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

    /// The SSSE3 kernels with SSE4.1's `pmaxsd` where this CPU has SSE4.1, else
    /// [`Self::ssse3`].
    pub(crate) fn sse41() -> Self {
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        if std::arch::is_x86_feature_detected!("ssse3")
            && std::arch::is_x86_feature_detected!("sse4.1")
        {
            return Self(Kind::Sse41);
        }
        Self::ssse3()
    }

    /// AVX2's kernel where this CPU has AVX2, else the widest it has.
    pub(crate) fn avx2() -> Self {
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        if std::arch::is_x86_feature_detected!("avx2") {
            return Self(Kind::Avx2);
        }
        Self::sse41()
    }

    pub(crate) fn name(self) -> &'static str {
        match self.0 {
            Kind::Portable => "portable",
            Kind::Ssse3 => "ssse3",
            Kind::Sse41 => "sse4.1",
            Kind::Avx2 => "avx2",
        }
    }

    /// `rows`, `[out][in]`, laid out for this kernel: panels of 16 outputs, or on AVX2
    /// panels of 32 where the layer has more than 16 outputs and [`QuadPanels::pairs`]
    /// where it has at most 16 (a 32-wide panel of a 16-output layer would be half zeros),
    /// and on SSSE3 one panel of 8 where it has at most 8 (of 4 where at most 4).
    pub(crate) fn lay_out(
        self,
        rows: &[i8],
        outputs: usize,
        inputs: usize,
    ) -> Result<QuadPanels, WeightOutOfRange> {
        match self.0 {
            Kind::Avx2 if outputs > 16 => QuadPanels::new(rows, outputs, inputs, 32),
            Kind::Avx2 => QuadPanels::pairs(rows, outputs, inputs),
            Kind::Ssse3 | Kind::Sse41 if outputs <= 4 => QuadPanels::new(rows, outputs, inputs, 4),
            Kind::Ssse3 | Kind::Sse41 if outputs <= 8 => QuadPanels::new(rows, outputs, inputs, 8),
            _ => QuadPanels::new(rows, outputs, inputs, 16),
        }
    }

    /// `acc[o] = max over rows r of (W x_r)[o]` in exact integers for each cell of `acc`,
    /// `x` holding each cell's whole rows of [`QuadPanels::padded_inputs`] bytes one after
    /// the other ([`largest_portable`]); `weights` laid out for this kernel
    /// ([`Self::lay_out`]; each kernel checks its layout). One row is a plain product.
    #[inline]
    pub(crate) fn largest(
        self,
        x: &[u8],
        weights: &QuadPanels,
        acc: &mut [i32],
        zeros: ZeroGroups,
    ) {
        match self.0 {
            #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
            // SAFETY: a `Kind::Ssse3` is made only where SSSE3 was detected, a `Kind::Sse41`
            // only where SSE4.1 was too; each kernel checks its layout.
            Kind::Ssse3 | Kind::Sse41 => unsafe {
                largest_ssse3_any(x, weights, acc, zeros, self.0 == Kind::Sse41)
            },
            #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
            // SAFETY: a `Kind::Avx2` is made only where AVX2 was detected; layout checked.
            Kind::Avx2 if weights.pairs => unsafe { largest_avx2_pairs(x, weights, acc, zeros) },
            #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
            // SAFETY: as above; 32 wide.
            Kind::Avx2 => unsafe { largest_avx2(x, weights, acc, zeros) },
            _ => largest_portable(x, weights, acc),
        }
    }
}

/// `QuantizeLinear` of a run of floats: `codes[i] = grid.code(values[i])` for the first
/// `min(len)` of each, sixteen at a time with SSE2 on x86 (both Naos): `mulps` by the
/// inverse scale, `maxps`/`minps` to +-512 (`maxps` answers its second operand for a NaN, as
/// [`Grid::code`]'s `max` does), `cvtps2dq` (rounds half to even in the default mode, as the
/// scalar code's 1.5 x 2^23 does), the zero point added in 32 bits, then `packssdw` and
/// `packuswb`, whose saturation is the clamp to 0..=255. The compiler left the scalar loop
/// at about seven instructions a code (callgrind, host AVX2, int8 CNN forward: 0.34 M of
/// its 2.1 M for 46,000 codes); here about two. Equal to the scalar code bit for bit (a
/// test holds it to it on the edge cases).
#[inline(always)]
pub(crate) fn code_run(grid: Grid, values: &[f32], codes: &mut [u8]) {
    let n = values.len().min(codes.len());
    #[allow(unused_mut)]
    let mut done = 0;
    #[cfg(all(
        any(target_arch = "x86", target_arch = "x86_64"),
        target_feature = "sse2"
    ))]
    // SAFETY: SSE2 is enabled for this build (the cfg); every load reads 16 floats at `done`
    // and every store writes 16 bytes at `done`, with `done + 16 <= n`, inside both slices.
    unsafe {
        let inverse = _mm_set1_ps(grid.inverse());
        let (low, high) = (_mm_set1_ps(-512.0), _mm_set1_ps(512.0));
        let zero = _mm_set1_epi32(i32::from(grid.zero()));
        let code = |at: *const f32| {
            let steps = _mm_min_ps(_mm_max_ps(_mm_mul_ps(_mm_loadu_ps(at), inverse), low), high);
            _mm_add_epi32(_mm_cvtps_epi32(steps), zero)
        };
        while done + 16 <= n {
            let at = values.as_ptr().add(done);
            let low_words = _mm_packs_epi32(code(at), code(at.add(4)));
            let high_words = _mm_packs_epi32(code(at.add(8)), code(at.add(12)));
            let bytes = _mm_packus_epi16(low_words, high_words);
            _mm_storeu_si128(codes.as_mut_ptr().add(done).cast::<__m128i>(), bytes);
            done += 16;
        }
    }
    for (code, &value) in codes[done..n].iter_mut().zip(&values[done..n]) {
        *code = grid.code(value);
    }
}

/// The shape of an int8 convolution's input and window: the codes are the zero-bordered map
/// `[padded_h][padded_w][c]` (the border holds the zero point, the integer of 0.0). A window
/// is copied out of the map into a run of [`Self::padded_len`] bytes, kernel row after kernel
/// row, where the weights `[ky][kx][c]` meet it (zero weights after). Rows of at most 8 bytes
/// (the cameras' one-channel 5x5 layers: 5) are copied with one 8-byte load and store each,
/// longer rows with 16-byte loads and stores (the narrow CNN's 20- and 40-byte rows: two and
/// three): the extra bytes are overwritten by the next row, the last row's lie inside the run
/// and meet zero weights, and the map's buffer holds the bytes the bottom-right window's last
/// row reads past the map ([`Self::slack`]). A `memcpy` call per row was more than the V5
/// could afford: about 50 instructions a 40-byte row with the call, 10 for its three moves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Window {
    pub padded_width: usize,
    pub channels: usize,
    pub kernel: [usize; 2],
    pub stride: [usize; 2],
    /// [`Self::padded_len`], worked out once.
    len: usize,
}

/// Rows up to this many bytes are copied 8 bytes at a time.
const SHORT_ROW: usize = 8;
/// Longer rows are copied this many bytes at a time.
const CHUNK: usize = 16;

impl Window {
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
            len: 0,
        };
        window.len = window.extent().div_ceil(GROUP) * GROUP;
        window
    }

    /// The bytes of one kernel row of a window.
    pub(crate) fn row(&self) -> usize {
        self.kernel[1] * self.channels
    }

    /// The bytes one row's copy moves: 8 for a short row, else the row rounded up to whole
    /// 16-byte chunks.
    fn copied(&self) -> usize {
        let row = self.row();
        if row <= SHORT_ROW {
            SHORT_ROW
        } else {
            row.div_ceil(CHUNK) * CHUNK
        }
    }

    /// The bytes a window's copy spans: its rows, the last one's copy whole.
    fn extent(&self) -> usize {
        match self.kernel[0] {
            0 => 0,
            kh => (kh - 1) * self.row() + self.copied(),
        }
    }

    /// The weights' inputs and the bytes of one copied window: its extent rounded up to
    /// whole groups of 16.
    pub(crate) fn padded_len(&self) -> usize {
        self.len
    }

    /// How many bytes past the map a bottom-right window's last row reads (its last load
    /// whole): the codes buffer holds them too.
    pub(crate) fn slack(&self) -> usize {
        self.copied() - self.row()
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

    /// Copies the windows of the `rows x columns` output pixels from `(y, x)` on (a max-pool
    /// cell's), row by row, into `out`, one after the other, each [`Self::padded_len`]
    /// bytes: one block of [`Self::gather_cells`].
    #[cfg(test)]
    pub(crate) fn gather_block(
        &self,
        codes: &[u8],
        pixel: [usize; 2],
        block: [usize; 2],
        out: &mut [u8],
    ) {
        self.gather_cells(codes, pixel, block, [1, 1], out);
    }

    /// Copies the windows of `cells` blocks of `rows x columns` output pixels, the first
    /// from pixel `(y, x)` on, each next one `step` pixels to the right (a row of max-pool
    /// cells, or with 1 x 1 blocks a row of pixels), into `out`: block by block, each block
    /// row by row, each window [`Self::padded_len`] bytes. Bounds are checked and the
    /// offsets worked out once per call, not per window or row (the V5's first layer copies
    /// 24,000 rows a forward; callgrind, host AVX2, int8 CNN forward: a check and the
    /// offsets per window cost 0.3 to 0.5 M instructions).
    #[inline(always)]
    pub(crate) fn gather_cells(
        &self,
        codes: &[u8],
        [y, x]: [usize; 2],
        [rows, columns]: [usize; 2],
        [cells, step]: [usize; 2],
        out: &mut [u8],
    ) {
        let (row, kh, len, c) = (self.row(), self.kernel[0], self.len, self.channels);
        if kh == 0 || rows == 0 || columns == 0 || cells == 0 {
            return;
        }
        let pitch = self.padded_width * c;
        // The last block's last window's last row ends furthest into `codes` (its last load
        // whole).
        let copied = self.copied();
        let end = (y + rows - 1)
            .checked_mul(self.stride[0])
            .and_then(|top| top.checked_add(kh - 1))
            .and_then(|bottom| bottom.checked_mul(self.padded_width))
            .and_then(|offset| {
                let last = (cells - 1)
                    .checked_mul(step)?
                    .checked_add(x + columns - 1)?;
                offset.checked_add(last.checked_mul(self.stride[1])?)
            })
            .and_then(|pixel| pixel.checked_mul(c))
            .and_then(|first| first.checked_add(copied));
        let windows = cells.checked_mul(rows * columns);
        assert!(
            end.is_some_and(|end| end <= codes.len())
                && windows.is_some_and(|n| n.checked_mul(len).is_some_and(|n| n <= out.len()))
                && (kh - 1) * row + copied <= len,
            "int8 window outside its map"
        );
        // Byte offsets: of the first window, from block to block, from window row to window
        // row and window to window inside a block.
        let first = ((y * self.stride[0]) * self.padded_width + x * self.stride[1]) * c;
        let (block_step, window_down, window_right) = (
            step * self.stride[1] * c,
            self.stride[0] * pitch,
            self.stride[1] * c,
        );
        let (source, target) = (codes.as_ptr(), out.as_mut_ptr());
        // Window `k` of the call (block by block, each row by row) and where it starts.
        let windows = (0..cells).flat_map(|cell| {
            (0..rows).flat_map(move |dy| {
                (0..columns)
                    .map(move |dx| first + cell * block_step + dy * window_down + dx * window_right)
            })
        });
        // SAFETY (every copy below): row `ky` of each window reads `copied` bytes from
        // `start + ky * pitch`, at most the last window's last row's end, inside `codes`
        // (checked above), and writes them `ky * row` bytes into the window's `len` bytes
        // of `out`, the windows one after the other (all inside `out`, checked above).
        if row > SHORT_ROW {
            // Whole 16-byte chunks; the rows of the CNNs' second layers, specialised.
            let rows = (windows, kh, [pitch, row, len], (source, target));
            // SAFETY: the checks above (`long_rows`' contract).
            unsafe {
                match copied / CHUNK {
                    2 => long_rows(rows, |from, to| copy_chunks::<2>(from, to)),
                    3 => long_rows(rows, |from, to| copy_chunks::<3>(from, to)),
                    chunks => long_rows(rows, |from, to| {
                        for k in 0..chunks {
                            copy_chunks::<1>(from.add(k * CHUNK), to.add(k * CHUNK));
                        }
                    }),
                }
            }
            return;
        }
        if kh == 5 {
            // The CNNs' 5 x 5 kernels, unrolled: five loads and five stores a window, the
            // pointers stepped, not multiplied out again for each window from the iterator's
            // indices (about 30 instructions a window on the V5 that way, callgrind), and the
            // cameras' one-channel rows (5 bytes, windows of 32) with constant offsets: the
            // V5's eight registers then hold the loop (22 instructions a window with the row
            // and the window's length in registers too, 19 without; callgrind).
            macro_rules! five_rows {
                ($row:expr, $len:expr) => {{
                    let (row, len, three) = ($row, $len, 3 * pitch);
                    let mut to = target;
                    for cell in 0..cells {
                        for dy in 0..rows {
                            let mut from =
                                unsafe { source.add(first + cell * block_step + dy * window_down) };
                            for _ in 0..columns {
                                unsafe {
                                    copy_short(from, to);
                                    copy_short(from.add(pitch), to.add(row));
                                    copy_short(from.add(2 * pitch), to.add(2 * row));
                                    copy_short(from.add(three), to.add(3 * row));
                                    copy_short(from.add(three + pitch), to.add(4 * row));
                                    from = from.add(window_right);
                                    to = to.add(len);
                                }
                            }
                        }
                    }
                }};
            }
            if row == 5 && len == 32 {
                five_rows!(5, 32);
            } else {
                five_rows!(row, len);
            }
        } else {
            // SAFETY: the checks above (`long_rows`' contract).
            unsafe {
                long_rows(
                    (windows, kh, [pitch, row, len], (source, target)),
                    |from, to| copy_short(from, to),
                )
            };
        }
    }
}

/// Each window's `kh` rows through `copy_row(from, to)`: from `pitch` bytes apart in the map
/// to `row` bytes apart in the window's `len`, the windows' starts in the map from `windows`.
///
/// # Safety
/// Inside [`Window::gather_cells`], whose checks bound every row `copy_row` is given, and
/// `copy_row` may read and write that row's copy (its `copied` bytes) and no more.
#[inline(always)]
unsafe fn long_rows(
    (windows, kh, [pitch, row, len], (source, target)): (
        impl Iterator<Item = usize>,
        usize,
        [usize; 3],
        (*const u8, *mut u8),
    ),
    copy_row: impl Fn(*const u8, *mut u8),
) {
    for (k, start) in windows.enumerate() {
        for ky in 0..kh {
            // SAFETY: the caller's checks (the window's row `ky`).
            let (from, to) = unsafe {
                (
                    source.add(start + ky * pitch),
                    target.add(k * len + ky * row),
                )
            };
            copy_row(from, to);
        }
    }
}

/// Copies `N` 16-byte chunks from `from` to `to` (unaligned).
///
/// # Safety
/// `16 * N` bytes readable at `from` and writable at `to`.
#[inline(always)]
unsafe fn copy_chunks<const N: usize>(from: *const u8, to: *mut u8) {
    for k in 0..N {
        // SAFETY: the caller's contract; SSE2 is part of every x86 target this crate builds
        // for (i686, x86-64).
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        unsafe {
            _mm_storeu_si128(
                to.add(k * CHUNK).cast::<__m128i>(),
                _mm_loadu_si128(from.add(k * CHUNK).cast::<__m128i>()),
            );
        }
        #[cfg(not(any(target_arch = "x86", target_arch = "x86_64")))]
        unsafe {
            to.add(k * CHUNK)
                .cast::<[u8; CHUNK]>()
                .write_unaligned(from.add(k * CHUNK).cast::<[u8; CHUNK]>().read_unaligned());
        }
    }
}

/// Copies one short row's 8 bytes from `from` to `to` (unaligned). On i686 through an SSE2
/// register (`movq`, a load and a store): as `[u8; 8]` the compiler moved the 8 bytes in two
/// 32-bit halves, four instructions a row (the V5's first layers copy 30,000 short rows a
/// tick; callgrind).
///
/// # Safety
/// 8 bytes readable at `from` and writable at `to`.
#[inline(always)]
unsafe fn copy_short(from: *const u8, to: *mut u8) {
    // SAFETY: the caller's contract; SSE2 as above.
    #[cfg(target_arch = "x86")]
    unsafe {
        _mm_storel_epi64(
            to.cast::<__m128i>(),
            _mm_loadl_epi64(from.cast::<__m128i>()),
        );
    }
    #[cfg(not(target_arch = "x86"))]
    unsafe {
        to.cast::<[u8; SHORT_ROW]>()
            .write_unaligned(from.cast::<[u8; SHORT_ROW]>().read_unaligned());
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
    /// weights `rows`: the largest product per output. Each vector kernel runs with and
    /// without the zero-group test, and in one call over two cells: `xs`, then the same rows
    /// with every byte `b` as `255 - b` ([`flipped`]), so its result is two cells' sums.
    fn every_kernel(
        xs: &[Vec<u8>],
        rows: &[i8],
        outputs: usize,
        inputs: usize,
    ) -> Vec<(String, Vec<i32>)> {
        let pad = |xs: &[Vec<u8>]| -> Vec<u8> {
            xs.iter()
                .flat_map(|x| {
                    let mut x = x.clone();
                    x.resize(inputs.div_ceil(GROUP) * GROUP, 0);
                    x
                })
                .collect()
        };
        let padded = pad(xs);
        let mut results = Vec::new();
        for width in [4, 8, 16] {
            let weights = QuadPanels::new(rows, outputs, inputs, width).expect("in range");
            let mut acc = vec![0; outputs];
            largest_portable(&padded, &weights, &mut acc);
            let mut second = vec![0; outputs];
            largest_portable(&pad(&flipped(xs)), &weights, &mut second);
            acc.extend(second);
            results.push((format!("portable {width}"), acc));
        }
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        {
            let two_cells = [padded.clone(), pad(&flipped(xs))].concat();
            for zeros in [ZeroGroups::Skip, ZeroGroups::Compute] {
                // Panels of 16, of 8 (as for layers of at most 8 outputs; wider ones in
                // pieces) and of 4 (at most 4), each maximum with SSE2 and with SSE4.1.
                for sse41 in [false, true] {
                    if !std::arch::is_x86_feature_detected!("ssse3")
                        || (sse41 && !std::arch::is_x86_feature_detected!("sse4.1"))
                    {
                        continue;
                    }
                    for width in [16, 8, 4] {
                        let weights =
                            QuadPanels::new(rows, outputs, inputs, width).expect("in range");
                        let mut acc = vec![0; 2 * outputs];
                        // SAFETY: SSSE3 detected, and SSE4.1 where `sse41`.
                        unsafe { largest_ssse3_any(&two_cells, &weights, &mut acc, zeros, sse41) };
                        let set = if sse41 { "sse4.1" } else { "ssse3" };
                        results.push((format!("{set}, panels of {width}, {zeros:?}"), acc));
                    }
                }
                if std::arch::is_x86_feature_detected!("avx2") {
                    let weights = QuadPanels::new(rows, outputs, inputs, 32).expect("in range");
                    let mut acc = vec![0; 2 * outputs];
                    // SAFETY: AVX2 detected; width 32.
                    unsafe { largest_avx2(&two_cells, &weights, &mut acc, zeros) };
                    results.push((format!("avx2, {zeros:?}"), acc));
                    // Two rows at a time: the layout for at most 16 outputs, in pieces of 16.
                    let mut acc = Vec::new();
                    for x in [&padded, &pad(&flipped(xs))] {
                        let mut cell = vec![0; outputs];
                        for (piece, out) in cell.chunks_mut(16).enumerate() {
                            let columns = out.len();
                            let piece_rows: Vec<i8> =
                                rows[piece * 16 * inputs..][..columns * inputs].to_vec();
                            let weights =
                                QuadPanels::pairs(&piece_rows, columns, inputs).expect("in range");
                            // SAFETY: AVX2 detected; laid out in pairs.
                            unsafe { largest_avx2_pairs(x, &weights, out, zeros) };
                        }
                        acc.extend(cell);
                    }
                    results.push((format!("avx2, pairs of rows, {zeros:?}"), acc));
                }
            }
        }
        results
    }

    /// `xs` with every byte `b` as `255 - b`: the second cell of [`every_kernel`].
    fn flipped(xs: &[Vec<u8>]) -> Vec<Vec<u8>> {
        xs.iter()
            .map(|x| x.iter().map(|&b| 255 - b).collect())
            .collect()
    }

    /// [`largest_reference`] of `xs` and of [`flipped`] `xs`, one after the other: what
    /// [`every_kernel`]'s two cells give.
    fn two_cells_reference(xs: &[Vec<u8>], rows: &[i8], outputs: usize, inputs: usize) -> Vec<i32> {
        let mut expected = largest_reference(xs, rows, outputs, inputs);
        expected.extend(largest_reference(&flipped(xs), rows, outputs, inputs));
        expected
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
            for count in [1, 3, 4] {
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
                let expected = two_cells_reference(&xs, &rows, outputs, inputs);
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
    fn the_last_group_is_computed_up_to_its_last_nonzero_weight() {
        // A camera's 5x5 window of one channel (25 bytes: 3 of the last group's 4 quads), of
        // four and of eight channels (100: 1; 200: 2), whole groups (4) and the small cases.
        for (inputs, tail) in [
            (25, 3),
            (100, 1),
            (200, 2),
            (1280, 4),
            (16, 4),
            (17, 1),
            (1, 1),
            (4, 1),
            (5, 2),
            (13, 4),
            (0, 1),
        ] {
            let weights = QuadPanels::new(&vec![1; 3 * inputs], 3, inputs, 4).expect("in range");
            assert_eq!(weights.tail_quads(), tail, "{inputs} inputs");
        }
        // A window laid out in whole groups: zero weights after its 25 bytes (quads 4..6 of
        // the last group hold them), but another output's last nonzero weight may come later.
        for (last, tail) in [(24, 3), (27, 3), (28, 4), (31, 4), (16, 3), (3, 3)] {
            let mut rows = vec![0i8; 3 * 32];
            rows[..25].fill(5);
            rows[64 + last] = -1;
            let weights = QuadPanels::new(&rows, 3, 32, 8).expect("in range");
            assert_eq!(weights.tail_quads(), tail, "last nonzero {last}");
        }
        // Nothing but zeros in the last group: one quad of it is computed.
        let mut rows = vec![0i8; 2 * 32];
        rows[..16].fill(-7);
        assert_eq!(
            QuadPanels::new(&rows, 2, 32, 4)
                .expect("in range")
                .tail_quads(),
            1
        );
    }

    #[test]
    fn coding_a_run_equals_coding_each_value() {
        // Halves (rounded to even), the ends of the range and past them, the clamp at +-512
        // steps, infinities, NaN, negative zero; runs of every length around 16.
        let mut rng = Lcg(17);
        for (scale, zero) in [(0.02f32, 0u8), (0.013, 128), (1.0 / 255.0, 3), (7.5, 255)] {
            let grid = Grid::new(scale, zero).expect("a grid");
            let mut values: Vec<f32> = Vec::new();
            for k in -600..600 {
                values.push((k as f32 + 0.5) * scale);
                values.push(k as f32 * scale);
            }
            values.extend([
                f32::NAN,
                -f32::NAN,
                f32::INFINITY,
                f32::NEG_INFINITY,
                -0.0,
                f32::MAX,
                f32::MIN,
                f32::MIN_POSITIVE,
            ]);
            values.extend(
                (0..200).map(|_| (rng.next() as f32 / 2f32.powi(31) - 0.5) * 600.0 * scale),
            );
            for start in 0..3 {
                for len in [0, 1, 15, 16, 17, 31, 32, 33, values.len() - start] {
                    let run = &values[start..start + len];
                    let mut codes = vec![0xeeu8; len];
                    code_run(grid, run, &mut codes);
                    let expected: Vec<u8> = run.iter().map(|&v| grid.code(v)).collect();
                    assert_eq!(
                        codes, expected,
                        "scale {scale}, zero {zero}, {len} from {start}"
                    );
                }
            }
        }
    }

    #[test]
    fn several_cells_in_one_call_equal_one_call_each() {
        // A row of max-pool cells (or of pixels) goes to the kernel in one call: each cell's
        // outputs must be those of the cell alone, for every layout and row count.
        let mut rng = Lcg(41);
        for (outputs, inputs) in [(16, 32), (8, 25), (4, 25), (32, 400), (37, 13)] {
            let rows: Vec<i8> = (0..outputs * inputs)
                .map(|_| ((rng.next() % 129) as i16 - 64) as i8)
                .collect();
            for (cells, per_cell) in [(1, 1), (5, 1), (7, 4), (3, 3)] {
                for kernel in [
                    Int8Kernel::PORTABLE,
                    Int8Kernel::ssse3(),
                    Int8Kernel::sse41(),
                    Int8Kernel::avx2(),
                ] {
                    let weights = kernel.lay_out(&rows, outputs, inputs).expect("in range");
                    let row = weights.padded_inputs();
                    let x: Vec<u8> = (0..cells * per_cell * row)
                        .map(|i| {
                            if i % row < inputs {
                                rng.next() as u8
                            } else {
                                0
                            }
                        })
                        .collect();
                    let mut together = vec![0i32; cells * outputs];
                    // One call without the zero-group test, each cell alone with it.
                    kernel.largest(&x, &weights, &mut together, ZeroGroups::Compute);
                    for cell in 0..cells {
                        let mut alone = vec![0i32; outputs];
                        let part = &x[cell * per_cell * row..(cell + 1) * per_cell * row];
                        kernel.largest(part, &weights, &mut alone, ZeroGroups::Skip);
                        assert_eq!(
                            together[cell * outputs..(cell + 1) * outputs],
                            alone,
                            "{}, {outputs}x{inputs}, cell {cell} of {cells}, {per_cell} row(s)",
                            kernel.name()
                        );
                        let xs: Vec<Vec<u8>> = part
                            .chunks_exact(row)
                            .map(|r| r[..inputs].to_vec())
                            .collect();
                        assert_eq!(alone, largest_reference(&xs, &rows, outputs, inputs));
                    }
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
                let expected = two_cells_reference(&xs, &rows, outputs, inputs);
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
        // Laid out in pairs of rows, the error names the real output too.
        assert_eq!(
            QuadPanels::pairs(&rows, 8, 5),
            Err(WeightOutOfRange {
                output: 3,
                input: 2,
                value: -65
            })
        );
        rows[3 * 5 + 2] = 127;
        assert!(QuadPanels::new(&rows, 8, 5, 8).is_err());
        assert!(QuadPanels::pairs(&rows, 8, 5).is_err());
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
            // The narrow CNN's second layers: rows of 40 and 20 bytes (three and two
            // 16-byte chunks), and a row of 72 (five chunks, the general loop).
            (11, 13, 8, 16, [5, 5], [2, 2]),
            (9, 9, 4, 8, [5, 5], [2, 2]),
            (7, 9, 24, 6, [3, 3], [1, 1]),
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
            // A row of pixels as one block: the same bytes as window by window.
            let len = window.padded_len();
            for y in 0..oh {
                let mut block = vec![0x5au8; ow * len];
                window.gather_block(&codes, [y, 0], [1, ow], &mut block);
                let mut one_by_one = vec![0x5au8; ow * len];
                for x in 0..ow {
                    let slot = &mut one_by_one[x * len..(x + 1) * len];
                    window.gather_block(&codes, [y, x], [1, 1], slot);
                }
                assert_eq!(block, one_by_one, "row {y}");
            }
            // A row of whole 2x2 cells as one call: the same bytes as cell by cell.
            for y in (0..oh.saturating_sub(1)).step_by(2) {
                let cells = ow / 2;
                let mut row_of_cells = vec![0x3cu8; cells * 4 * len];
                window.gather_cells(&codes, [y, 0], [2, 2], [cells, 2], &mut row_of_cells);
                let mut cell_by_cell = vec![0x3cu8; cells * 4 * len];
                for cell in 0..cells {
                    let slot = &mut cell_by_cell[cell * 4 * len..(cell + 1) * 4 * len];
                    window.gather_block(&codes, [y, 2 * cell], [2, 2], slot);
                }
                assert_eq!(row_of_cells, cell_by_cell, "cells of row {y}");
            }
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
                Int8Kernel::sse41(),
                Int8Kernel::avx2(),
            ] {
                let weights = kernel
                    .lay_out(&laid_out, oc, window.padded_len())
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
                        let slot = &mut windows[i * len..(i + 1) * len];
                        window.gather_block(&codes, pixel, [1, 1], slot);
                    }
                    if pixels.len() == 4 {
                        // The cell as one block: the same bytes as window by window.
                        let mut block = vec![0xa5u8; 4 * len];
                        window.gather_block(&codes, [y, x], [2, 2], &mut block);
                        assert_eq!(block, windows[..4 * len], "cell ({y}, {x})");
                    }
                    kernel.largest(
                        &windows[..pixels.len() * len],
                        &weights,
                        &mut sums,
                        ZeroGroups::Skip,
                    );
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
