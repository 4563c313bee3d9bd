//! The static execution plan: steps over buffers that were all allocated at load, and the
//! loop that runs them. Running a plan allocates nothing: a step borrows its output buffer
//! out of the list (`mem::take` leaves an empty `Vec`, which costs no allocation), computes
//! from the others, and puts it back.

use core::mem;

use super::kernels::{self, ConvShape, MulAdd};
use super::winograd;

/// The two hot kernels, as an instruction set provides them.
pub(crate) trait Kernels {
    /// Output rows `first_row..` of a convolution, as many as `out` holds.
    fn conv(
        shape: &ConvShape,
        padded: &[f32],
        weights: &[f32],
        bias: &[f32],
        relu: bool,
        first_row: usize,
        out: &mut [f32],
    );
    /// `y = bias + W x`; `nonzero` is scratch for the indices of `x`'s non-zero values.
    fn dense(x: &[f32], weights: &DenseWeights, bias: &[f32], y: &mut [f32], nonzero: &mut [u32]);

    /// A convolution and its pool by [`winograd`] into the pooled map `out`, where the set
    /// has the kernels for the layer's channels; false, having written nothing, where not.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)] // one layer
    fn winograd_conv_pool(
        _layer: &winograd::Layer,
        _padded: &[f32],
        _weights: &[f32],
        _bias: &[f32],
        _relu: bool,
        _transformed: &mut [f32],
        _products: &mut [f32],
        _out: &mut [f32],
    ) -> bool {
        false
    }

    /// Max pooling of an NHWC map (see [`kernels::max_pool_nhwc`]).
    #[inline(always)]
    fn max_pool(
        input: &[f32],
        size: [usize; 3],
        kernel: [usize; 2],
        stride: [usize; 2],
        out_size: [usize; 2],
        out: &mut [f32],
    ) {
        kernels::max_pool_nhwc(input, size, kernel, stride, out_size, out);
    }
}

/// The generic kernels, left to the compiler to vectorise (the portable path).
#[derive(Debug)]
pub(crate) struct Generic<M>(core::marker::PhantomData<M>);

impl<M: MulAdd> Kernels for Generic<M> {
    #[inline(always)]
    fn conv(
        shape: &ConvShape,
        padded: &[f32],
        weights: &[f32],
        bias: &[f32],
        relu: bool,
        first_row: usize,
        out: &mut [f32],
    ) {
        let row = first_row;
        match shape.out_channels {
            8 => kernels::conv::<M, 8, 8>(shape, padded, weights, bias, relu, row, out),
            16 => kernels::conv::<M, 16, 4>(shape, padded, weights, bias, relu, row, out),
            32 => kernels::conv::<M, 32, 2>(shape, padded, weights, bias, relu, row, out),
            _ => kernels::conv_any::<M>(shape, padded, weights, bias, relu, row, out),
        }
    }

    #[inline(always)]
    fn dense(x: &[f32], weights: &DenseWeights, bias: &[f32], y: &mut [f32], nonzero: &mut [u32]) {
        kernels::dense::<M>(x, weights, bias, y, nonzero);
    }
}

/// SSE vectors (the Nao V5's and V6's sets): four channels per register.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
#[derive(Debug)]
pub(crate) struct SseKernels;

