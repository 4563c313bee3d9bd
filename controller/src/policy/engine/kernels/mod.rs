//! The engine's arithmetic, written once and compiled per instruction set ([`super::isa`]).
//!
//! What each instruction set provides is the [`Kernels`] trait: [`Generic`] (the portable
//! loops of [`portable`], left to the compiler to vectorise), and on x86 [`SseKernels`],
//! [`AvxKernels`] and [`Avx512Kernels`] (the vector kernels of [`simd`] and [`winograd`]).
//! The kernels import only [`super::layout`]; the plan above them calls them.
//!
//! Every kernel is `#[inline(always)]` and generic over how a product is added ([`MulAdd`]):
//! inlined into a `#[target_feature]` function, the fixed-size inner loops over output
//! channels become that set's vector instructions (4 lanes for SSE, 8 for AVX2), and with
//! FMA one fused instruction per multiply-add. No kernel allocates: every buffer is the
//! caller's, sized at load.
//!
//! Layouts: feature maps are NHWC (channels innermost, batch 1), so a pixel's output
//! channels are one contiguous run that the vector registers hold; convolution weights are
//! re-laid out at load as `[ky][kx][in][out]`, dense weights in column panels
//! `[panel][in][width]` ([`DenseWeights`](super::layout::DenseWeights)).

pub(crate) mod int8;
pub(crate) mod portable;
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
pub(crate) mod simd;
#[cfg(target_arch = "x86_64")]
pub(crate) mod single_channel_pool;
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
mod window_asm;
pub(crate) mod winograd;

use super::layout::{ConvLayer, DenseWeights};

/// How `a * b + c` is computed: fused (one rounding, the FMA instruction) or as a product
/// and a sum.
pub(crate) trait MulAdd {
    fn mul_add(a: f32, b: f32, c: f32) -> f32;
}

/// One rounding: compiles to an FMA instruction where the target has one. Only used
/// inside functions compiled with FMA enabled (elsewhere it would call the slow libm `fmaf`).
#[derive(Debug)]
pub(crate) struct Fused;

impl MulAdd for Fused {
    #[inline(always)]
    fn mul_add(a: f32, b: f32, c: f32) -> f32 {
        a.mul_add(b, c)
    }
}

/// Product, then sum: two roundings, any target.
#[derive(Debug)]
pub(crate) struct Separate;

impl MulAdd for Separate {
    #[inline(always)]
    fn mul_add(a: f32, b: f32, c: f32) -> f32 {
        a * b + c
    }
}

/// A max-pool's geometry over an NHWC map (no padding): the input's `[h, w, c]`, the
/// window's and the stride's `[rows, columns]`, and the pooled map's `[h, w]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct PoolShape {
    pub size: [usize; 3],
    pub kernel: [usize; 2],
    pub stride: [usize; 2],
    pub out: [usize; 2],
}

/// A convolution's pool as [`Kernels::single_channel_conv_pool`] computes it: the pool's
/// window, stride and pooled size, the padded image, the kernel's scratch, the pooled map.
/// Only x86-64 has that kernel; elsewhere the plan builds the struct and nothing reads it.
#[derive(Debug)]
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
pub(crate) struct PooledConv<'a> {
    pub pool: [[usize; 2]; 3],
    pub padded: &'a [f32],
    pub planes: &'a mut [f32],
    pub out: &'a mut [f32],
}

