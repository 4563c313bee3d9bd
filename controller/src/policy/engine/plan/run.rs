//! The loop that runs a plan's steps over its buffers with one instruction set's kernels,
//! and each step's work: the float layers, the data moves and the int8 layers.

use core::mem;

use super::{
    BinaryOp, ConvPool, QuantizedConv, QuantizedDense, QuantizedPool, ReduceOp, Step, WinogradConv,
};
use crate::policy::engine::kernels::int8::{ZeroGroups, code_run};
use crate::policy::engine::kernels::winograd;
use crate::policy::engine::kernels::{Kernels, PoolShape, PooledConv, portable};
use crate::policy::engine::layout::{BufferId, ConvLayer, DenseWeights, Strided};

/// Runs `steps` over `buffers` with `K`'s kernels. Inlined into one function per
/// instruction set, so that every kernel below is compiled for that set; each step's own
/// function is inlined into it too.
#[inline(always)]
pub(crate) fn run<K: Kernels>(steps: &mut [Step], buffers: &mut [Vec<f32>], nonzero: &mut [u32]) {
    for step in steps {
        match step {
            Step::QuantizedConv(conv) => quantized_conv(conv, buffers),
            Step::QuantizedDense(dense) => quantized_dense(dense, buffers),
            step => float_step::<K>(step, buffers, nonzero),
        }
    }
}

/// One float layer (padding, convolution, pooling, layout, dense, LSTM) with `K`'s kernels;
/// the other float steps go to [`data_step`], the int8 steps own scratch and run above.
#[inline(always)]
fn float_step<K: Kernels>(step: &Step, buffers: &mut [Vec<f32>], nonzero: &mut [u32]) {
    match step {
        Step::Pad {
            from,
            to,
            size,
            origin,
            padded_width,
            from_nchw,
        } => with_output(buffers, *to, |out, buffers| {
            pad(
                &buffers[*from],
                *size,
                *origin,
                *padded_width,
                *from_nchw,
                out,
            );
        }),
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
            let layer = ConvLayer {
                weights: weights.as_slice(),
                bias,
                shape,
                relu: *relu,
            };
            if let Some(winograd) = winograd
                && winograd_conv_pool::<K>(&layer, winograd, *padded, *out, buffers)
            {
                return;
            }
            match pool {
                None => with_output(buffers, *out, |target, buffers| {
                    K::conv(&layer, &buffers[*padded], 0, target);
                }),
                Some(pool) => conv_pool::<K>(&layer, pool, *padded, *out, buffers),
            }
        }
        Step::MaxPool { from, to, shape } => with_output(buffers, *to, |target, buffers| {
            K::max_pool(&buffers[*from], *shape, target);
        }),
        Step::NhwcToNchw { from, to, size } => with_output(buffers, *to, |target, buffers| {
            nhwc_to_nchw(&buffers[*from], *size, target);
        }),
        Step::Dense {
            from,
            weights,
            bias,
            rows,
            relu,
            to,
        } => with_output(buffers, *to, |target, buffers| {
            dense_rows::<K>(
                &buffers[*from],
                weights,
                bias,
                *rows,
                *relu,
                target,
                nonzero,
            );
        }),
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
            let ports = LstmBuffers {
                x: *x,
                h_in: *h_in,
                c_in: *c_in,
                joined: *joined,
                gates: *gates,
                h_out: *h_out,
                c_out: *c_out,
            };
            lstm_step::<K>(&ports, weights, bias, buffers, nonzero);
        }
        Step::QuantizedConv(_) | Step::QuantizedDense(_) => {
            unreachable!("int8 steps run in `run`")
        }
        step => data_step(step, buffers),
    }
}

