//! QDQ graphs (DESIGN.md, "Policies": `precision = "int8"`): `QuantizeLinear` and
//! `DequantizeLinear` as onnxruntime's static quantizer writes them, lowered to integer steps.
//!
//! - An integer constant (int8 weights, int32 biases, uint8 or int8 zero points) is kept as
//!   [`Codes`], usable only by a `DequantizeLinear`.
//! - `DequantizeLinear` of a constant gives the float constant the graph means, so every
//!   float lowering still applies; int8 weights with zero points 0 are also kept as
//!   [`IntegerWeights`], which a `Conv` or `Gemm` reading them may take instead.
//! - `QuantizeLinear` of a float value with one scale and a uint8 zero point waits for its
//!   `DequantizeLinear`: the pair rounds the value onto a [`Grid`]. Where the value was made
//!   by an int8 step that only the pair reads, the rounding goes into that step's epilogue;
//!   where the value already lies on the grid, the pair is nothing; else a
//!   [`Step::SnapToGrid`]. The grid is then known of the buffer, and stays known through
//!   what keeps values on it (a reshape, a ReLU, a max-pool, a layout change).
//! - A `Conv` or `Gemm` between [`IntegerWeights`] and an input on a grid becomes a
//!   [`QuantizedConv`] or [`QuantizedDense`]: exact integer sums, then the float the graph
//!   computes from them.

use super::*;
#[cfg(target_arch = "x86_64")]
use crate::policy::engine::kernels::int8::PooledPixelWeights;
use crate::policy::engine::kernels::int8::{Window, ZeroGroups};
use crate::policy::engine::layout::Grid;
use crate::policy::engine::plan::{Epilogue, QuantizedConv, QuantizedDense};

const UINT8: i32 = 2;
const INT8: i32 = 3;
const INT32: i32 = 6;

/// The most inputs an int8 dense row or convolution window may have: 2^16 products of at
/// most 255 x 64 sum to less than 2^30, so neither a 32-bit sum nor its difference from the
/// zero point's term can wrap.
pub(crate) const MAX_INT8_INPUTS: usize = 1 << 16;

/// An integer constant of a QDQ graph.
#[derive(Clone, Debug)]
pub(super) struct Codes {
    element_type: i32,
    values: Vec<i64>,
    shape: Vec<usize>,
}

/// Int8 weights (zero points 0) with their scales along `axis` (one scale: per tensor).
#[derive(Clone, Debug)]
pub(super) struct IntegerWeights {
    values: Vec<i8>,
    shape: Vec<usize>,
    scales: Vec<f32>,
    axis: Option<usize>,
}

impl IntegerWeights {
    /// The scale of each index along `axis` of the weights (`count` of them), where the
    /// weights are per tensor or per channel along that axis.
    fn scales_along(&self, axis: usize, count: usize) -> Option<Vec<f32>> {
        match (self.axis, self.scales.len()) {
            (_, 1) => Some(vec![self.scales[0]; count]),
            (Some(a), n) if a == axis && n == count => Some(self.scales.clone()),
            _ => None,
        }
    }
}