/// The two hot kernels, as an instruction set provides them.
pub(crate) trait Kernels {
    /// Output rows `first_row..` of a convolution, as many as `out` holds.
    fn conv(layer: &ConvLayer<'_>, padded: &[f32], first_row: usize, out: &mut [f32]);
    /// `y = bias + W x`; `nonzero` is scratch for the indices of `x`'s non-zero values.
    fn dense(x: &[f32], weights: &DenseWeights, bias: &[f32], y: &mut [f32], nonzero: &mut [u32]);

    /// A convolution and its pool by [`winograd`] into the pooled map `out`, where the set
    /// has the kernels for the layer's channels; false, having written nothing, where not.
    #[inline(always)]
    fn winograd_conv_pool(_conv: &mut winograd::Operands<'_>) -> bool {
        false
    }

    /// A one-channel image's stride-2 convolution and its 2x2 pool, vectorised over pooled
    /// pixels ([`single_channel_pool`]), into the pooled map of `conv`. False, having
    /// written nothing to it, where the set has no such kernel for the layer.
    #[inline(always)]
    fn single_channel_conv_pool(_layer: &ConvLayer<'_>, _conv: PooledConv<'_>) -> bool {
        false
    }

    /// Max pooling of an NHWC map (see [`portable::max_pool_nhwc`]).
    #[inline(always)]
    fn max_pool(input: &[f32], shape: PoolShape, out: &mut [f32]) {
        portable::max_pool_nhwc(input, shape, out);
    }
}

/// The generic kernels, left to the compiler to vectorise (the portable path).
#[derive(Debug)]
pub(crate) struct Generic<M>(core::marker::PhantomData<M>);

impl<M: MulAdd> Kernels for Generic<M> {
    #[inline(always)]
    fn conv(layer: &ConvLayer<'_>, padded: &[f32], first_row: usize, out: &mut [f32]) {
        let (shape, row) = (layer.shape, first_row);
        // Four channels (the narrow networks' first layers) fill one SSE vector: eight pixels
        // at a time, as eight channels do, where the any-width loop took a scalar multiply-add
        // and its bounds checks per product (callgrind, the narrower float network's whole
        // tick: 16.2 M -> 3.1 M instructions on avx2+fma, 18.7 M -> 3.1 M on sse4.2). Both sum
        // each output's products in the same order from the bias: the same numbers, bit for bit.
        match shape.out_channels {
            4 => portable::conv::<M, 4, 8>(layer, padded, row, out),
            8 => portable::conv::<M, 8, 8>(layer, padded, row, out),
            16 => portable::conv::<M, 16, 4>(layer, padded, row, out),
            32 => portable::conv::<M, 32, 2>(layer, padded, row, out),
            _ => portable::conv_any::<M>(layer, padded, row, out),
        }
    }

    #[inline(always)]
    fn dense(x: &[f32], weights: &DenseWeights, bias: &[f32], y: &mut [f32], nonzero: &mut [u32]) {
        portable::dense::<M>(x, weights, bias, y, nonzero);
    }
}

/// SSE vectors (the Nao V5's and V6's sets): four channels per register.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
#[derive(Debug)]
pub(crate) struct SseKernels;

#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
impl Kernels for SseKernels {
    #[inline(always)]
    fn conv(layer: &ConvLayer<'_>, padded: &[f32], first_row: usize, out: &mut [f32]) {
        use self::simd::{Sse, conv_rows};
        let shape = layer.shape;
        let (ic, row) = (shape.in_channels, first_row);
        // Accumulators, weight vectors and broadcast inputs in registers: sixteen on x86-64,
        // eight on the 32-bit build. Measured with callgrind (`cross/count`): one group of all
        // 32 channels beats two groups of 16 on both, as the inputs are then read once.
        // The first layer (one input channel) gets its inner loop unrolled.
        // Four channels (the narrow networks' first layers) fill one vector: twelve pixels a
        // block, where the portable loop took them eight at a time with the compiler's
        // vectorisation (B-Human's CompiledNN ran the robot package's float student in 86 µs
        // to our 135: `python -m dribble_models.compiled_nn compare`). Vectorised over four
        // output pixels instead (two loads and a shuffle for a stride-2 tap, each channel's
        // weight broadcast once), the first layer took more instructions, not fewer: SSE's
        // two-operand multiply needs a copy of the input or the weight per channel
        // (callgrind, the top camera's layer on sse4.2: 0.77 M instructions against 0.71 M).
        // What does pay is the pooled-pixel kernel with the image split into column phases
        // (no shuffle a tap, one load for every channel): `single_channel_conv_pool`, which
        // takes those layers before they get here on x86-64.
        #[cfg(target_arch = "x86_64")]
        let done = match (shape.out_channels, ic, shape.kernel[1]) {
            (4, 1, 5) => conv_rows::<Sse, 1, 12, 1, 5>(layer, padded, row, out),
            (4, _, _) => conv_rows::<Sse, 1, 12, 0, 0>(layer, padded, row, out),
            (8, 1, 5) => conv_rows::<Sse, 2, 5, 1, 5>(layer, padded, row, out),
            (8, _, _) => conv_rows::<Sse, 2, 5, 0, 0>(layer, padded, row, out),
            (16, 1, 5) => conv_rows::<Sse, 4, 2, 1, 5>(layer, padded, row, out),
            (16, 8, 5) => conv_rows::<Sse, 4, 2, 8, 5>(layer, padded, row, out),
            (32, 16, 5) => conv_rows::<Sse, 8, 1, 16, 5>(layer, padded, row, out),
            _ => conv_rows::<Sse, 4, 2, 0, 0>(layer, padded, row, out),
        };
        // The kernel's width is left to a loop: its taps unrolled, the compiler interleaves
        // them and spills the eight registers (callgrind, fixture CNN: 7.57 M instructions
        // per forward with the width unrolled, 7.31 M with one input channel's loop rolled).
        #[cfg(target_arch = "x86")]
        let done = match (shape.out_channels, ic) {
            (4, 1) => conv_rows::<Sse, 1, 4, 1, 0>(layer, padded, row, out),
            (4, _) => conv_rows::<Sse, 1, 4, 0, 0>(layer, padded, row, out),
            (8, 1) => conv_rows::<Sse, 2, 2, 1, 0>(layer, padded, row, out),
            (8, _) => conv_rows::<Sse, 2, 2, 0, 0>(layer, padded, row, out),
            (16, 1) => conv_rows::<Sse, 4, 1, 1, 0>(layer, padded, row, out),
            (16, 8) => conv_rows::<Sse, 4, 1, 8, 0>(layer, padded, row, out),
            (32, 16) => conv_rows::<Sse, 4, 1, 16, 0>(layer, padded, row, out),
            _ => conv_rows::<Sse, 4, 1, 0, 0>(layer, padded, row, out),
        };
        if !done {
            Generic::<Separate>::conv(layer, padded, row, out);
        }
    }

