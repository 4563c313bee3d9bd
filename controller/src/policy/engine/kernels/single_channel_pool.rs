//! A camera's first layer as its own kernel: a convolution of a one-channel image (luma in,
//! a few channels out) with stride 2 and the 2x2 max-pool after it, vectorised over pooled
//! pixels instead of over output channels.
//!
//! Why a kernel of its own: the other vector kernels put a pixel's output channels in a
//! register's lanes, and a narrow network's first layer has four of them: half of an AVX2
//! register, a quarter of AVX-512's, and each broadcast input feeds only four products.
//! B-Human's CompiledNN ran the robot package's float student faster than the engine on
//! every instruction set, and this layer was half of the engine's time
//! (`dribble-controller forward --layers`: 41 µs of 86 on avx2+fma).
//!
//! How: the padded image is first split by column into four phase planes,
//! `plane[m][row][j] = image[row][4j + m]`. The four convolution outputs under pooled
//! pixel `q` read columns `4q + 2dx + kx` (`dx` the output's column in the pool window,
//! `kx` the tap), that is plane `(2dx + kx) % 4` at `q + (2dx + kx) / 4`: so a tap of a block
//! of `LANES` pooled pixels is one unaligned load from one plane, and that load serves every
//! output channel. Each output channel's weight is broadcast once a tap. The four
//! convolution outputs of a pool window are four accumulators, so the pool is a lane-wise
//! maximum of registers; the bias and the ReLU come after it (adding the same bias to every
//! candidate and rounding keeps their order, so the maximum is the separate pool's, bit for
//! bit, of these sums). Two output channels at a time: eight accumulators, four inputs and a
//! weight in the sixteen registers of x86-64.
//!
//! The sums add each output's products tap by tap from zero and the bias last, where the
//! channel-lane kernels start from the bias: the same products, another rounding order
//! (within the engine's parity tolerance against tract, as every float kernel is).
#![allow(unsafe_code)]

use super::PooledConv;
use super::simd::Vector;
use crate::policy::engine::layout::ConvLayer;

/// The most lanes a vector type has (AVX-512's sixteen floats) times the most output
/// channels the kernel takes: the stack scratch that turns a block's channel vectors into
/// NHWC pixels.
const MAX_BLOCK: usize = 16 * 8;

/// The floats of one phase plane's row: a quarter of the padded width, rounded up.
pub(crate) fn plane_width(padded_width: usize) -> usize {
    padded_width.div_ceil(4)
}

/// The floats the four phase planes of a padded image of `rows` rows take.
pub(crate) fn planes_len(rows: usize, padded_width: usize) -> Option<usize> {
    plane_width(padded_width).checked_mul(rows)?.checked_mul(4)
}

/// Whether the kernel takes a convolution and pool of these shapes: one input channel, four
/// outputs, stride 2, a 2x2 pool with stride 2. Eight outputs fill an AVX2 register of the
/// channel-lane kernels, which ran the host model's 1->8 layer in less than half this
/// kernel's time (`dribble-controller forward --layers`); the kernel itself is written for
/// any even count up to eight.
pub(crate) fn takes(
    in_channels: usize,
    out_channels: usize,
    stride: [usize; 2],
    pool: [[usize; 2]; 2],
) -> bool {
    in_channels == 1 && out_channels == 4 && stride == [2, 2] && pool == [[2, 2], [2, 2]]
}

/// Splits the `rows` rows of `padded` (`width` floats each) into the four phase planes of
/// `planes` (see the module's doc); columns past the image are zero.
fn split_phases(padded: &[f32], rows: usize, width: usize, planes: &mut [f32]) {
    let quarter = plane_width(width);
    let plane = rows * quarter;
    let (first, rest) = planes.split_at_mut(plane);
    let (second, rest) = rest.split_at_mut(plane);
    let (third, fourth) = rest.split_at_mut(plane);
    let fourth = &mut fourth[..plane];
    for (r, row) in padded.chunks_exact(width).take(rows).enumerate() {
        let span = r * quarter..(r + 1) * quarter;
        let [p0, p1, p2, p3] = [
            &mut first[span.clone()],
            &mut second[span.clone()],
            &mut third[span.clone()],
            &mut fourth[span],
        ];
        let quads = row.chunks_exact(4);
        let tail = quads.remainder();
        for (j, quad) in quads.enumerate() {
            p0[j] = quad[0];
            p1[j] = quad[1];
            p2[j] = quad[2];
            p3[j] = quad[3];
        }
        let last = width / 4;
        if last < quarter {
            for (m, plane) in [p0, p1, p2, p3].into_iter().enumerate() {
                plane[last] = tail.get(m).copied().unwrap_or(0.0);
            }
        }
    }
}

/// [`conv_pool`] with `V`'s vectors for the layers it is compiled for (four outputs, a 5x5
/// kernel); false, nothing written, for any other.
#[inline(always)]
pub(crate) fn conv_pool_of_layer<V: Vector>(layer: &ConvLayer<'_>, conv: PooledConv<'_>) -> bool {
    match (layer.shape.out_channels, layer.shape.kernel) {
        (4, [5, 5]) => conv_pool::<V, 4, 5, 5>(layer, conv),
        _ => false,
    }
}

