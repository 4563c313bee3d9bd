//! Convolutions and max-pools: a Conv (with the ReLU after it folded in where the graph has
//! it) and a MaxPool, which [`super::pool_fusion`] folds into the convolution before it
//! where it can, else a step of its own.

use super::*;

impl Lowerer {
    pub(super) fn conv(&mut self, op: &Operation<'_>) -> Lowered<()> {
        let (node, attributes, input, output) = (op.node, &op.attributes, op.first()?, op.output);
        let (buffer, shape, layout) = self.float_tensor(input, "a convolution")?;
        let weights_name = node.input.get(1).or_unsupported("no weights")?;
        let (weights, weight_shape) = self.weights(weights_name)?;
        let [n, c, h, w] = shape[..] else {
            return unsupported(format!("input shape {shape:?}: only 2-D convolutions"));
        };
        let [oc, wc, kh, kw] = weight_shape[..] else {
            return unsupported(format!("weight shape {weight_shape:?}"));
        };
        if n != 1 || wc != c {
            return unsupported(format!("batch {n}, {c} channels for weights of {wc}"));
        }
        let (strides, pads) = conv_geometry(attributes, [kh, kw])?;
        // Each term at most MAX_ELEMENTS (2^24): the sums cannot wrap even in 32 bits.
        let (padded_h, padded_w) = (h + pads[0] + pads[2], w + pads[1] + pads[3]);
        if padded_h < kh || padded_w < kw {
            return unsupported("a kernel larger than its padded input");
        }
        let padded_len = elements(&[padded_h, padded_w, c])?;
        let out = [
            (padded_h - kh) / strides[0] + 1,
            (padded_w - kw) / strides[1] + 1,
        ];
        let bias = match node.input.get(2).filter(|s| !s.is_empty()) {
            Some(name) => {
                let (bias, bias_shape) = self.weights(name)?;
                if bias_shape != [oc] {
                    return unsupported(format!("bias shape {bias_shape:?}"));
                }
                bias
            }
            None => vec![0.0; oc],
        };
        if let Some(step) = self.quantized_conv(
            weights_name,
            (buffer, [h, w, c], layout),
            [pads[0], pads[1]],
            [padded_h, padded_w],
            &bias,
            [[strides[0], strides[1]], out],
        )? {
            let to = step.out;
            self.push(output, Step::QuantizedConv(Box::new(step)));
            return self.define_tensor(output, to, vec![1, oc, out[0], out[1]], Layout::Nhwc);
        }
        let relaid = kernel_major(&weights, [oc, c, kh, kw]);
        let padded = self.buffer(padded_len)?;
        self.steps.push(Step::Pad {
            from: buffer,
            to: padded,
            size: [h, w, c],
            origin: [pads[0], pads[1]],
            padded_width: padded_w,
            from_nchw: layout == Layout::Standard,
        });
        let to = self.buffer(elements(&[out[0], out[1], oc])?)?;
        let shape = ConvShape {
            padded_width: padded_w,
            in_channels: c,
            out_channels: oc,
            kernel: [kh, kw],
            stride: [strides[0], strides[1]],
            out,
        };
        self.push(
            output,
            Step::Conv {
                padded,
                weights: AlignedWeights::new(&relaid),
                bias,
                shape,
                relu: false,
                pool: None,
                winograd: None,
                out: to,
            },
        );
        self.define_tensor(output, to, vec![1, oc, out[0], out[1]], Layout::Nhwc)
    }

    pub(super) fn max_pool(&mut self, op: &Operation<'_>) -> Lowered<()> {
        let (attributes, input, output) = (&op.attributes, op.first()?, op.output);
        let (buffer, shape, layout) = self.float_tensor(input, "pooling")?;
        if layout != Layout::Nhwc {
            return unsupported("pooling a map that no convolution made");
        }
        let kernel = positive(attributes.ints("kernel_shape").unwrap_or_default(), 2)?;
        let strides = positive(attributes.ints("strides").unwrap_or(vec![1, 1]), 2)?;
        let pads = attributes.ints("pads").unwrap_or(vec![0; 4]);
        if pads.iter().any(|&p| p != 0)
            || attributes.int("ceil_mode").unwrap_or(0) != 0
            || attributes
                .ints("dilations")
                .is_some_and(|d| d.iter().any(|&d| d != 1))
            || attributes.int("storage_order").unwrap_or(0) != 0
            || attributes.string("auto_pad").is_some_and(|p| p != "NOTSET")
        {
            return unsupported("pooling with padding, ceil mode, dilation or storage order");
        }
        let (c, h, w) = (shape[1], shape[2], shape[3]);
        if h < kernel[0] || w < kernel[1] {
            return unsupported("a pooling window larger than its input");
        }
        let out = [
            (h - kernel[0]) / strides[0] + 1,
            (w - kernel[1]) / strides[1] + 1,
        ];
        let to = self.buffer(elements(&[out[0], out[1], c])?)?;
        let pool = [[kernel[0], kernel[1]], [strides[0], strides[1]], out];
        if let Some(index) = self.fuse_pool(input, buffer, pool, to)? {
            self.producer.insert(output.to_owned(), index);
            return self.define_tensor(output, to, vec![1, c, out[0], out[1]], Layout::Nhwc);
        }
        self.keep_grid(buffer, to);
        self.push(
            output,
            Step::MaxPool {
                from: buffer,
                to,
                shape: PoolShape {
                    size: [h, w, c],
                    kernel: [kernel[0], kernel[1]],
                    stride: [strides[0], strides[1]],
                    out,
                },
            },
        );
        self.define_tensor(output, to, vec![1, c, out[0], out[1]], Layout::Nhwc)
    }
}

/// A convolution's strides and pads (top, left, bottom, right) from its attributes, refusing
/// what the engine does not compute: groups, dilations, `auto_pad`, a `kernel_shape` other
/// than the weights' `[kh, kw]`.
fn conv_geometry(
    attributes: &Attributes<'_>,
    [kh, kw]: [usize; 2],
) -> Lowered<(Vec<usize>, Vec<usize>)> {
    if attributes.int("group").unwrap_or(1) != 1 {
        return unsupported("grouped convolutions");
    }
    if attributes
        .ints("dilations")
        .is_some_and(|d| d.iter().any(|&d| d != 1))
    {
        return unsupported("dilated convolutions");
    }
    if attributes.string("auto_pad").is_some_and(|p| p != "NOTSET") {
        return unsupported("auto_pad");
    }
    if let Some(kernel) = attributes.ints("kernel_shape")
        && kernel != [kh as i64, kw as i64]
    {
        return unsupported("kernel_shape differs from the weights");
    }
    let strides = positive(attributes.ints("strides").unwrap_or(vec![1, 1]), 2)?;
    let pads = non_negative(attributes.ints("pads").unwrap_or(vec![0; 4]), 4)?;
    Ok((strides, pads))
}

/// ONNX's `[oc][c][ky][kx]` weights laid out `[ky][kx][c][oc]`, as the float kernels read them.
fn kernel_major(weights: &[f32], [oc, c, kh, kw]: [usize; 4]) -> Vec<f32> {
    let mut relaid = vec![0.0; weights.len()];
    for o in 0..oc {
        for i in 0..c {
            for y in 0..kh {
                for x in 0..kw {
                    relaid[((y * kw + x) * c + i) * oc + o] =
                        weights[((o * c + i) * kh + y) * kw + x];
                }
            }
        }
    }
    relaid
}