/// One step that moves or combines values without a kernel of an instruction set: copies,
/// gathers, ReLU, elementwise and reduction operators, the grid snap.
#[inline(always)]
fn data_step(step: &Step, buffers: &mut [Vec<f32>]) {
    match step {
        Step::Copy {
            from,
            from_offset,
            to,
            to_offset,
            len,
        } => with_output(buffers, *to, |target, buffers| {
            target[*to_offset..to_offset + len]
                .copy_from_slice(&buffers[*from][*from_offset..from_offset + len]);
        }),
        Step::Gather { from, source, to } => with_output(buffers, *to, |target, buffers| {
            let input = &buffers[*from];
            source.for_each(|i, offset| target[i] = input[offset]);
        }),
        Step::Relu { from, to, len } => with_output(buffers, *to, |target, buffers| {
            for (t, &v) in target[..*len].iter_mut().zip(&buffers[*from]) {
                *t = v.max(0.0);
            }
        }),
        Step::Binary {
            op,
            a,
            a_index,
            b,
            b_index,
            to,
        } => with_output(buffers, *to, |target, buffers| {
            binary(
                *op,
                (&buffers[*a], a_index),
                (&buffers[*b], b_index),
                target,
            );
        }),
        Step::Reduce {
            op,
            from,
            target,
            to,
        } => with_output(buffers, *to, |out, buffers| {
            reduce(*op, &buffers[*from], target, out);
        }),
        Step::SnapToGrid {
            from,
            to,
            len,
            grid,
        } => with_output(buffers, *to, |out, buffers| {
            for (y, &x) in out[..*len].iter_mut().zip(&buffers[*from]) {
                *y = grid.snap(x);
            }
        }),
        _ => unreachable!("layers and int8 steps run in `float_step` and `run`"),
    }
}

/// An int8 convolution: the input's codes into the padded byte map (its border stays the
/// zero point), then each output pixel's window through the int8 kernel.
#[inline(always)]
fn quantized_conv(conv: &mut QuantizedConv, buffers: &mut [Vec<f32>]) {
    let QuantizedConv {
        from,
        size: [h, w, c],
        from_nchw,
        origin: [top, left],
        input,
        window,
        out_size: [oh, ow],
        weights,
        kernel,
        zeros,
        epilogue,
        codes,
        windows,
        sums,
        out,
        pool,
        #[cfg(target_arch = "x86_64")]
        pooled_pixels,
    } = conv;
    let (h, w, c) = (*h, *w, *c);
    let map = &buffers[*from];
    for y in 0..h {
        let row = &mut codes[((*top + y) * window.padded_width + *left) * c..][..w * c];
        // One channel is the same row in both layouts (the cameras' input): no per-pixel walk.
        if *from_nchw && c > 1 {
            for (x, pixel) in row.chunks_exact_mut(c).enumerate() {
                for (channel, code) in pixel.iter_mut().enumerate() {
                    *code = input.code(map[(channel * h + y) * w + x]);
                }
            }
        } else {
            code_run(*input, &map[y * w * c..], row);
        }
    }
    let outputs = weights.outputs();
    let len = window.padded_len();
    // One row of outputs (pixels, or max-pool cells) at a time: their windows one after the
    // other, one kernel call for the row (the kernel keeps each cell's largest sum), then
    // one epilogue call for the row's outputs.
    with_output(buffers, *out, |target, _| match pool {
        None => {
            let rows = target.chunks_exact_mut(*ow * outputs).take(*oh);
            for (y, values) in rows.enumerate() {
                window.gather_cells(codes, [y, 0], [1, 1], [*ow, 1], windows);
                kernel.largest(
                    &windows[..*ow * len],
                    weights,
                    &mut sums[..*ow * outputs],
                    *zeros,
                );
                epilogue.apply(&sums[..*ow * outputs], values);
            }
        }
        Some(QuantizedPool {
            kernel: [kh, kw],
            stride: [sh, sw],
            out: [ph, pw],
        }) => {
            let cell_len = *kh * *kw * len;
            let rows = target.chunks_exact_mut(*pw * outputs).take(*ph);
            for (cy, values) in rows.enumerate() {
                #[cfg(target_arch = "x86_64")]
                if let Some(weights) = pooled_pixels
                    && kernel.pooled_pixel_row(
                        weights,
                        codes,
                        [[*kh, *kw], [*sh, *sw], [*ph, *pw]],
                        cy,
                        sums,
                    )
                {
                    epilogue.apply(&sums[..*pw * outputs], values);
                    continue;
                }
                window.gather_cells(codes, [cy * *sh, 0], [*kh, *kw], [*pw, *sw], windows);
                kernel.largest(
                    &windows[..*pw * cell_len],
                    weights,
                    &mut sums[..*pw * outputs],
                    *zeros,
                );
                epilogue.apply(&sums[..*pw * outputs], values);
            }
        }
    });
}