impl Lowerer {
    /// An integer constant other than int64 (which shapes and axes are): kept as [`Codes`].
    pub(super) fn integer_constant(&mut self, tensor: &pb::TensorProto) -> Lowered<Option<Codes>> {
        let width = match tensor.data_type {
            UINT8 | INT8 => 1,
            INT32 => 4,
            _ => return Ok(None),
        };
        let shape = declared_shape(tensor)?;
        let count = if shape.is_empty() {
            1
        } else {
            elements(&shape)?
        };
        let values: Vec<i64> = if tensor.raw_data.is_empty() {
            tensor.int32_data.iter().map(|&v| i64::from(v)).collect()
        } else if tensor.raw_data.len() == count * width {
            match tensor.data_type {
                UINT8 => tensor.raw_data.iter().map(|&b| i64::from(b)).collect(),
                INT8 => tensor
                    .raw_data
                    .iter()
                    .map(|&b| i64::from(b as i8))
                    .collect(),
                _ => tensor
                    .raw_data
                    .chunks_exact(4)
                    .map(|b| i64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])))
                    .collect(),
            }
        } else {
            return unsupported(format!("{} has a ragged raw_data", tensor.name));
        };
        let in_range = match tensor.data_type {
            UINT8 => values.iter().all(|v| (0..=255).contains(v)),
            INT8 => values.iter().all(|v| (-128..=127).contains(v)),
            _ => values.iter().all(|&v| i32::try_from(v).is_ok()),
        };
        if values.len() != count || !in_range {
            return unsupported(format!(
                "{} holds {} integers for shape {shape:?}",
                tensor.name,
                values.len()
            ));
        }
        Ok(Some(Codes {
            element_type: tensor.data_type,
            values,
            shape,
        }))
    }

    /// One float from a constant of one value (a scalar, or any shape of one element).
    fn single_float(&self, name: &str) -> Lowered<f32> {
        match self.weights(name)? {
            (values, _) if values.len() == 1 => Ok(values[0]),
            (values, _) => unsupported(format!(
                "{name} holds {} scales: activations are quantized per tensor here",
                values.len()
            )),
        }
    }

    /// An activation's zero point: one uint8 constant, or 0 where the input is absent;
    /// `None` for anything else.
    fn uint8_zero(&self, name: Option<&String>) -> Option<u8> {
        match name {
            None => Some(0),
            Some(name) => self
                .codes
                .get(name)
                .filter(|codes| codes.element_type == UINT8 && codes.values.len() == 1)
                .and_then(|codes| u8::try_from(codes.values[0]).ok()),
        }
    }

    /// The opset-21 forms (blocked quantization, other output types) are refused.
    fn plain_quantization(attributes: &Attributes<'_>) -> Lowered<()> {
        if attributes.int("block_size").is_some_and(|b| b != 0) {
            return unsupported("blocked quantization");
        }
        if attributes
            .int("output_dtype")
            .is_some_and(|t| t != 0 && t != i64::from(UINT8))
        {
            return unsupported("a quantization to another type than uint8");
        }
        Ok(())
    }

    pub(super) fn quantize_linear(&mut self, op: &Operation<'_>) -> Lowered<()> {
        let (x, scale_name, zero_name) = quantization_inputs(op.node, &op.attributes)?;
        let output = op.output;
        let scale = self.single_float(scale_name)?;
        let zero = self
            .uint8_zero(zero_name)
            .or_unsupported("a zero point that is not one uint8")?;
        let Value::Tensor { boolean: false, .. } = self.value(x)? else {
            return unsupported("quantizing something that is not a float tensor");
        };
        let grid = Grid::new(scale, zero)
            .ok_or_else(|| Unsupported(format!("a quantization scale of {scale}")))?;
        self.pending.insert(output.to_owned(), (x.clone(), grid));
        Ok(())
    }

    pub(super) fn dequantize_linear(&mut self, op: &Operation<'_>) -> Lowered<()> {
        let (q, scale_name, zero_name) = quantization_inputs(op.node, &op.attributes)?;
        let output = op.output;
        if let Some((source, grid)) = self.pending.get(q).cloned() {
            let scale = self.single_float(scale_name)?;
            let zero = self.uint8_zero(zero_name);
            if scale.to_bits() != grid.scale().to_bits() || zero != Some(grid.zero()) {
                return unsupported("a DequantizeLinear on another grid than its QuantizeLinear");
            }
            return self.snap(&source, q, grid, output);
        }
        let Some(codes) = self.codes.get(q).cloned() else {
            return unsupported(format!(
                "{q}: a DequantizeLinear of what no QuantizeLinear or constant gave"
            ));
        };
        let (scales, scale_shape) = self.weights(scale_name)?;
        let rank = codes.shape.len();
        // Per tensor (one scale) or along `axis` (opset 13 on; default 1).
        let axis = if scales.len() == 1 && scale_shape.iter().all(|&d| d == 1) {
            None
        } else {
            let axis = normalise_axis(op.attributes.int("axis").unwrap_or(1), rank)?;
            // A scalar has no axis to hold several scales.
            if rank == 0 || scale_shape != [codes.shape[axis]] {
                return unsupported(format!(
                    "scales of shape {scale_shape:?} for {:?} along axis {axis}",
                    codes.shape
                ));
            }
            Some(axis)
        };
        let zeros = match zero_name {
            None => vec![0; scales.len()],
            Some(name) => match self.codes.get(name) {
                Some(zero)
                    if zero.element_type == codes.element_type
                        && zero.values.len() == scales.len() =>
                {
                    zero.values.clone()
                }
                _ => return unsupported("zero points that do not match the scales"),
            },
        };
        // Index `i`'s channel: its coordinate along the axis.
        let inner: usize = axis.map_or(1, |a| codes.shape[a + 1..].iter().product());
        let channels = scales.len();
        let channel = |i: usize| {
            if axis.is_some() {
                (i / inner) % channels
            } else {
                0
            }
        };
        let values: Vec<f32> = codes
            .values
            .iter()
            .enumerate()
            .map(|(i, &q)| (q - zeros[channel(i)]) as f32 * scales[channel(i)])
            .collect();
        let buffer = self.buffer(values.len())?;
        self.buffers[buffer] = values;
        self.fixed[buffer] = true;
        self.constant[buffer] = true;
        if codes.element_type == INT8 && zeros.iter().all(|&z| z == 0) {
            self.integer_weights.insert(
                output.to_owned(),
                IntegerWeights {
                    values: codes.values.iter().map(|&v| v as i8).collect(),
                    shape: codes.shape.clone(),
                    scales,
                    axis,
                },
            );
        }
        self.define_tensor(output, buffer, codes.shape, Layout::Standard)
    }

    /// `output` is `source` rounded onto `grid` (`pair` names the QuantizeLinear between).
    fn snap(&mut self, source: &str, pair: &str, grid: Grid, output: &str) -> Lowered<()> {
        let value = self.value(source)?.clone();
        let Value::Tensor {
            buffer,
            ref shape,
            layout,
            boolean: false,
        } = value
        else {
            return unsupported("quantizing something that is not a float tensor");
        };
        if self.grids.get(&buffer) == Some(&grid) {
            return self.define(output, value);
        }
        if self.single_reader(source)
            && self.single_reader(pair)
            && let Some(&index) = self.producer.get(source)
        {
            let epilogue = match &mut self.steps[index] {
                Step::QuantizedConv(conv) if conv.out == buffer => Some(&mut conv.epilogue),
                Step::QuantizedDense(dense) if dense.to == buffer => Some(&mut dense.epilogue),
                _ => None,
            };
            if let Some(epilogue) = epilogue.filter(|e| e.output.is_none()) {
                epilogue.output = Some(grid);
                self.grids.insert(buffer, grid);
                self.producer.insert(output.to_owned(), index);
                return self.define(output, value);
            }
        }
        let len = elements(shape)?;
        let to = self.buffer(len)?;
        self.push(
            output,
            Step::SnapToGrid {
                from: buffer,
                to,
                len,
                grid,
            },
        );
        self.grids.insert(to, grid);
        self.define_tensor(output, to, shape.clone(), layout)
    }

    /// The value in `to` is on the grid of `from`'s (a layout change, a pool, a ReLU).
    pub(super) fn keep_grid(&mut self, from: BufferId, to: BufferId) {
        if let Some(&grid) = self.grids.get(&from) {
            self.grids.insert(to, grid);
        }
    }

    /// The epilogue of an int8 layer with `outputs` outputs: weight scales `weight_scales`.
    fn epilogue(
        input: Grid,
        rows: &[i8],
        inputs: usize,
        weight_scales: &[f32],
        bias: Vec<f32>,
    ) -> Epilogue {
        let zero = i32::from(input.zero());
        Epilogue {
            // At most 255 x 64 x 2^16 < 2^30 (MAX_INT8_INPUTS).
            offsets: rows
                .chunks_exact(inputs)
                .map(|row| zero * row.iter().map(|&w| i32::from(w)).sum::<i32>())
                .collect(),
            scales: weight_scales.iter().map(|&s| input.scale() * s).collect(),
            bias,
            relu: false,
            output: None,
        }
    }

    /// A convolution as a [`QuantizedConv`], where its weights are int8 (per output
    /// channel or per tensor) and its input lies on a grid; `None` where not (it is then
    /// lowered in floats, from the same weights dequantized).
    pub(super) fn quantized_conv(
        &mut self,
        weights_name: &str,
        input: (BufferId, [usize; 3], Layout),
        pads: [usize; 2],
        padded: [usize; 2],
        bias: &[f32],
        [strides, out]: [[usize; 2]; 2],
    ) -> Lowered<Option<QuantizedConv>> {
        let (buffer, [h, w, c], layout) = input;
        let (Some(grid), Some(weights)) = (
            self.grids.get(&buffer).copied(),
            self.integer_weights.get(weights_name),
        ) else {
            return Ok(None);
        };
        let [oc, _, kh, kw] = weights.shape[..] else {
            return Ok(None);
        };
        let Some(scales) = weights.scales_along(0, oc) else {
            return Ok(None);
        };
        let window = Window::new(padded[1], c, [kh, kw], strides);
        let inputs = window.padded_len();
        if inputs > MAX_INT8_INPUTS {
            return Ok(None);
        }
        // [oc][c][ky][kx] -> [oc][ky][kx][c], the window's order, then laid out as the
        // window is read (zero weights where they meet padding or the next pixel's bytes).
        let window_len = elements(&[kh, kw, c])?;
        let mut ordered = vec![0i8; elements(&[oc, window_len])?];
        for o in 0..oc {
            for i in 0..c {
                for y in 0..kh {
                    for x in 0..kw {
                        ordered[o * window_len + (y * kw + x) * c + i] =
                            weights.values[((o * c + i) * kh + y) * kw + x];
                    }
                }
            }
        }
        let rows = window.weights(&ordered, oc);
        let Ok(panels) = self.int8.lay_out(&rows, oc, inputs) else {
            return Ok(None);
        };
        // Terms for a whole row of output pixels (a row of pooled outputs is shorter), as
        // many as that row's sums: the size checked before anything that large is made.
        elements(&[oc, out[1]])?;
        let epilogue = Self::epilogue(grid, &rows, inputs, &scales, bias.to_vec()).tiled(out[1]);
        let padded_len = elements(&[padded[0], padded[1], c])?;
        let out_buffer = self.buffer(elements(&[out[0], out[1], oc])?)?;
        Ok(Some(QuantizedConv {
            from: buffer,
            size: [h, w, c],
            from_nchw: layout == Layout::Standard,
            origin: pads,
            input: grid,
            window,
            out_size: out,
            weights: panels,
            kernel: self.int8,
            // The engine writes its own maps NHWC; an NCHW one is an input of the network, a
            // camera's pixels, in which sixteen zero codes in a row are rare.
            zeros: if layout == Layout::Standard {
                ZeroGroups::Compute
            } else {
                ZeroGroups::Skip
            },
            epilogue,
            codes: vec![grid.zero(); padded_len + window.slack()],
            // One row of output pixels' windows and sums ([`QuantizedConv`]).
            windows: vec![0; elements(&[inputs, out[1]])?],
            sums: vec![0; elements(&[oc, out[1]])?],
            out: out_buffer,
            pool: None,
            #[cfg(target_arch = "x86_64")]
            pooled_pixels: PooledPixelWeights::new(&ordered, [oc, c], [kh, kw], strides, padded[1]),
        }))
    }

    /// A Gemm `x (m x k)` times int8 weights (`[n][k]` with `transposed`, else `[k][n]`) as a
    /// [`QuantizedDense`], where `x` lies on a grid and the weights' scales are per output
    /// (or per tensor); `None` where not.
    pub(super) fn quantized_gemm(
        &mut self,
        x: BufferId,
        [m, k, n]: [usize; 3],
        weights_name: &str,
        transposed: bool,
        alpha: f32,
        bias: Vec<f32>,
    ) -> Lowered<Option<QuantizedDense>> {
        let (Some(grid), Some(weights)) = (
            self.grids.get(&x).copied(),
            self.integer_weights.get(weights_name),
        ) else {
            return Ok(None);
        };
        let Some(scales) = weights.scales_along(usize::from(!transposed), n) else {
            return Ok(None);
        };
        if k > MAX_INT8_INPUTS || !alpha.is_finite() {
            return Ok(None);
        }
        let mut rows = vec![0i8; elements(&[n, k])?];
        for (row, weights_row) in rows.chunks_exact_mut(k).enumerate() {
            for (col, w) in weights_row.iter_mut().enumerate() {
                *w = if transposed {
                    weights.values[row * k + col]
                } else {
                    weights.values[col * n + row]
                };
            }
        }
        let Ok(panels) = self.int8.lay_out(&rows, n, k) else {
            return Ok(None);
        };
        let padded_inputs = panels.padded_inputs();
        let scales: Vec<f32> = scales.iter().map(|&s| alpha * s).collect();
        let epilogue = Self::epilogue(grid, &rows, k, &scales, bias);
        let to = self.buffer(elements(&[m, n])?)?;
        Ok(Some(QuantizedDense {
            from: x,
            input: grid,
            rows: m,
            weights: panels,
            kernel: self.int8,
            epilogue,
            codes: vec![0; padded_inputs],
            sums: vec![0; n],
            to,
        }))
    }
}