#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
impl Kernels for SseKernels {
    #[inline(always)]
    fn conv(
        shape: &ConvShape,
        padded: &[f32],
        weights: &[f32],
        bias: &[f32],
        relu: bool,
        first_row: usize,
        out: &mut [f32],
    ) {
        use super::simd::{Sse, conv_rows};
        let (ic, row) = (shape.in_channels, first_row);
        // Accumulators, weight vectors and broadcast inputs in registers: sixteen on x86-64,
        // eight on the 32-bit build. Measured with callgrind (`cross/count`): one group of all
        // 32 channels beats two groups of 16 on both, as the inputs are then read once.
        // The first layer (one input channel) gets its inner loop unrolled.
        #[cfg(target_arch = "x86_64")]
        let done = match (shape.out_channels, ic, shape.kernel[1]) {
            (8, 1, 5) => conv_rows::<Sse, 2, 5, 1, 5>(shape, padded, weights, bias, relu, row, out),
            (8, _, _) => conv_rows::<Sse, 2, 5, 0, 0>(shape, padded, weights, bias, relu, row, out),
            (16, 1, 5) => {
                conv_rows::<Sse, 4, 2, 1, 5>(shape, padded, weights, bias, relu, row, out)
            }
            (16, 8, 5) => {
                conv_rows::<Sse, 4, 2, 8, 5>(shape, padded, weights, bias, relu, row, out)
            }
            (32, 16, 5) => {
                conv_rows::<Sse, 8, 1, 16, 5>(shape, padded, weights, bias, relu, row, out)
            }
            _ => conv_rows::<Sse, 4, 2, 0, 0>(shape, padded, weights, bias, relu, row, out),
        };
        // The kernel's width is left to a loop: its taps unrolled, the compiler interleaves
        // them and spills the eight registers (callgrind, fixture CNN: 7.57 M instructions
        // per forward with the width unrolled, 7.31 M with one input channel's loop rolled).
        #[cfg(target_arch = "x86")]
        let done = match (shape.out_channels, ic) {
            (8, 1) => conv_rows::<Sse, 2, 2, 1, 0>(shape, padded, weights, bias, relu, row, out),
            (8, _) => conv_rows::<Sse, 2, 2, 0, 0>(shape, padded, weights, bias, relu, row, out),
            (16, 1) => conv_rows::<Sse, 4, 1, 1, 0>(shape, padded, weights, bias, relu, row, out),
            (16, 8) => conv_rows::<Sse, 4, 1, 8, 0>(shape, padded, weights, bias, relu, row, out),
            (32, 16) => conv_rows::<Sse, 4, 1, 16, 0>(shape, padded, weights, bias, relu, row, out),
            _ => conv_rows::<Sse, 4, 1, 0, 0>(shape, padded, weights, bias, relu, row, out),
        };
        if !done {
            Generic::<kernels::Separate>::conv(shape, padded, weights, bias, relu, row, out);
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn winograd_conv_pool(
        layer: &winograd::Layer,
        padded: &[f32],
        weights: &[f32],
        bias: &[f32],
        relu: bool,
        transformed: &mut [f32],
        products: &mut [f32],
        out: &mut [f32],
    ) -> bool {
        use super::simd::Sse;
        // One tile by every output channel: each broadcast input (a shuffle, on the pipes
        // that the multiplies and adds use) feeds eight or four multiplies, where five tiles
        // by two vectors fed two (`profile`, SSE: the top camera's second layer 186 -> 146
        // µs, the bottom camera's 13.9 -> 12.3 µs; two tiles by four vectors: 172 µs).
        macro_rules! blocked {
            ($tiles:literal, $vecs:literal) => {
                winograd::conv_pool::<Sse, $tiles, $vecs>(
                    layer,
                    padded,
                    weights,
                    bias,
                    relu,
                    transformed,
                    products,
                    out,
                )
            };
        }
        if layer.out_channels.is_multiple_of(32) {
            blocked!(1, 8)
        } else if layer.out_channels.is_multiple_of(16) {
            blocked!(1, 4)
        } else {
            blocked!(5, 2)
        }
    }

    #[inline(always)]
    fn dense(x: &[f32], weights: &DenseWeights, bias: &[f32], y: &mut [f32], nonzero: &mut [u32]) {
        use super::simd::{Sse, dense};
        let done = match weights.width() {
            8 => dense::<Sse, 2>(x, weights, bias, y, nonzero),
            16 => dense::<Sse, 4>(x, weights, bias, y, nonzero),
            32 => dense::<Sse, 8>(x, weights, bias, y, nonzero),
            _ => false,
        };
        if !done {
            Generic::<kernels::Separate>::dense(x, weights, bias, y, nonzero);
        }
    }

    #[inline(always)]
    fn max_pool(
        input: &[f32],
        size: [usize; 3],
        kernel: [usize; 2],
        stride: [usize; 2],
        out_size: [usize; 2],
        out: &mut [f32],
    ) {
        super::simd::max_pool::<super::simd::Sse>(input, size, kernel, stride, out_size, out);
    }
}

/// AVX2 vectors with FMA: eight channels per register.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
#[derive(Debug)]
pub(crate) struct AvxKernels;

#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
impl Kernels for AvxKernels {
    #[inline(always)]
    fn conv(
        shape: &ConvShape,
        padded: &[f32],
        weights: &[f32],
        bias: &[f32],
        relu: bool,
        first_row: usize,
        out: &mut [f32],
    ) {
        use super::simd::{Avx, conv_rows};
        let (ic, kw, row) = (shape.in_channels, shape.kernel[1], first_row);
        // Sixteen registers: up to twelve accumulators, the weight vectors and the broadcast
        // input. The first layer of the bottom camera (8 channels, 40 pixels a row) takes
        // blocks of ten, which tile its rows, where twelve recomputed a fifth of them
        // (`CompiledNetwork::profile`: 9.7 µs, half the peak, with twelve).
        let done = match (shape.out_channels, ic, kw) {
            (8, 1, 5) => {
                conv_rows::<Avx, 1, 10, 1, 5>(shape, padded, weights, bias, relu, row, out)
            }
            (8, _, _) => {
                conv_rows::<Avx, 1, 12, 0, 0>(shape, padded, weights, bias, relu, row, out)
            }
            (16, 1, 5) => {
                conv_rows::<Avx, 2, 5, 1, 5>(shape, padded, weights, bias, relu, row, out)
            }
            (16, 8, 5) => {
                conv_rows::<Avx, 2, 5, 8, 5>(shape, padded, weights, bias, relu, row, out)
            }
            (32, 16, 5) => {
                conv_rows::<Avx, 2, 5, 16, 5>(shape, padded, weights, bias, relu, row, out)
            }
            _ => conv_rows::<Avx, 2, 5, 0, 0>(shape, padded, weights, bias, relu, row, out),
        };
        if !done {
            Generic::<kernels::Fused>::conv(shape, padded, weights, bias, relu, row, out);
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn winograd_conv_pool(
        layer: &winograd::Layer,
        padded: &[f32],
        weights: &[f32],
        bias: &[f32],
        relu: bool,
        transformed: &mut [f32],
        products: &mut [f32],
        out: &mut [f32],
    ) -> bool {
        winograd::conv_pool::<super::simd::Avx, 5, 2>(
            layer,
            padded,
            weights,
            bias,
            relu,
            transformed,
            products,
            out,
        )
    }

    #[inline(always)]
    fn dense(x: &[f32], weights: &DenseWeights, bias: &[f32], y: &mut [f32], nonzero: &mut [u32]) {
        use super::simd::{Avx, dense};
        let done = match weights.width() {
            8 => dense::<Avx, 1>(x, weights, bias, y, nonzero),
            16 => dense::<Avx, 2>(x, weights, bias, y, nonzero),
            32 => dense::<Avx, 4>(x, weights, bias, y, nonzero),
            64 => dense::<Avx, 8>(x, weights, bias, y, nonzero),
            _ => false,
        };
        if !done {
            Generic::<kernels::Fused>::dense(x, weights, bias, y, nonzero);
        }
    }

    #[inline(always)]
    fn max_pool(
        input: &[f32],
        size: [usize; 3],
        kernel: [usize; 2],
        stride: [usize; 2],
        out_size: [usize; 2],
        out: &mut [f32],
    ) {
        super::simd::max_pool::<super::simd::Avx>(input, size, kernel, stride, out_size, out);
    }
}

/// AVX-512 vectors with FMA: sixteen channels per register, thirty-two registers. Layers
/// whose channels are not a whole number of sixteen take the AVX2 kernels, which run here
/// too.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
#[derive(Debug)]
pub(crate) struct Avx512Kernels;

#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
impl Kernels for Avx512Kernels {
    #[inline(always)]
    fn conv(
        shape: &ConvShape,
        padded: &[f32],
        weights: &[f32],
        bias: &[f32],
        relu: bool,
        first_row: usize,
        out: &mut [f32],
    ) {
        use super::simd::{Avx512, conv_rows};
        let (ic, kw, row) = (shape.in_channels, shape.kernel[1], first_row);
        // Thirty-two registers: up to twenty accumulators (ten pixels of 32 channels, or
        // twenty of 16), the weight vectors and the broadcast input. Blocks of ten and twenty
        // pixels tile the paper's widths (80, 40, 20, 10).
        let done = match (shape.out_channels, ic, kw) {
            (16, 1, 5) => {
                conv_rows::<Avx512, 1, 20, 1, 5>(shape, padded, weights, bias, relu, row, out)
            }
            (16, 8, 5) => {
                conv_rows::<Avx512, 1, 10, 8, 5>(shape, padded, weights, bias, relu, row, out)
            }
            (32, 16, 5) => {
                conv_rows::<Avx512, 2, 10, 16, 5>(shape, padded, weights, bias, relu, row, out)
            }
            (oc, _, _) if oc.is_multiple_of(32) => {
                conv_rows::<Avx512, 2, 10, 0, 0>(shape, padded, weights, bias, relu, row, out)
            }
            (oc, _, _) if oc.is_multiple_of(16) => {
                conv_rows::<Avx512, 1, 10, 0, 0>(shape, padded, weights, bias, relu, row, out)
            }
            _ => false,
        };
        if !done {
            AvxKernels::conv(shape, padded, weights, bias, relu, row, out);
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn winograd_conv_pool(
        layer: &winograd::Layer,
        padded: &[f32],
        weights: &[f32],
        bias: &[f32],
        relu: bool,
        transformed: &mut [f32],
        products: &mut [f32],
        out: &mut [f32],
    ) -> bool {
        winograd::conv_pool::<super::simd::Avx512, 5, 2>(
            layer,
            padded,
            weights,
            bias,
            relu,
            transformed,
            products,
            out,
        ) || AvxKernels::winograd_conv_pool(
            layer,
            padded,
            weights,
            bias,
            relu,
            transformed,
            products,
            out,
        )
    }

    #[inline(always)]
    fn dense(x: &[f32], weights: &DenseWeights, bias: &[f32], y: &mut [f32], nonzero: &mut [u32]) {
        use super::simd::{Avx512, dense};
        let done = match weights.width() {
            16 => dense::<Avx512, 1>(x, weights, bias, y, nonzero),
            32 => dense::<Avx512, 2>(x, weights, bias, y, nonzero),
            64 => dense::<Avx512, 4>(x, weights, bias, y, nonzero),
            _ => false,
        };
        if !done {
            AvxKernels::dense(x, weights, bias, y, nonzero);
        }
    }

    #[inline(always)]
    fn max_pool(
        input: &[f32],
        size: [usize; 3],
        kernel: [usize; 2],
        stride: [usize; 2],
        out_size: [usize; 2],
        out: &mut [f32],
    ) {
        if size[2].is_multiple_of(16) {
            super::simd::max_pool::<super::simd::Avx512>(
                input, size, kernel, stride, out_size, out,
            );
        } else {
            AvxKernels::max_pool(input, size, kernel, stride, out_size, out);
        }
    }
}

pub(crate) type BufferId = usize;

/// Weights whose first value sits on a 64-byte boundary. The vector kernels then read them
/// with aligned loads, which SSE folds into its `mulps` as a memory operand (an unaligned
/// one it cannot): no register is spent holding a weight vector, which on the V5's eight
/// registers is what made the compiler spill accumulators to the stack.
///
/// Safe code: the values start at the first aligned index of an over-allocated `Vec`, and a
/// `Vec`'s heap buffer stays where it is when the `Vec` moves.
#[derive(Clone, PartialEq)]
pub(crate) struct AlignedWeights {
    /// The values, with `SLACK` spare floats around them.
    storage: Vec<f32>,
    start: usize,
}

impl AlignedWeights {
    /// The boundary, in bytes: an AVX-512 register's width (and a cache line).
    pub(crate) const ALIGN: usize = 64;
    const SLACK: usize = Self::ALIGN / size_of::<f32>();

    pub(crate) fn new(values: &[f32]) -> Self {
        let mut storage = vec![0.0; values.len() + Self::SLACK];
        // Below SLACK for a 4-byte-aligned buffer; should it ever say "cannot", the values
        // start at 0 and the vector kernels, which check, leave the work to the generic ones.
        let start = match storage.as_ptr().align_offset(Self::ALIGN) {
            offset if offset < Self::SLACK => offset,
            _ => 0,
        };
        storage[start..start + values.len()].copy_from_slice(values);
        Self { storage, start }
    }

    pub(crate) fn as_slice(&self) -> &[f32] {
        let len = self.storage.len() - Self::SLACK;
        &self.storage[self.start..self.start + len]
    }
}

impl core::fmt::Debug for AlignedWeights {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        self.as_slice().fmt(f)
    }
}

/// A dense layer's weights in column panels, `[panel][input][width]`: `width` outputs per
/// panel (a multiple of eight, the last panel padded with zero columns). The kernel keeps a
/// panel's outputs in vector registers and walks the inputs once per panel, reading its
/// weights as one contiguous stream; an input that is zero (most features after ReLU and
/// max-pool are) is skipped together with its row of weights. The `[out][in]` layout needed
/// every weight of the 2560x128 layer on every step, 1.3 MB, more than the Atoms' L2.
#[derive(Clone, PartialEq)]
pub(crate) struct DenseWeights {
    panels: AlignedWeights,
    inputs: usize,
    outputs: usize,
    width: usize,
}

impl DenseWeights {
    /// From `rows` laid out `[out][in]` (`outputs` rows of `inputs`), `width` columns a
    /// panel, at most `max_width` and no wider than the outputs need (rounded up to eight).
    pub(crate) fn from_rows(rows: &[f32], outputs: usize, inputs: usize, max_width: usize) -> Self {
        let mut width = 8;
        while width < max_width && width < outputs {
            width *= 2;
        }
        let panels = outputs.div_ceil(width);
        let mut values = vec![0.0; panels * inputs * width];
        for (o, row) in rows.chunks_exact(inputs).take(outputs).enumerate() {
            let (panel, column) = (o / width, o % width);
            for (i, &w) in row.iter().enumerate() {
                values[(panel * inputs + i) * width + column] = w;
            }
        }
        Self {
            panels: AlignedWeights::new(&values),
            inputs,
            outputs,
            width,
        }
    }

    /// `[panel][input][width]`.
    pub(crate) fn panels(&self) -> &[f32] {
        self.panels.as_slice()
    }

    pub(crate) fn inputs(&self) -> usize {
        self.inputs
    }

    pub(crate) fn outputs(&self) -> usize {
        self.outputs
    }

    /// Outputs per panel: 8, 16, 32 or 64.
    pub(crate) fn width(&self) -> usize {
        self.width
    }
}

impl core::fmt::Debug for DenseWeights {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "DenseWeights {{ {} -> {}, panels of {} }}",
            self.inputs, self.outputs, self.width
        )
    }
}

/// A max-pool folded into the convolution before it: the convolution's rows under one row
/// of pooling windows (`kernel[0]` of them) are computed into `scratch` and pooled at once,
/// so the full-size map is never written out. Only for windows that do not overlap
/// vertically (`stride[0] >= kernel[0]`), so that each convolution row is computed once.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct ConvPool {
    pub kernel: [usize; 2],
    pub stride: [usize; 2],
    /// The pooled map's height and width.
    pub out: [usize; 2],
    /// `kernel[0]` rows of the convolution's output.
    pub scratch: BufferId,
}

/// A convolution and its pool as [`winograd`] computes them: the transformed weights and the
/// scratch of one row of tiles.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct WinogradConv {
    pub layer: winograd::Layer,
    pub weights: AlignedWeights,
    /// `[tile][point][4 * in]`
    pub transformed: BufferId,
    /// `[tile][point][out]`
    pub products: BufferId,
}

/// The highest rank the element-wise steps index.
pub(crate) const MAX_RANK: usize = 6;

/// Walks a tensor of `shape` in row-major order and gives, for each element, an offset
/// under other `strides` (a broadcast operand, a transposed source, a reduction target).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Strided {
    rank: usize,
    shape: [usize; MAX_RANK],
    strides: [usize; MAX_RANK],
}