/// An int8 dense layer: each row's codes through the int8 kernel.
#[inline(always)]
fn quantized_dense(dense: &mut QuantizedDense, buffers: &mut [Vec<f32>]) {
    let QuantizedDense {
        from,
        input,
        rows,
        weights,
        kernel,
        epilogue,
        codes,
        sums,
        to,
    } = dense;
    let (k, n) = (weights.inputs(), weights.outputs());
    let mut target = mem::take(&mut buffers[*to]);
    let x = &buffers[*from];
    for r in 0..*rows {
        code_run(*input, &x[r * k..(r + 1) * k], &mut codes[..k]);
        kernel.largest(codes, weights, sums, ZeroGroups::Skip);
        epilogue.apply(sums, &mut target[r * n..(r + 1) * n]);
    }
    buffers[*to] = target;
}

/// Lends buffer `to` to `compute` as its output while the others stay readable, then puts
/// it back. `mem::take` leaves an empty `Vec` in its place: no allocation.
#[inline(always)]
fn with_output(
    buffers: &mut [Vec<f32>],
    to: BufferId,
    compute: impl FnOnce(&mut [f32], &[Vec<f32>]),
) {
    let mut out = mem::take(&mut buffers[to]);
    compute(&mut out, buffers);
    buffers[to] = out;
}

/// A `[h][w][c]` map (or `[c][h][w]`, `from_nchw`) into the interior of a zero-bordered
/// NHWC buffer `padded_width` wide, at `origin` (top, left).
#[inline(always)]
fn pad(
    input: &[f32],
    [h, w, c]: [usize; 3],
    [top, left]: [usize; 2],
    padded_width: usize,
    from_nchw: bool,
    out: &mut [f32],
) {
    for y in 0..h {
        let row = &mut out[((top + y) * padded_width + left) * c..][..w * c];
        if from_nchw && c == 1 {
            row.copy_from_slice(&input[y * w..(y + 1) * w]);
        } else if from_nchw {
            for (x, pixel) in row.chunks_exact_mut(c).enumerate() {
                for (channel, value) in pixel.iter_mut().enumerate() {
                    *value = input[(channel * h + y) * w + x];
                }
            }
        } else {
            row.copy_from_slice(&input[y * w * c..(y + 1) * w * c]);
        }
    }
}

/// The convolution and its pool by Winograd into buffer `out`, where `K` has the kernels for
/// the layer; false, with `out` untouched, where not.
#[inline(always)]
fn winograd_conv_pool<K: Kernels>(
    layer: &ConvLayer<'_>,
    winograd: &WinogradConv,
    padded: BufferId,
    out: BufferId,
    buffers: &mut [Vec<f32>],
) -> bool {
    let mut target = mem::take(&mut buffers[out]);
    let mut transformed = mem::take(&mut buffers[winograd.transformed]);
    let mut products = mem::take(&mut buffers[winograd.products]);
    let done = K::winograd_conv_pool(&mut winograd::Operands {
        layer: &winograd.layer,
        padded: &buffers[padded],
        weights: winograd.weights.as_slice(),
        bias: layer.bias,
        relu: layer.relu,
        transformed: &mut transformed,
        products: &mut products,
        out: &mut target,
    });
    buffers[winograd.transformed] = transformed;
    buffers[winograd.products] = products;
    buffers[out] = target;
    done
}

/// The convolution computed a pool window's rows at a time into the pool's scratch, each
/// band pooled into its row of buffer `out`: the full-size map never exists.
#[inline(always)]
fn conv_pool<K: Kernels>(
    layer: &ConvLayer<'_>,
    pool: &ConvPool,
    padded: BufferId,
    out: BufferId,
    buffers: &mut [Vec<f32>],
) {
    let mut target = mem::take(&mut buffers[out]);
    if let Some(planes) = pool.planes {
        let mut scratch = mem::take(&mut buffers[planes]);
        let conv = PooledConv {
            pool: [pool.kernel, pool.stride, pool.out],
            padded: &buffers[padded],
            planes: &mut scratch,
            out: &mut target,
        };
        let done = K::single_channel_conv_pool(layer, conv);
        buffers[planes] = scratch;
        if done {
            buffers[out] = target;
            return;
        }
    }
    let mut scratch = mem::take(&mut buffers[pool.scratch]);
    let input = &buffers[padded];
    let ([_, ow], oc) = (layer.shape.out, layer.shape.out_channels);
    let [ph, pw] = pool.out;
    let rows = pool.kernel[0];
    let scratch_rows = &mut scratch[..rows * ow * oc];
    let pooled_rows = target.chunks_exact_mut(pw * oc).take(ph);
    for (py, pooled) in pooled_rows.enumerate() {
        let first = py * pool.stride[0];
        K::conv(layer, input, first, scratch_rows);
        let shape = PoolShape {
            size: [rows, ow, oc],
            kernel: pool.kernel,
            stride: pool.stride,
            out: [1, pw],
        };
        K::max_pool(scratch_rows, shape, pooled);
    }
    buffers[pool.scratch] = scratch;
    buffers[out] = target;
}

