//! The portable kernels: plain loops, every one `#[inline(always)]` and generic over
//! [`MulAdd`], so that each instruction set's `#[target_feature]` function compiles them with
//! its own vector instructions. The x86 paths fall back to them where their own kernels do
//! not fit a layer.

use super::{MulAdd, PoolShape};
use crate::policy::engine::layout::{ConvLayer, ConvShape, DenseWeights};

/// Convolution of a zero-bordered NHWC input (`padded`: `[rows][padded_width][in]`) with
/// weights `[ky][kx][in][OC]`, plus bias, optionally clamped at zero, into NHWC `out`:
/// output rows `first_row..`, as many as `out` holds.
/// `P` neighbouring output pixels are computed together so each weight vector loaded is
/// used `P` times; the `P x OC` accumulators stay in vector registers.
#[inline(always)]
pub(crate) fn conv<M: MulAdd, const OC: usize, const P: usize>(
    layer: &ConvLayer<'_>,
    padded: &[f32],
    first_row: usize,
    out: &mut [f32],
) {
    let ConvLayer {
        shape,
        weights,
        bias,
        relu,
    } = *layer;
    let [_, ow] = shape.out;
    let Ok(bias) = <&[f32; OC]>::try_from(&bias[..OC]) else {
        return;
    };
    let (weights, _) = weights.as_chunks::<OC>();
    let (out, _) = out.as_chunks_mut::<OC>();
    for (i, out_row) in out.chunks_exact_mut(ow).enumerate() {
        let oy = first_row + i;
        let blocks = ow / P;
        let (whole, rest) = out_row.split_at_mut(blocks * P);
        for (block, target) in whole.chunks_exact_mut(P).enumerate() {
            conv_block::<M, OC, P>(shape, padded, weights, bias, relu, oy, block * P, target);
        }
        for (i, target) in rest.chunks_exact_mut(1).enumerate() {
            conv_block::<M, OC, 1>(
                shape,
                padded,
                weights,
                bias,
                relu,
                oy,
                blocks * P + i,
                target,
            );
        }
    }
}

/// `P` output pixels of row `oy` from column `ox` on.
#[inline(always)]
#[allow(clippy::too_many_arguments)] // one block of one convolution
fn conv_block<M: MulAdd, const OC: usize, const P: usize>(
    shape: &ConvShape,
    padded: &[f32],
    weights: &[[f32; OC]],
    bias: &[f32; OC],
    relu: bool,
    oy: usize,
    ox: usize,
    target: &mut [[f32; OC]],
) {
    let ic = shape.in_channels;
    let [kh, kw] = shape.kernel;
    let [sy, sx] = shape.stride;
    let row = shape.padded_width * ic;
    let step = sx * ic;
    let mut acc = [*bias; P];
    for ky in 0..kh {
        let input_row = &padded[(oy * sy + ky) * row..(oy * sy + ky + 1) * row];
        for kx in 0..kw {
            let taps = &weights[(ky * kw + kx) * ic..(ky * kw + kx + 1) * ic];
            let first = (ox * sx + kx) * ic;
            let span = &input_row[first..first + (P - 1) * step + ic];
            for (c, w) in taps.iter().enumerate() {
                // Loads (and their bounds checks) first, so that the multiply-adds below are
                // one straight run the compiler turns into vector instructions.
                let mut xs = [0.0f32; P];
                for (p, x) in xs.iter_mut().enumerate() {
                    *x = span[p * step + c];
                }
                for p in 0..P {
                    for o in 0..OC {
                        acc[p][o] = M::mul_add(xs[p], w[o], acc[p][o]);
                    }
                }
            }
        }
    }
    for (target, acc) in target.iter_mut().zip(&acc) {
        for (t, &a) in target.iter_mut().zip(acc) {
            *t = if relu { a.max(0.0) } else { a };
        }
    }
}