impl Strided {
    /// `shape` and `strides` of equal length, at most [`MAX_RANK`] (checked when lowering).
    pub(crate) fn new(shape: &[usize], strides: &[usize]) -> Self {
        let rank = shape.len().min(MAX_RANK);
        let mut s = Self {
            rank,
            shape: [1; MAX_RANK],
            strides: [0; MAX_RANK],
        };
        s.shape[..rank].copy_from_slice(&shape[..rank]);
        s.strides[..rank].copy_from_slice(&strides[..rank]);
        s
    }

    fn len(&self) -> usize {
        self.shape[..self.rank].iter().product()
    }

    /// Calls `visit(element, offset)` for every element in row-major order.
    #[inline(always)]
    fn for_each(&self, mut visit: impl FnMut(usize, usize)) {
        let mut index = [0usize; MAX_RANK];
        let mut offset = 0;
        for element in 0..self.len() {
            visit(element, offset);
            for d in (0..self.rank).rev() {
                index[d] += 1;
                offset += self.strides[d];
                if index[d] < self.shape[d] {
                    break;
                }
                offset -= self.strides[d] * self.shape[d];
                index[d] = 0;
            }
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum BinaryOp {
    Add,
    Sub,
    Mul,
    Div,
    /// 1.0 where equal, else 0.0.
    Equal,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum ReduceOp {
    Max,
    Sum,
}

/// One step of a plan. Weights live in the step, laid out for its kernel.
#[derive(Debug)]
pub(crate) enum Step {
    /// Copies a `[h][w][c]` map (or a `[c][h][w]` one, `from_nchw`) into the interior of a
    /// zero-bordered NHWC buffer at `origin` (top and left padding); the border stays zero.
    Pad {
        from: BufferId,
        to: BufferId,
        size: [usize; 3],
        origin: [usize; 2],
        padded_width: usize,
        from_nchw: bool,
    },
    /// A convolution, with its ReLU and the max-pool after it where the graph has them.
    Conv {
        padded: BufferId,
        weights: AlignedWeights,
        bias: Vec<f32>,
        shape: ConvShape,
        relu: bool,
        /// When set, `out` holds the pooled map and the full-size one never exists.
        pool: Option<ConvPool>,
        /// With a pool, the same layer with fewer multiplications, where the kernels take it.
        winograd: Option<WinogradConv>,
        out: BufferId,
    },
    MaxPool {
        from: BufferId,
        to: BufferId,
        size: [usize; 3],
        kernel: [usize; 2],
        stride: [usize; 2],
        out: [usize; 2],
    },
    NhwcToNchw {
        from: BufferId,
        to: BufferId,
        size: [usize; 3],
    },
    /// `rows` rows of `from` times `weights` plus `bias`.
    Dense {
        from: BufferId,
        weights: DenseWeights,
        bias: Vec<f32>,
        rows: usize,
        relu: bool,
        to: BufferId,
    },
    /// One LSTM step: `[x, h_in]` into `joined`, one dense layer into `gates`, then the
    /// cell update from `c_in` into `c_out` and `h_out`.
    Lstm {
        x: BufferId,
        h_in: BufferId,
        c_in: BufferId,
        joined: BufferId,
        weights: DenseWeights,
        bias: Vec<f32>,
        gates: BufferId,
        h_out: BufferId,
        c_out: BufferId,
    },
    Copy {
        from: BufferId,
        from_offset: usize,
        to: BufferId,
        to_offset: usize,
        len: usize,
    },
    /// `to[i] = from[source offset of i]`: a transpose.
    Gather {
        from: BufferId,
        source: Strided,
        to: BufferId,
    },
    Relu {
        from: BufferId,
        to: BufferId,
        len: usize,
    },
    Binary {
        op: BinaryOp,
        a: BufferId,
        a_index: Strided,
        b: BufferId,
        b_index: Strided,
        to: BufferId,
    },
    /// Element `i` of `from` goes into `to[target offset of i]`.
    Reduce {
        op: ReduceOp,
        from: BufferId,
        target: Strided,
        to: BufferId,
    },
}

impl Step {
    /// The multiply-adds one run of this step computes: a convolution's output pixels (the
    /// rows a folded pool reads) times its window, a dense layer's or an LSTM gate layer's
    /// weights (zero inputs counted too: they are skipped at run time, as many as there are).
    pub(crate) fn multiply_adds(&self) -> u64 {
        let count = match self {
            Self::Conv {
                winograd: Some(winograd),
                ..
            } => winograd.layer.multiply_adds(),
            Self::Conv { shape, pool, .. } => {
                let [oh, ow] = shape.out;
                let rows = pool.map_or(oh, |pool| pool.out[0] * pool.kernel[0]);
                rows * ow
                    * shape.kernel[0]
                    * shape.kernel[1]
                    * shape.in_channels
                    * shape.out_channels
            }
            Self::Dense { weights, rows, .. } => rows * weights.inputs() * weights.outputs(),
            Self::Lstm { weights, .. } => weights.inputs() * weights.outputs(),
            _ => 0,
        };
        count as u64
    }

    /// The buffers this step reads, and the ones it writes.
    pub(crate) fn buffers(&self) -> (Vec<BufferId>, Vec<BufferId>) {
        match self {
            Self::Pad { from, to, .. }
            | Self::MaxPool { from, to, .. }
            | Self::NhwcToNchw { from, to, .. }
            | Self::Dense { from, to, .. }
            | Self::Copy { from, to, .. }
            | Self::Gather { from, to, .. }
            | Self::Relu { from, to, .. }
            | Self::Reduce { from, to, .. } => (vec![*from], vec![*to]),
            Self::Conv {
                padded,
                pool,
                winograd,
                out,
                ..
            } => {
                let mut writes = vec![*out];
                writes.extend(pool.map(|pool| pool.scratch));
                if let Some(winograd) = winograd {
                    writes.extend([winograd.transformed, winograd.products]);
                }
                (vec![*padded], writes)
            }
            Self::Binary { a, b, to, .. } => (vec![*a, *b], vec![*to]),
            Self::Lstm {
                x,
                h_in,
                c_in,
                joined,
                gates,
                h_out,
                c_out,
                ..
            } => (
                vec![*x, *h_in, *c_in],
                vec![*joined, *gates, *h_out, *c_out],
            ),
        }
    }
}

/// Runs `steps` over `buffers` with `K`'s kernels. Inlined into one function per
/// instruction set, so that every kernel below is compiled for that set.
#[inline(always)]
pub(crate) fn run<K: Kernels>(steps: &[Step], buffers: &mut [Vec<f32>], nonzero: &mut [u32]) {
    for step in steps {
        match step {
            Step::Pad {
                from,
                to,
                size: [h, w, c],
                origin: [top, left],
                padded_width,
                from_nchw,
            } => {
                let mut out = mem::take(&mut buffers[*to]);
                let input = &buffers[*from];
                for y in 0..*h {
                    let row = &mut out[((top + y) * padded_width + left) * c..][..w * c];
                    if *from_nchw && *c == 1 {
                        row.copy_from_slice(&input[y * w..(y + 1) * w]);
                    } else if *from_nchw {
                        for (x, pixel) in row.chunks_exact_mut(*c).enumerate() {
                            for (channel, value) in pixel.iter_mut().enumerate() {
                                *value = input[(channel * h + y) * w + x];
                            }
                        }
                    } else {
                        row.copy_from_slice(&input[y * w * c..(y + 1) * w * c]);
                    }
                }
                buffers[*to] = out;
            }
            Step::Conv {
                padded,
                weights,
                bias,
                shape,
                relu,
                pool,
                winograd,
                out,
            } => {
                let mut target = mem::take(&mut buffers[*out]);
                let weights = weights.as_slice();
                if let Some(winograd) = winograd {
                    let mut transformed = mem::take(&mut buffers[winograd.transformed]);
                    let mut products = mem::take(&mut buffers[winograd.products]);
                    let done = K::winograd_conv_pool(
                        &winograd.layer,
                        &buffers[*padded],
                        winograd.weights.as_slice(),
                        bias,
                        *relu,
                        &mut transformed,
                        &mut products,
                        &mut target,
                    );
                    buffers[winograd.transformed] = transformed;
                    buffers[winograd.products] = products;
                    if done {
                        buffers[*out] = target;
                        continue;
                    }
                }
                match pool {
                    None => K::conv(
                        shape,
                        &buffers[*padded],
                        weights,
                        bias,
                        *relu,
                        0,
                        &mut target,
                    ),
                    Some(pool) => {
                        let mut scratch = mem::take(&mut buffers[pool.scratch]);
                        let input = &buffers[*padded];
                        let ([_, ow], oc) = (shape.out, shape.out_channels);
                        let [ph, pw] = pool.out;
                        let rows = pool.kernel[0];
                        let scratch_rows = &mut scratch[..rows * ow * oc];
                        let pooled_rows = target.chunks_exact_mut(pw * oc).take(ph);
                        for (py, pooled) in pooled_rows.enumerate() {
                            let first = py * pool.stride[0];
                            K::conv(shape, input, weights, bias, *relu, first, scratch_rows);
                            K::max_pool(
                                scratch_rows,
                                [rows, ow, oc],
                                pool.kernel,
                                pool.stride,
                                [1, pw],
                                pooled,
                            );
                        }
                        buffers[pool.scratch] = scratch;
                    }
                }
                buffers[*out] = target;
            }
            Step::MaxPool {
                from,
                to,
                size,
                kernel,
                stride,
                out,
            } => {
                let mut target = mem::take(&mut buffers[*to]);
                K::max_pool(&buffers[*from], *size, *kernel, *stride, *out, &mut target);
                buffers[*to] = target;
            }
            Step::NhwcToNchw {
                from,
                to,
                size: [h, w, c],
            } => {
                let mut target = mem::take(&mut buffers[*to]);
                let input = &buffers[*from];
                for (pixel, values) in input.chunks_exact(*c).enumerate().take(h * w) {
                    for (channel, &value) in values.iter().enumerate() {
                        target[channel * h * w + pixel] = value;
                    }
                }
                buffers[*to] = target;
            }
            Step::Dense {
                from,
                weights,
                bias,
                rows,
                relu,
                to,
            } => {
                let mut target = mem::take(&mut buffers[*to]);
                let input = &buffers[*from];
                let (k, n) = (weights.inputs(), weights.outputs());
                for r in 0..*rows {
                    let y = &mut target[r * n..(r + 1) * n];
                    K::dense(&input[r * k..(r + 1) * k], weights, bias, y, nonzero);
                    if *relu {
                        for value in y.iter_mut() {
                            *value = value.max(0.0);
                        }
                    }
                }
                buffers[*to] = target;
            }
            Step::Lstm {
                x,
                h_in,
                c_in,
                joined,
                weights,
                bias,
                gates,
                h_out,
                c_out,
            } => {
                let mut xh = mem::take(&mut buffers[*joined]);
                let features = buffers[*x].len();
                xh[..features].copy_from_slice(&buffers[*x]);
                xh[features..].copy_from_slice(&buffers[*h_in]);
                let mut gate_values = mem::take(&mut buffers[*gates]);
                K::dense(&xh, weights, bias, &mut gate_values, nonzero);
                let (mut h, mut c) = (
                    mem::take(&mut buffers[*h_out]),
                    mem::take(&mut buffers[*c_out]),
                );
                c.copy_from_slice(&buffers[*c_in]);
                kernels::lstm_cell(&gate_values, &mut c, &mut h);
                buffers[*joined] = xh;
                buffers[*gates] = gate_values;
                buffers[*h_out] = h;
                buffers[*c_out] = c;
            }
            Step::Copy {
                from,
                from_offset,
                to,
                to_offset,
                len,
            } => {
                let mut target = mem::take(&mut buffers[*to]);
                target[*to_offset..to_offset + len]
                    .copy_from_slice(&buffers[*from][*from_offset..from_offset + len]);
                buffers[*to] = target;
            }
            Step::Gather { from, source, to } => {
                let mut target = mem::take(&mut buffers[*to]);
                let input = &buffers[*from];
                source.for_each(|i, offset| target[i] = input[offset]);
                buffers[*to] = target;
            }
            Step::Relu { from, to, len } => {
                let mut target = mem::take(&mut buffers[*to]);
                for (t, &v) in target[..*len].iter_mut().zip(&buffers[*from]) {
                    *t = v.max(0.0);
                }
                buffers[*to] = target;
            }
            Step::Binary {
                op,
                a,
                a_index,
                b,
                b_index,
                to,
            } => {
                let mut target = mem::take(&mut buffers[*to]);
                let (left, right) = (&buffers[*a], &buffers[*b]);
                a_index.for_each(|i, offset| target[i] = left[offset]);
                let apply = |x: f32, y: f32| match op {
                    BinaryOp::Add => x + y,
                    BinaryOp::Sub => x - y,
                    BinaryOp::Mul => x * y,
                    BinaryOp::Div => x / y,
                    BinaryOp::Equal => f32::from(u8::from(x == y)),
                };
                b_index.for_each(|i, offset| target[i] = apply(target[i], right[offset]));
                buffers[*to] = target;
            }
            Step::Reduce {
                op,
                from,
                target,
                to,
            } => {
                let mut out = mem::take(&mut buffers[*to]);
                out.fill(match op {
                    ReduceOp::Max => f32::NEG_INFINITY,
                    ReduceOp::Sum => 0.0,
                });
                let input = &buffers[*from];
                target.for_each(|i, offset| {
                    out[offset] = match op {
                        ReduceOp::Max => out[offset].max(input[i]),
                        ReduceOp::Sum => out[offset] + input[i],
                    }
                });
                buffers[*to] = out;
            }
        }
    }
}