/// An NHWC map into NCHW order (what a Flatten after the convolutions reads).
#[inline(always)]
fn nhwc_to_nchw(input: &[f32], [h, w, c]: [usize; 3], out: &mut [f32]) {
    for (pixel, values) in input.chunks_exact(c).enumerate().take(h * w) {
        for (channel, &value) in values.iter().enumerate() {
            out[channel * h * w + pixel] = value;
        }
    }
}

/// `rows` rows of `input` through one dense layer, each with its ReLU where asked.
#[inline(always)]
fn dense_rows<K: Kernels>(
    input: &[f32],
    weights: &DenseWeights,
    bias: &[f32],
    rows: usize,
    relu: bool,
    out: &mut [f32],
    nonzero: &mut [u32],
) {
    let (k, n) = (weights.inputs(), weights.outputs());
    for r in 0..rows {
        let y = &mut out[r * n..(r + 1) * n];
        K::dense(&input[r * k..(r + 1) * k], weights, bias, y, nonzero);
        if relu {
            for value in y.iter_mut() {
                *value = value.max(0.0);
            }
        }
    }
}

/// The buffers of one LSTM step (see [`Step::Lstm`]).
struct LstmBuffers {
    x: BufferId,
    h_in: BufferId,
    c_in: BufferId,
    joined: BufferId,
    gates: BufferId,
    h_out: BufferId,
    c_out: BufferId,
}

/// One LSTM step: `[x, h_in]`, its gates by one dense layer, then the cell update.
#[inline(always)]
fn lstm_step<K: Kernels>(
    ports: &LstmBuffers,
    weights: &DenseWeights,
    bias: &[f32],
    buffers: &mut [Vec<f32>],
    nonzero: &mut [u32],
) {
    let mut xh = mem::take(&mut buffers[ports.joined]);
    let features = buffers[ports.x].len();
    xh[..features].copy_from_slice(&buffers[ports.x]);
    xh[features..].copy_from_slice(&buffers[ports.h_in]);
    let mut gate_values = mem::take(&mut buffers[ports.gates]);
    K::dense(&xh, weights, bias, &mut gate_values, nonzero);
    let (mut h, mut c) = (
        mem::take(&mut buffers[ports.h_out]),
        mem::take(&mut buffers[ports.c_out]),
    );
    c.copy_from_slice(&buffers[ports.c_in]);
    portable::lstm_cell(&gate_values, &mut c, &mut h);
    buffers[ports.joined] = xh;
    buffers[ports.gates] = gate_values;
    buffers[ports.h_out] = h;
    buffers[ports.c_out] = c;
}

/// An element-wise operator over two broadcast inputs.
#[inline(always)]
fn binary(
    op: BinaryOp,
    (left, left_index): (&[f32], &Strided),
    (right, right_index): (&[f32], &Strided),
    out: &mut [f32],
) {
    left_index.for_each(|i, offset| out[i] = left[offset]);
    let apply = |x: f32, y: f32| match op {
        BinaryOp::Add => x + y,
        BinaryOp::Sub => x - y,
        BinaryOp::Mul => x * y,
        BinaryOp::Div => x / y,
        BinaryOp::Equal => f32::from(u8::from(x == y)),
    };
    right_index.for_each(|i, offset| out[i] = apply(out[i], right[offset]));
}

/// A reduction: element `i` of `input` into `out[target offset of i]`.
#[inline(always)]
fn reduce(op: ReduceOp, input: &[f32], target: &Strided, out: &mut [f32]) {
    out.fill(match op {
        ReduceOp::Max => f32::NEG_INFINITY,
        ReduceOp::Sum => 0.0,
    });
    target.for_each(|i, offset| {
        out[offset] = match op {
            ReduceOp::Max => out[offset].max(input[i]),
            ReduceOp::Sum => out[offset] + input[i],
        }
    });
}
