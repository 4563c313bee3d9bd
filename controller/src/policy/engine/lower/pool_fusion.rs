//! Pool fusion: a max-pool folded into the convolution that made its input, so the
//! convolution writes the pooled map and the full-size map is never stored.
//!
//! Where it applies: only the pool reads the convolution's output and its windows do not
//! overlap (stride at least the window). A float convolution then pools each band of rows as
//! it computes them (`ConvPool`, with Winograd's F(2x2, 3x3) where the instruction set's
//! kernels take the layer: [`super::super::kernels::winograd`]); an int8 convolution takes the
//! largest of the window's integer sums before its epilogue (`QuantizedPool`), which gives
//! the separate pool's numbers bit for bit where the epilogue is monotonic. Anything else
//! stays a `MaxPool` step of its own ([`super::conv`]).

use super::*;
#[cfg(target_arch = "x86_64")]
use crate::policy::engine::kernels::single_channel_pool;

/// A max-pool's window, stride and output size, `[[kh, kw], [sh, sw], [oh, ow]]`.
pub(super) type PoolShape = [[usize; 2]; 3];

impl Lowerer {
    /// Folds the pool (reading `input`, held in `buffer`, writing `to`) into the
    /// convolution that made `input` where it can; the index of the step it folded into.
    pub(super) fn fuse_pool(
        &mut self,
        input: &str,
        buffer: BufferId,
        pool: PoolShape,
        to: BufferId,
    ) -> Lowered<Option<usize>> {
        if let Some(index) = self.fold_pool_into_int8_conv(input, buffer, pool, to) {
            self.keep_grid(buffer, to);
            return Ok(Some(index));
        }
        self.fold_pool_into_float_conv(input, pool, to)
    }

    /// Folds the pool into the float convolution that made `input` (`ConvPool`), choosing
    /// Winograd for the pair where the instruction set's kernels take its channels.
    fn fold_pool_into_float_conv(
        &mut self,
        input: &str,
        [kernel, strides, out]: PoolShape,
        to: BufferId,
    ) -> Lowered<Option<usize>> {
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
        let Some((index, scratch_len)) = fold else {
            return Ok(None);
        };
        let scratch = self.buffer(scratch_len)?;
        let fit = self.winograd;
        let mut winograd_buffers = None;
        // Only x86-64 has the single-channel pool that sets it.
        #[cfg_attr(not(target_arch = "x86_64"), allow(unused_mut))]
        let mut planes_len = None;
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
                planes: None,
            });
            let (ic, oc) = (shape.in_channels, shape.out_channels);
            let row = shape.padded_width * ic;
            let padded_rows = self.buffers[*padded].len() / row.max(1);
            #[cfg(target_arch = "x86_64")]
            if single_channel_pool::takes(ic, oc, shape.stride, [kernel, strides]) {
                planes_len = single_channel_pool::planes_len(padded_rows, shape.padded_width);
            }
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
        if let Some(len) = planes_len {
            let planes = self.buffer(len)?;
            if let Step::Conv {
                pool: Some(pool), ..
            } = &mut self.steps[index]
            {
                pool.planes = Some(planes);
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
        Ok(Some(index))
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
        [kernel, strides, out]: PoolShape,
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
