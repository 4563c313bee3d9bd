//! The int8 weights laid out for the kernels: panels of output columns, quads of inputs.
// The vector kernels are `unsafe`: intrinsics of a `#[target_feature]` the caller checked.
#![allow(unsafe_code)]

use super::{GROUP, MAX_WEIGHT, WeightOutOfRange};

/// 64 bytes of weights on a 64-byte boundary: one quad of a 16-wide panel, half of a 32-wide
/// one. Aligned so that the SSSE3 kernel's `pmaddubsw` reads its weights as a memory operand
/// (a legacy-encoded SSE instruction takes only aligned ones), which leaves the V5's eight
/// vector registers to the sums.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(C, align(64))]
pub(super) struct WeightBlock([i8; 64]);

/// Int8 weights `[panel][quad][width][4]`; inputs are taken in whole groups of sixteen, the
/// last one padded with zero weights, and outputs in panels of `width`, the last padded with
/// zero columns. Every quad of a panel of 16 or 32 starts on a 64-byte boundary (of 8, on a
/// 32-byte one; of 4, on a 16-byte one; every panel on a 64-byte one).
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct QuadPanels {
    pub(super) blocks: Vec<WeightBlock>,
    pub(super) len: usize,
    pub(super) inputs: usize,
    pub(super) outputs: usize,
    pub(super) width: usize,
    /// [`Self::pairs`]' layout: one 32-wide panel whose 256-bit vectors hold four outputs'
    /// weights twice, for two rows at once.
    pub(super) pairs: bool,
    /// [`Self::tail_quads`].
    pub(super) tail_quads: usize,
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

    /// At most 16 outputs laid out for [`u8s8_max_product_2x16c_avx2`]: one 32-wide panel in which
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
    pub(super) fn values(&self) -> &[i8] {
        // SAFETY: `WeightBlock` is 64 `i8` with no padding (`repr(C)`, size 64), so the
        // blocks are `64 * blocks.len()` initialised bytes, of which `len` are used.
        unsafe { std::slice::from_raw_parts(self.blocks.as_ptr().cast::<i8>(), self.len) }
    }

    pub(super) fn panel(&self, panel: usize) -> &[i8] {
        let size = self.padded_inputs() * self.width;
        &self.values()[panel * size..(panel + 1) * size]
    }

    /// How many cells `acc` holds (`outputs` sums each) and how many rows of
    /// [`Self::padded_inputs`] bytes `x` holds per cell; panics where `acc` is not whole
    /// cells or `x` not the same whole number of rows for each (checked once per call, so
    /// the loops' reads are in bounds).
    pub(super) fn cells_in(&self, x: &[u8], acc: &[i32]) -> (usize, usize) {
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

/// Gives `store` a place for a panel's `N` sums: `out` itself where it holds exactly `N`, else
/// a scratch array whose first `out.len()` are then copied into `out` (a last, narrower
/// panel). `store` writes at most `N` sums through the pointer.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
#[inline(always)]
pub(super) fn write_sums<const N: usize>(out: &mut [i32], store: impl FnOnce(*mut i32)) {
    if out.len() == N {
        store(out.as_mut_ptr());
    } else {
        let mut lanes = [0i32; N];
        store(lanes.as_mut_ptr());
        out.copy_from_slice(&lanes[..out.len()]);
    }
}