/// The pooled map `out` (`[pool_out[0]][pool_out[1]][OC]`) of a one-channel image's
/// stride-2 `KH`x`KW` convolution and its 2x2 pool, with `V`'s vectors; `planes` is scratch
/// of [`planes_len`] floats. False, having written nothing to `out`, where the shapes are not
/// the kernel's (one input channel, an even number of outputs, stride 2, a 2x2 pool with
/// stride 2), the pooled rows are narrower than a vector, or a buffer is too short.
#[inline(always)]
pub(crate) fn conv_pool<V: Vector, const OC: usize, const KH: usize, const KW: usize>(
    layer: &ConvLayer<'_>,
    conv: PooledConv<'_>,
) -> bool {
    let (shape, weights, bias) = (layer.shape, layer.weights, layer.bias);
    let PooledConv {
        pool,
        padded,
        planes,
        out,
    } = conv;
    let [pool_kernel, pool_stride, [ph, pw]] = pool;
    let lanes = V::LANES;
    let width = shape.padded_width;
    let rows = padded.len() / width.max(1);
    let quarter = plane_width(width);
    if shape.in_channels != 1
        || shape.stride != [2, 2]
        || [pool_kernel, pool_stride] != [[2, 2], [2, 2]]
        || !OC.is_multiple_of(2)
        || shape.out_channels != OC
        || shape.kernel != [KH, KW]
        || OC * lanes > MAX_BLOCK
        || ph == 0
        || pw < lanes
        || 2 * ph > shape.out[0]
        || 2 * pw > shape.out[1]
        // The rows and columns the last pool window's taps read.
        || 4 * (ph - 1) + 2 + KH > rows
        || 4 * (pw - 1) + 2 + KW > width
        || weights.len() < KH * KW * OC
        || bias.len() < OC
        || planes_len(rows, width).is_none_or(|len| planes.len() < len)
        || out.len() < ph * pw * OC
    {
        return false;
    }
    split_phases(padded, rows, width, planes);
    let planes = &planes[..4 * rows * quarter];
    let mut block = [0.0f32; MAX_BLOCK];
    for py in 0..ph {
        let pooled_row = &mut out[py * pw * OC..][..pw * OC];
        // Blocks of `lanes` pooled pixels; a row that is not a whole number of them ends with
        // a block that overlaps the one before (those pixels are computed twice, identically).
        let mut start = 0;
        loop {
            let q = start.min(pw - lanes);
            for pair in 0..OC / 2 {
                let [first, second] =
                    channel_pair::<V, OC, KH, KW>(planes, [rows, quarter], py, q, weights, pair);
                for (c, sums) in [(2 * pair, first), (2 * pair + 1, second)] {
                    let mut value = V::add(sums, V::splat(bias[c]));
                    if layer.relu {
                        value = V::max(value, V::zero());
                    }
                    value.store(&mut block[c * lanes..]);
                }
            }
            for (pixel, values) in pooled_row[q * OC..]
                .chunks_exact_mut(OC)
                .take(lanes)
                .enumerate()
            {
                for (c, value) in values.iter_mut().enumerate() {
                    *value = block[c * lanes + pixel];
                }
            }
            if q + lanes >= pw {
                break;
            }
            start += lanes;
        }
    }
    true
}