/// [`conv`] for any number of output channels: eight at a time, then the rest.
#[inline(always)]
pub(crate) fn conv_any<M: MulAdd>(
    layer: &ConvLayer<'_>,
    padded: &[f32],
    first_row: usize,
    out: &mut [f32],
) {
    let ConvLayer {
        shape,
        weights,
        bias,
        relu,
    } = *layer;
    let ic = shape.in_channels;
    let oc = shape.out_channels;
    let [kh, kw] = shape.kernel;
    let [sy, sx] = shape.stride;
    let [_, ow] = shape.out;
    let row = shape.padded_width * ic;
    for (i, out_row) in out.chunks_exact_mut(ow * oc).enumerate() {
        let oy = first_row + i;
        for ox in 0..ow {
            let target = &mut out_row[ox * oc..(ox + 1) * oc];
            target.copy_from_slice(&bias[..oc]);
            for ky in 0..kh {
                let input_row = &padded[(oy * sy + ky) * row..(oy * sy + ky + 1) * row];
                for kx in 0..kw {
                    let pixel = &input_row[(ox * sx + kx) * ic..(ox * sx + kx + 1) * ic];
                    let taps = &weights[(ky * kw + kx) * ic * oc..(ky * kw + kx + 1) * ic * oc];
                    for (&x, w) in pixel.iter().zip(taps.chunks_exact(oc)) {
                        for (t, &w) in target.iter_mut().zip(w) {
                            *t = M::mul_add(x, w, *t);
                        }
                    }
                }
            }
            if relu {
                for t in target.iter_mut() {
                    *t = t.max(0.0);
                }
            }
        }
    }
}

/// Max pooling of an NHWC map `[h][w][c]` (no padding). A ReLU next to the pool is folded
/// into the convolution before it (both are monotone), so the pool has no clamp of its own.
#[inline(always)]
pub(crate) fn max_pool_nhwc(input: &[f32], shape: PoolShape, out: &mut [f32]) {
    let PoolShape {
        size: [_, w, c],
        kernel,
        stride,
        out: [oh, ow],
    } = shape;
    for oy in 0..oh {
        for ox in 0..ow {
            let target = &mut out[(oy * ow + ox) * c..(oy * ow + ox + 1) * c];
            target.fill(f32::NEG_INFINITY);
            for ky in 0..kernel[0] {
                for kx in 0..kernel[1] {
                    let (y, x) = (oy * stride[0] + ky, ox * stride[1] + kx);
                    let pixel = &input[(y * w + x) * c..(y * w + x + 1) * c];
                    for (t, &v) in target.iter_mut().zip(pixel) {
                        *t = t.max(v);
                    }
                }
            }
        }
    }
}

/// The indices of `x`'s non-zero values, in order, into the front of `nonzero` (which holds
/// at least `x.len()`); returns how many. Without a branch on the values: every index is
/// written and the count moves on past a non-zero one (NaN included), so the time taken
/// does not depend on where the zeros are.
#[inline(always)]
pub(crate) fn nonzero_indices(x: &[f32], nonzero: &mut [u32]) -> usize {
    debug_assert!(nonzero.len() >= x.len(), "scratch sized at load");
    let mut count = 0;
    for (i, &value) in x.iter().enumerate() {
        // `count <= i < nonzero.len()`: the slot is always there.
        if let Some(slot) = nonzero.get_mut(count) {
            *slot = i as u32;
        }
        count += usize::from(value != 0.0);
    }
    count.min(nonzero.len())
}

/// `y = bias + W x` for a dense layer in column panels ([`DenseWeights`]), `W` outputs a
/// panel, inputs that are zero skipped; `nonzero` is scratch for [`nonzero_indices`].
#[inline(always)]
pub(crate) fn dense<M: MulAdd>(
    x: &[f32],
    weights: &DenseWeights,
    bias: &[f32],
    y: &mut [f32],
    nonzero: &mut [u32],
) {
    match weights.width() {
        8 => dense_panels::<M, 8>(x, weights, bias, y, nonzero),
        16 => dense_panels::<M, 16>(x, weights, bias, y, nonzero),
        32 => dense_panels::<M, 32>(x, weights, bias, y, nonzero),
        _ => dense_panels::<M, 64>(x, weights, bias, y, nonzero),
    }
}