/// Takes out each [`Step::SnapToGrid`] whose only reader is an int8 step coding its input on
/// that same grid: the int8 step codes the unsnapped numbers instead. The codes are the
/// same: the snap of `x` is the grid value of `x`'s code, and a grid value's code is that
/// code again (checked for all 256 codes before the step goes; a grid where rounding broke
/// it keeps its snap). One pass over the map fewer per layer, no float map written and read
/// back (the camera inputs, the pooled maps, the features: five of the int8 CNN's passes).
pub(super) fn fold_snaps(steps: &mut Vec<Step>, outputs: &[(String, BufferId, usize)]) {
    let mut index = 0;
    while index < steps.len() {
        let Step::SnapToGrid { from, to, grid, .. } = steps[index] else {
            index += 1;
            continue;
        };
        let round_trip = (0..=255u8).all(|code| {
            let value = f32::from(i16::from(code) - i16::from(grid.zero())) * grid.scale();
            grid.code(value) == code
        });
        let is_output = outputs.iter().any(|&(_, buffer, _)| buffer == to);
        let readers: Vec<usize> = (index + 1..steps.len())
            .filter(|&j| steps[j].buffers().0.contains(&to))
            .collect();
        let folded = match (round_trip && !is_output, readers.as_slice()) {
            (true, &[reader]) => match &mut steps[reader] {
                Step::QuantizedConv(conv) if conv.from == to && conv.input == grid => {
                    conv.from = from;
                    true
                }
                Step::QuantizedDense(dense) if dense.from == to && dense.input == grid => {
                    dense.from = from;
                    true
                }
                _ => false,
            },
            _ => false,
        };
        if folded {
            steps.remove(index);
        } else {
            index += 1;
        }
    }
}

/// A QuantizeLinear's or DequantizeLinear's inputs by name (the value, its scale, its zero
/// point where given), once its attributes ask for nothing but the plain per-tensor or
/// per-axis uint8 quantization.
fn quantization_inputs<'n>(
    node: &'n pb::NodeProto,
    attributes: &Attributes<'_>,
) -> Lowered<(&'n String, &'n String, Option<&'n String>)> {
    Lowerer::plain_quantization(attributes)?;
    let input = |i: usize| node.input.get(i).filter(|s| !s.is_empty());
    let value = input(0).or_unsupported("no input")?;
    let scale = input(1).or_unsupported("no scale")?;
    Ok((value, scale, input(2)))
}
