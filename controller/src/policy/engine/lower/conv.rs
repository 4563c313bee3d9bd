//! Convolutions and max-pools: a Conv (with the ReLU and the pool after it folded in where
//! the graph has them, by Winograd where the instruction set's kernels take the layer) and a
//! MaxPool on its own.

use super::*;

impl Lowerer {
    pub(super) fn conv(
        &mut self,
        node: &pb::NodeProto,
        attributes: &Attributes<'_>,
        input: &str,
        output: &str,
    ) -> Lowered<()> {
        let value = self.value(input)?.clone();
        let Value::Tensor {
            buffer,
            shape,
            layout,
            boolean: false,
        } = value
        else {
            return unsupported("a convolution of something that is not a float tensor");
        };
        let weights_name = node
            .input
            .get(1)
            .ok_or_else(|| Unsupported("no weights".into()))?;
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
        // [oc][c][ky][kx] -> [ky][kx][c][oc]
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

    pub(super) fn max_pool(
        &mut self,
        attributes: &Attributes<'_>,
        input: &str,
        output: &str,
    ) -> Lowered<()> {
        let value = self.value(input)?.clone();
        let Value::Tensor {
            buffer,
            shape,
            layout,
            boolean: false,
        } = value
        else {
            return unsupported("pooling something that is not a float tensor");
        };
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
        if let Some(index) = self.fold_pool_into_int8_conv(
            input,
            buffer,
            [[kernel[0], kernel[1]], [strides[0], strides[1]], out],
            to,
        ) {
            self.producer.insert(output.to_owned(), index);
            self.keep_grid(buffer, to);
            return self.define_tensor(output, to, vec![1, c, out[0], out[1]], Layout::Nhwc);
        }
        // A pool right after a convolution that only it reads is folded into that step
        // (`ConvPool`), where its windows do not overlap vertically.
        let fold = match self.producer.get(input) {
            Some(&index) if strides[0] >= kernel[0] && self.single_reader(input) => {
                match &self.steps[index] {
                    Step::Conv {
                        shape, pool: None, ..
                    } => Some((
                        index,
                        elements(&[kernel[0], shape.out[1], shape.out_channels])?,
                    )),
                    _ => None,
                }
            }
            _ => None,
        };
        if let Some((index, scratch_len)) = fold {
            let scratch = self.buffer(scratch_len)?;
            let fit = self.winograd;
            let mut winograd_buffers = None;
            if let Step::Conv {
                padded,
                weights,
                shape,
                pool,
                winograd,
                out: conv_out,
                ..
            } = &mut self.steps[index]
            {
                *conv_out = to;
                *pool = Some(ConvPool {
                    kernel: [kernel[0], kernel[1]],
                    stride: [strides[0], strides[1]],
                    out,
                    scratch,
                });
                let (ic, oc) = (shape.in_channels, shape.out_channels);
                let row = shape.padded_width * ic;
                let padded_rows = self.buffers[*padded].len() / row.max(1);
                let layer = fit.filter(|fit| fit.takes(ic, oc)).and_then(|_| {
                    winograd::Layer::new(
                        [shape.kernel, shape.stride],
                        [[kernel[0], kernel[1]], [strides[0], strides[1]]],
                        [shape.padded_width, padded_rows],
                        [ic, oc],
                        out,
                    )
                });
                if let Some(layer) = layer {
                    // The rows past the padding that the last tiles read: zero, as the
                    // border is (the padding step writes only the map's own rows).
                    let needed = layer.padded_rows_needed() * row;
                    if self.buffers[*padded].len() < needed {
                        self.allocated += needed - self.buffers[*padded].len();
                        self.buffers[*padded].resize(needed, 0.0);
                    }
                    *winograd = Some(WinogradConv {
                        layer,
                        weights: winograd::transform_weights(weights.as_slice(), ic, oc),
                        transformed: 0,
                        products: 0,
                    });
                    winograd_buffers = Some(layer.scratch());
                }
            }
            if let Some([transformed_len, products_len]) = winograd_buffers {
                let (transformed, products) =
                    (self.buffer(transformed_len)?, self.buffer(products_len)?);
                if let Step::Conv {
                    winograd: Some(winograd),
                    ..
                } = &mut self.steps[index]
                {
                    winograd.transformed = transformed;
                    winograd.products = products;
                }
            }
            self.producer.insert(output.to_owned(), index);
            return self.define_tensor(output, to, vec![1, c, out[0], out[1]], Layout::Nhwc);
        }
        self.keep_grid(buffer, to);
        self.push(
            output,
            Step::MaxPool {
                from: buffer,
                to,
                size: [h, w, c],
                kernel: [kernel[0], kernel[1]],
                stride: [strides[0], strides[1]],
                out,
            },
        );
        self.define_tensor(output, to, vec![1, c, out[0], out[1]], Layout::Nhwc)
    }

    /// Folds a max-pool into the int8 convolution that made `buffer` (`QuantizedPool`) where
    /// only the pool reads it, its windows do not overlap, and the epilogue is monotonic
    /// (every scale positive and finite, every bias finite: then the largest sum's epilogue
    /// is the largest epilogue). The convolution then writes the pooled map into `to`, and
    /// its full-size output is given back. The convolution's step where it folded.
    fn fold_pool_into_int8_conv(
        &mut self,
        input: &str,
        buffer: BufferId,
        [kernel, strides, out]: [[usize; 2]; 3],
        to: BufferId,
    ) -> Option<usize> {
        let &index = self.producer.get(input)?;
        if !self.single_reader(input) || strides[0] < kernel[0] || strides[1] < kernel[1] {
            return None;
        }
        let Step::QuantizedConv(conv) = &mut self.steps[index] else {
            return None;
        };
        let monotonic = conv
            .epilogue
            .scales
            .iter()
            .all(|s| s.is_finite() && *s > 0.0)
            && conv.epilogue.bias.iter().all(|b| b.is_finite());
        if conv.out != buffer || conv.pool.is_some() || !monotonic {
            return None;
        }
        conv.pool = Some(QuantizedPool {
            kernel,
            stride: strides,
            out,
        });
        // Room for a row of pool cells' windows, copied one after the other, and their sums.
        conv.windows = vec![0; kernel[0] * kernel[1] * conv.window.padded_len() * out[1]];
        conv.sums = vec![0; conv.weights.outputs() * out[1]];
        conv.out = to;
        let full = std::mem::take(&mut self.buffers[buffer]);
        self.allocated = self.allocated.saturating_sub(full.len());
        Some(index)
    }
}