#[inline(always)]
fn dense_panels<M: MulAdd, const W: usize>(
    x: &[f32],
    weights: &DenseWeights,
    bias: &[f32],
    y: &mut [f32],
    nonzero: &mut [u32],
) {
    let k = weights.inputs();
    let x = &x[..k];
    let count = nonzero_indices(x, nonzero);
    let nonzero = &nonzero[..count];
    let (rows, _) = weights.panels().as_chunks::<W>();
    let outputs = weights.outputs().min(y.len());
    let targets = y[..outputs].chunks_mut(W).zip(bias.chunks(W));
    for (rows, (y, bias)) in rows.chunks_exact(k).zip(targets) {
        let mut acc = [0.0f32; W];
        for &i in nonzero {
            let (value, row) = (x[i as usize], &rows[i as usize]);
            for l in 0..W {
                acc[l] = M::mul_add(value, row[l], acc[l]);
            }
        }
        for ((t, a), b) in y.iter_mut().zip(acc).zip(bias) {
            *t = a + b;
        }
    }
}

/// One LSTM step (ONNX gate order input, output, forget, cell): `gates` holds
/// `W x + R h + Wb + Rb` for the 4H gates; updates `c` and writes `h`.
#[inline(always)]
pub(crate) fn lstm_cell(gates: &[f32], c: &mut [f32], h: &mut [f32]) {
    let units = h.len();
    for j in 0..units {
        let input = sigmoid(gates[j]);
        let output = sigmoid(gates[units + j]);
        let forget = sigmoid(gates[2 * units + j]);
        let candidate = gates[3 * units + j].tanh();
        c[j] = forget * c[j] + input * candidate;
        h[j] = output * c[j].tanh();
    }
}

#[inline(always)]
fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::engine::kernels::{Fused, Separate};

    /// Seeded values in -0.5..0.5: every product rounds, so a different order of sums shows.
    fn values(count: usize, seed: u32) -> Vec<f32> {
        (0..count)
            .map(|i| {
                let mixed = (i as u32).wrapping_mul(2_654_435_761).wrapping_add(seed);
                (mixed >> 9) as f32 / (1u32 << 23) as f32 - 0.5
            })
            .collect()
    }

    #[test]
    fn the_blocked_convolution_gives_the_any_width_loops_numbers_bit_for_bit() {
        // Widths that leave a remainder after the blocks of eight pixels, strides 1 and 2.
        for (out_width, stride, in_channels, relu) in [
            (13, 1, 1, true),
            (8, 2, 3, false),
            (21, 2, 4, true),
            (1, 1, 2, false),
        ] {
            let shape = ConvShape {
                padded_width: (out_width - 1) * stride + 5,
                in_channels,
                out_channels: 4,
                kernel: [5, 5],
                stride: [stride, stride],
                out: [3, out_width],
            };
            let rows = (shape.out[0] - 1) * stride + 5;
            let padded = values(rows * shape.padded_width * in_channels, 1);
            let weights = values(25 * in_channels * 4, 2);
            let bias = values(4, 3);
            let size = shape.out[0] * out_width * 4;
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            let layer = ConvLayer {
                shape: &shape,
                weights: &weights,
                bias: &bias,
                relu,
            };
            let (mut blocked, mut any) = (vec![0.0; size], vec![0.0; size]);
            conv::<Separate, 4, 8>(&layer, &padded, 0, &mut blocked);
            conv_any::<Separate>(&layer, &padded, 0, &mut any);
            assert_eq!(bits(&blocked), bits(&any), "{shape:?}");
            assert!(blocked.iter().any(|&x| x != 0.0));
            // One rounding per product (the AVX2 path's; `fmaf` here, the same numbers).
            conv::<Fused, 4, 8>(&layer, &padded, 0, &mut blocked);
            conv_any::<Fused>(&layer, &padded, 0, &mut any);
            assert_eq!(bits(&blocked), bits(&any), "{shape:?}");
        }
    }
}