/// The pool window's largest convolution sum (no bias yet) for output channels `2 * pair`
/// and `2 * pair + 1` at pooled pixels `q..q + LANES` of pooled row `py`.
#[inline(always)]
fn channel_pair<V: Vector, const OC: usize, const KH: usize, const KW: usize>(
    planes: &[f32],
    [rows, quarter]: [usize; 2],
    py: usize,
    q: usize,
    weights: &[f32],
    pair: usize,
) -> [V; 2] {
    // [window position dy * 2 + dx][channel of the pair]
    let mut sums = [[V::zero(); 2]; 4];
    let base = planes.as_ptr();
    for ky in 0..KH {
        for kx in 0..KW {
            let tap = &weights[(ky * KW + kx) * OC + 2 * pair..][..2];
            let (w0, w1) = (V::splat(tap[0]), V::splat(tap[1]));
            for dy in 0..2 {
                let row = 4 * py + 2 * dy + ky;
                for dx in 0..2 {
                    let shift = 2 * dx + kx;
                    let at = ((shift % 4) * rows + row) * quarter + q + shift / 4;
                    // SAFETY: `conv_pool` checked that every window's rows (`row < rows`)
                    // and columns (`4q + shift < width`, so `q + shift / 4 + LANES - 1 <
                    // quarter` for the block's last pixel `q + LANES - 1 < pw`) lie inside
                    // the image, whose planes `planes` holds whole; the caller's
                    // instruction set is `V`'s.
                    let x = unsafe { V::load_unchecked(base.add(at)) };
                    let sum = &mut sums[dy * 2 + dx];
                    sum[0] = V::mul_add(x, w0, sum[0]);
                    sum[1] = V::mul_add(x, w1, sum[1]);
                }
            }
        }
    }
    let largest = |c: usize| {
        V::max(
            V::max(sums[0][c], sums[1][c]),
            V::max(sums[2][c], sums[3][c]),
        )
    };
    [largest(0), largest(1)]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::engine::kernels::portable::{conv_any, max_pool_nhwc};
    use crate::policy::engine::kernels::{PoolShape, Separate};
    use crate::policy::engine::layout::ConvShape;

    /// The portable convolution and a separate pool: the reference the kernel must match.
    fn reference(layer: &ConvLayer<'_>, padded: &[f32], pool_out: [usize; 2]) -> Vec<f32> {
        let [oh, ow] = layer.shape.out;
        let oc = layer.shape.out_channels;
        let mut full = vec![0.0; oh * ow * oc];
        conv_any::<Separate>(layer, padded, 0, &mut full);
        let mut pooled = vec![0.0; pool_out[0] * pool_out[1] * oc];
        let shape = PoolShape {
            size: [oh, ow, oc],
            kernel: [2, 2],
            stride: [2, 2],
            out: pool_out,
        };
        max_pool_nhwc(&full, shape, &mut pooled);
        pooled
    }

    fn pattern(len: usize, seed: u32) -> Vec<f32> {
        let mut state = seed | 1;
        (0..len)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 17;
                state ^= state << 5;
                (state % 2001) as f32 / 1000.0 - 1.0
            })
            .collect()
    }

    fn check<V: Vector, const OC: usize>(image: [usize; 2], relu: bool) {
        let [h, w] = image;
        let (pad, k) = (2, 5);
        let [hp, wp] = [h + 2 * pad, w + 2 * pad];
        let out = [(hp - k) / 2 + 1, (wp - k) / 2 + 1];
        let pool_out = [out[0] / 2, out[1] / 2];
        let shape = ConvShape {
            padded_width: wp,
            in_channels: 1,
            out_channels: OC,
            kernel: [k, k],
            stride: [2, 2],
            out,
        };
        let (weights, bias, padded) = (
            pattern(k * k * OC, 7),
            pattern(OC, 11),
            pattern(hp * wp, 13),
        );
        let layer = ConvLayer {
            shape: &shape,
            weights: &weights,
            bias: &bias,
            relu,
        };
        let mut planes = vec![f32::NAN; planes_len(hp, wp).expect("small planes")];
        let mut pooled = vec![f32::NAN; pool_out[0] * pool_out[1] * OC];
        assert!(conv_pool::<V, OC, 5, 5>(
            &layer,
            PooledConv {
                pool: [[2, 2], [2, 2], pool_out],
                padded: &padded,
                planes: &mut planes,
                out: &mut pooled,
            }
        ));
        let expected = reference(&layer, &padded, pool_out);
        for (i, (got, want)) in pooled.iter().zip(&expected).enumerate() {
            assert!(
                (got - want).abs() <= 1e-5,
                "output {i}: {got} against {want}"
            );
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn pooled_pixels_in_lanes_give_the_portable_convolution_and_pool() {
        use crate::policy::engine::kernels::simd::Sse;
        // The robot package's two first layers (120x160 and 60x80 images, four channels),
        // a row that is not a whole number of blocks, and eight channels.
        check::<Sse, 4>([120, 160], true);
        check::<Sse, 4>([60, 80], false);
        // The kernel is written for any even count of outputs (it runs four).
        check::<Sse, 8>([22, 46], true);
        check::<Sse, 2>([16, 30], true);
        check::<Sse, 4>([21, 43], true);
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn shapes_the_kernel_does_not_take_are_left_alone() {
        use crate::policy::engine::kernels::simd::Sse;
        let shape = ConvShape {
            padded_width: 20,
            in_channels: 1,
            out_channels: 4,
            kernel: [5, 5],
            stride: [1, 1],
            out: [16, 16],
        };
        let (weights, bias, padded) = (pattern(100, 1), pattern(4, 2), pattern(400, 3));
        let layer = ConvLayer {
            shape: &shape,
            weights: &weights,
            bias: &bias,
            relu: true,
        };
        let mut planes = vec![0.0; planes_len(20, 20).expect("small planes")];
        let mut out = vec![f32::NAN; 8 * 8 * 4];
        assert!(!conv_pool::<Sse, 4, 5, 5>(
            &layer,
            PooledConv {
                pool: [[2, 2], [2, 2], [8, 8]],
                padded: &padded,
                planes: &mut planes,
                out: &mut out,
            }
        ));
        assert!(out.iter().all(|v| v.is_nan()), "nothing written");
        // Stride 2, but rows narrower than a vector of pooled pixels would need.
        let narrow = ConvShape {
            padded_width: 10,
            stride: [2, 2],
            out: [3, 3],
            ..shape
        };
        let layer = ConvLayer {
            shape: &narrow,
            ..layer
        };
        assert!(!conv_pool::<Sse, 4, 5, 5>(
            &layer,
            PooledConv {
                pool: [[2, 2], [2, 2], [1, 1]],
                padded: &padded[..100],
                planes: &mut planes,
                out: &mut out,
            }
        ));
    }
}
