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
//! panels of 8 ([`u8s8_max_product_8c_ssse3`]), not half-empty panels of 16.
//!
//! History, measured with callgrind (cross/README.md): one call per pixel with the window
//! read in place (a segment per kernel row) and one quad per broadcast cost 8.07 M
//! instructions per CNN forward on the V5, more than the float engine's 5.95 M.
//!
//! Files: [`panels`] (the weights' layout), [`reference`] (the portable kernel the vector
//! ones equal), [`ssse3`] (both Naos' kernels, in assembly), [`avx2`] (the host's),
//! [`pooled_pixels`] (the cameras' one-channel first layers, vectorised over pooled pixels),
//! [`dispatch`] (which kernel a CPU gets), [`quantize`] (floats to codes), [`window`]
//! (a convolution's windows copied out of the code map), and the tests beside them.
// The vector kernels are `unsafe`: intrinsics of a `#[target_feature]` the caller checked.
#![allow(unsafe_code)]

mod avx2;
mod dispatch;
mod panels;
#[cfg(target_arch = "x86_64")]
mod pooled_pixels;
mod quantize;
mod reference;
mod ssse3;
mod window;

#[cfg(test)]
mod tests;

pub(crate) use dispatch::{Int8Kernel, ZeroGroups};
pub(crate) use panels::QuadPanels;
#[cfg(target_arch = "x86_64")]
pub(crate) use pooled_pixels::PooledPixelWeights;
pub(crate) use quantize::code_run;
pub(crate) use window::Window;

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