    #[inline(always)]
    fn winograd_conv_pool(conv: &mut winograd::Operands<'_>) -> bool {
        use self::simd::Sse;
        // One tile by every output channel: each broadcast input (a shuffle, on the pipes
        // that the multiplies and adds use) feeds eight or four multiplies, where five tiles
        // by two vectors fed two (`profile`, SSE: the top camera's second layer 186 -> 146
        // µs, the bottom camera's 13.9 -> 12.3 µs; two tiles by four vectors: 172 µs).
        macro_rules! blocked {
            ($tiles:literal, $vecs:literal) => {
                winograd::conv_pool::<Sse, $tiles, $vecs>(conv)
            };
        }
        #[cfg(target_arch = "x86_64")]
        let done = if conv.layer.out_channels.is_multiple_of(32) {
            blocked!(1, 8)
        } else if conv.layer.out_channels.is_multiple_of(16) {
            blocked!(1, 4)
        } else {
            blocked!(5, 2)
        };
        // The V5's eight registers: one tile by two vectors, its four inputs broadcast at a
        // time (two accumulators, four broadcasts, a product; the layers it gets:
        // `Isa::winograd_fit`).
        #[cfg(target_arch = "x86")]
        let done = blocked!(1, 2);
        done
    }

    #[inline(always)]
    fn dense(x: &[f32], weights: &DenseWeights, bias: &[f32], y: &mut [f32], nonzero: &mut [u32]) {
        use self::simd::{Sse, dense};
        let done = match weights.width() {
            8 => dense::<Sse, 2>(x, weights, bias, y, nonzero),
            16 => dense::<Sse, 4>(x, weights, bias, y, nonzero),
            32 => dense::<Sse, 8>(x, weights, bias, y, nonzero),
            _ => false,
        };
        if !done {
            Generic::<Separate>::dense(x, weights, bias, y, nonzero);
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn single_channel_conv_pool(layer: &ConvLayer<'_>, conv: PooledConv<'_>) -> bool {
        single_channel_pool::conv_pool_of_layer::<simd::Sse>(layer, conv)
    }

    #[inline(always)]
    fn max_pool(input: &[f32], shape: PoolShape, out: &mut [f32]) {
        simd::max_pool::<simd::Sse>(input, shape, out);
    }
}

/// AVX2 vectors with FMA: eight channels per register.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
#[derive(Debug)]
pub(crate) struct AvxKernels;

#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
impl Kernels for AvxKernels {
    #[inline(always)]
    fn conv(layer: &ConvLayer<'_>, padded: &[f32], first_row: usize, out: &mut [f32]) {
        use self::simd::{Avx, conv_rows};
        let shape = layer.shape;
        let (ic, kw, row) = (shape.in_channels, shape.kernel[1], first_row);
        // Sixteen registers: up to twelve accumulators, the weight vectors and the broadcast
        // input. The first layer of the bottom camera (8 channels, 40 pixels a row) takes
        // blocks of ten, which tile its rows, where twelve recomputed a fifth of them
        // (`CompiledNetwork::profile`: 9.7 µs, half the peak, with twelve).
        let done = match (shape.out_channels, ic, kw) {
            // Four channels fill half a vector: the SSE kernel's blocks (VEX-encoded here).
            (4, 1, 5) => conv_rows::<self::simd::Sse, 1, 12, 1, 5>(layer, padded, row, out),
            (4, _, _) => conv_rows::<self::simd::Sse, 1, 12, 0, 0>(layer, padded, row, out),
            (8, 1, 5) => conv_rows::<Avx, 1, 10, 1, 5>(layer, padded, row, out),
            (8, _, _) => conv_rows::<Avx, 1, 12, 0, 0>(layer, padded, row, out),
            (16, 1, 5) => conv_rows::<Avx, 2, 5, 1, 5>(layer, padded, row, out),
            (16, 8, 5) => conv_rows::<Avx, 2, 5, 8, 5>(layer, padded, row, out),
            (32, 16, 5) => conv_rows::<Avx, 2, 5, 16, 5>(layer, padded, row, out),
            _ => conv_rows::<Avx, 2, 5, 0, 0>(layer, padded, row, out),
        };
        if !done {
            Generic::<Fused>::conv(layer, padded, row, out);
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn winograd_conv_pool(conv: &mut winograd::Operands<'_>) -> bool {
        winograd::conv_pool::<simd::Avx, 5, 2>(conv)
    }

    #[inline(always)]
    fn dense(x: &[f32], weights: &DenseWeights, bias: &[f32], y: &mut [f32], nonzero: &mut [u32]) {
        use self::simd::{Avx, dense};
        let done = match weights.width() {
            8 => dense::<Avx, 1>(x, weights, bias, y, nonzero),
            16 => dense::<Avx, 2>(x, weights, bias, y, nonzero),
            32 => dense::<Avx, 4>(x, weights, bias, y, nonzero),
            64 => dense::<Avx, 8>(x, weights, bias, y, nonzero),
            _ => false,
        };
        if !done {
            Generic::<Fused>::dense(x, weights, bias, y, nonzero);
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn single_channel_conv_pool(layer: &ConvLayer<'_>, conv: PooledConv<'_>) -> bool {
        single_channel_pool::conv_pool_of_layer::<simd::Avx>(layer, conv)
    }

    #[inline(always)]
    fn max_pool(input: &[f32], shape: PoolShape, out: &mut [f32]) {
        simd::max_pool::<simd::Avx>(input, shape, out);
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
    fn conv(layer: &ConvLayer<'_>, padded: &[f32], first_row: usize, out: &mut [f32]) {
        use self::simd::{Avx512, conv_rows};
        let shape = layer.shape;
        let (ic, kw, row) = (shape.in_channels, shape.kernel[1], first_row);
        // Thirty-two registers: up to twenty accumulators (ten pixels of 32 channels, or
        // twenty of 16), the weight vectors and the broadcast input. Blocks of ten and twenty
        // pixels tile the paper's widths (80, 40, 20, 10).
        let done = match (shape.out_channels, ic, kw) {
            (16, 1, 5) => conv_rows::<Avx512, 1, 20, 1, 5>(layer, padded, row, out),
            (16, 8, 5) => conv_rows::<Avx512, 1, 10, 8, 5>(layer, padded, row, out),
            (32, 16, 5) => conv_rows::<Avx512, 2, 10, 16, 5>(layer, padded, row, out),
            (oc, _, _) if oc.is_multiple_of(32) => {
                conv_rows::<Avx512, 2, 10, 0, 0>(layer, padded, row, out)
            }
            (oc, _, _) if oc.is_multiple_of(16) => {
                conv_rows::<Avx512, 1, 10, 0, 0>(layer, padded, row, out)
            }
            _ => false,
        };
        if !done {
            AvxKernels::conv(layer, padded, row, out);
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn winograd_conv_pool(conv: &mut winograd::Operands<'_>) -> bool {
        winograd::conv_pool::<simd::Avx512, 5, 2>(conv) || AvxKernels::winograd_conv_pool(conv)
    }

    #[inline(always)]
    fn dense(x: &[f32], weights: &DenseWeights, bias: &[f32], y: &mut [f32], nonzero: &mut [u32]) {
        use self::simd::{Avx512, dense};
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

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn single_channel_conv_pool(layer: &ConvLayer<'_>, conv: PooledConv<'_>) -> bool {
        // Sixteen pooled pixels a vector would compute most of the bottom camera's
        // twenty-pixel rows twice; AVX2's eight ran both layers as fast or faster.
        AvxKernels::single_channel_conv_pool(layer, conv)
    }

    #[inline(always)]
    fn max_pool(input: &[f32], shape: PoolShape, out: &mut [f32]) {
        if shape.size[2].is_multiple_of(16) {
            simd::max_pool::<simd::Avx512>(input, shape, out);
        } else {
            AvxKernels::max_pool(input, shape, out);
        }
    }
}
