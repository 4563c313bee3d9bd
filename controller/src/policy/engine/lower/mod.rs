//! Lowering: an ONNX graph (already read and checked by tract) becomes a static list of
//! [`Step`]s over buffers sized at load. Shapes are fixed by the controller's inputs, so every
//! shape, index and weight layout is worked out here, once; running the plan is arithmetic
//! and nothing else.
//!
//! The operators lowered are those of the paper's networks and their exports: Conv (any
//! stride and padding, group 1), Relu, MaxPool, Flatten, Reshape, Squeeze, Unsqueeze,
//! Transpose, Gather (constant indices), Concat, Gemm, MatMul (constant right side, with a
//! following Add folded into the bias), one LSTM step (forward, default activations), the
//! element-wise Add, Sub, Mul, Div, Equal with broadcasting, ReduceMax, ReduceSum, Cast to
//! float, Identity and Constant. Anything else is refused with the reason, and the
//! network runs under tract instead.
//!
//! A model file is input from outside: every dimension, attribute and index it declares is
//! checked here before any arithmetic uses it. Each tensor the plan computes has no empty
//! dimension and at most [`MAX_ELEMENTS`] numbers, the plan at most [`MAX_PLAN_ELEMENTS`] in
//! all, and sizes are combined with checked arithmetic, so no product wraps on a 32-bit
//! robot or a 64-bit host and every offset a kernel computes lies inside its buffer.
//! Attributes follow the operator set the file declares (`axes` became an input of
//! Squeeze, Unsqueeze and ReduceSum at 13, of ReduceMax at 18): the lowering reads an
//! operator as tract does at that opset, and refuses the forms it does not know.

use std::collections::HashMap;

use tract_onnx::pb;

use super::kernels::ConvShape;
use super::plan::{
    AlignedWeights, BinaryOp, BufferId, ConvPool, DenseWeights, MAX_RANK, ReduceOp, Step, Strided,
    WinogradConv,
};
use super::winograd;

/// Why a graph cannot be lowered (it then runs under tract).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Unsupported(pub String);

type Lowered<T> = Result<T, Unsupported>;

/// The most numbers one tensor of the plan may hold: 2^24 (64 MiB of floats), over 50 times
/// the largest of the paper's networks (the 2560x128 dense weights).
pub const MAX_ELEMENTS: usize = 1 << 24;

/// The most numbers all buffers of one plan may hold together (256 MiB of floats).
pub const MAX_PLAN_ELEMENTS: usize = 1 << 26;

/// The number of elements of `shape`, refused when a dimension is empty or the count passes
/// [`MAX_ELEMENTS`] (checked, so a declared shape cannot wrap it).
pub(crate) fn elements(shape: &[usize]) -> Lowered<usize> {
    let count = shape
        .iter()
        .try_fold(1usize, |count, &d| count.checked_mul(d))
        .filter(|&count| count <= MAX_ELEMENTS);
    match count {
        Some(count) if count > 0 => Ok(count),
        Some(_) => unsupported(format!("an empty tensor of shape {shape:?}")),
        None => unsupported(format!(
            "a tensor of shape {shape:?}: more than {MAX_ELEMENTS} numbers"
        )),
    }
}

/// A dimension, size, stride or padding declared in the file, as a `usize` no larger than
/// [`MAX_ELEMENTS`].
fn dimension(value: i64) -> Lowered<usize> {
    usize::try_from(value)
        .ok()
        .filter(|&v| v <= MAX_ELEMENTS)
        .ok_or_else(|| Unsupported(format!("size {value}")))
}

fn unsupported<T>(why: impl Into<String>) -> Lowered<T> {
    Err(Unsupported(why.into()))
}

/// How a float value's numbers lie in its buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Layout {
    /// Row-major in the ONNX shape's order.
    Standard,
    /// A `[1, C, H, W]` value stored as `[H][W][C]` (the convolution kernels' layout).
    Nhwc,
}

#[derive(Clone, Debug)]
enum Value {
    /// Numbers at run time: floats, or booleans stored as 0.0 and 1.0.
    Tensor {
        buffer: BufferId,
        shape: Vec<usize>,
        layout: Layout,
        boolean: bool,
    },
    /// Integers known at load (shapes, axes, indices).
    Ints { values: Vec<i64>, shape: Vec<usize> },
}

/// A lowered graph: steps, the buffers they use (with constants filled in), where the
/// inputs go and the outputs come from.
#[derive(Debug)]
pub(crate) struct Lowering {
    pub steps: Vec<Step>,
    pub buffers: Vec<Vec<f32>>,
    pub inputs: Vec<(String, BufferId)>,
    pub outputs: Vec<(String, BufferId, usize)>,
}

struct Lowerer {
    values: HashMap<String, Value>,
    buffers: Vec<Vec<f32>>,
    steps: Vec<Step>,
    /// How many nodes (and graph outputs) read each value.
    readers: HashMap<String, usize>,
    /// The step that wrote a value, for folding an Add or a Relu into it.
    producer: HashMap<String, usize>,
    /// Buffers whose contents are constants or graph inputs: never written by a step.
    fixed: Vec<bool>,
    /// Buffers whose contents are the file's constants (known at load): only these may be
    /// folded into a step as weights. A graph input is fixed but not constant.
    constant: Vec<bool>,
    /// Numbers in all buffers so far (at most [`MAX_PLAN_ELEMENTS`]).
    allocated: usize,
    /// The file's operator set (default domain), which decides where some operators keep
    /// their axes.
    opset: i64,
    /// The widest panel of a dense layer's weights.
    dense_width: usize,
    /// The kernels' lanes for the Winograd convolution ([`super::Isa::winograd_lanes`]).
    winograd_lanes: Option<usize>,
}

/// Lowers `graph` for inputs of the given shapes;
/// `dense_width`: the most outputs a dense layer's weight panel holds (the kernels' choice,
/// [`super::Isa::dense_panel_width`]); `winograd_lanes`: whether the kernels take 5x5
/// stride-two convolutions with their 2x2 pool by [`super::winograd`], and in vectors of
/// how many lanes.
pub(crate) fn lower(
    model: &pb::ModelProto,
    inputs: &[(&str, &[usize])],
    dense_width: usize,
    winograd_lanes: Option<usize>,
) -> Lowered<Lowering> {
    let graph = model
        .graph
        .as_ref()
        .ok_or_else(|| Unsupported("no graph".into()))?;
    let opset = model
        .opset_import
        .iter()
        .find(|import| import.domain.is_empty() || import.domain == "ai.onnx")
        .map(|import| import.version)
        .ok_or_else(|| Unsupported("no operator set for the default domain".into()))?;
    let mut lowerer = Lowerer {
        values: HashMap::new(),
        buffers: Vec::new(),
        steps: Vec::new(),
        readers: HashMap::new(),
        producer: HashMap::new(),
        fixed: Vec::new(),
        constant: Vec::new(),
        allocated: 0,
        opset,
        dense_width,
        winograd_lanes,
    };
    for node in &graph.node {
        for input in node.input.iter().filter(|i| !i.is_empty()) {
            *lowerer.readers.entry(input.clone()).or_default() += 1;
        }
    }
    for output in &graph.output {
        *lowerer.readers.entry(output.name.clone()).or_default() += 1;
    }
    for initializer in &graph.initializer {
        let value = lowerer.constant(initializer)?;
        lowerer.values.insert(initializer.name.clone(), value);
    }
    let mut input_buffers = Vec::new();
    for (name, shape) in inputs {
        let buffer = lowerer.buffer(elements(shape)?)?;
        lowerer.fixed[buffer] = true;
        lowerer.values.insert(
            (*name).to_owned(),
            Value::Tensor {
                buffer,
                shape: shape.to_vec(),
                layout: Layout::Standard,
                boolean: false,
            },
        );
        input_buffers.push(((*name).to_owned(), buffer));
    }
    for node in &graph.node {
        lowerer.node(node).map_err(|Unsupported(why)| {
            Unsupported(format!("{} ({}): {why}", node.op_type, node.name))
        })?;
    }
    let mut outputs = Vec::new();
    for output in &graph.output {
        let value = lowerer.standard(&output.name)?;
        let Value::Tensor { buffer, shape, .. } = value else {
            return unsupported(format!("output {} is a constant", output.name));
        };
        outputs.push((output.name.clone(), buffer, shape.iter().product()));
    }
    Ok(Lowering {
        steps: lowerer.steps,
        buffers: lowerer.buffers,
        inputs: input_buffers,
        outputs,
    })
}

impl Lowerer {
    /// A new zeroed buffer of `len` numbers, within the plan's limits.
    fn buffer(&mut self, len: usize) -> Lowered<BufferId> {
        let allocated = self
            .allocated
            .checked_add(len)
            .filter(|&all| len <= MAX_ELEMENTS && all <= MAX_PLAN_ELEMENTS)
            .ok_or_else(|| {
                Unsupported(format!(
                    "a plan of more than {MAX_PLAN_ELEMENTS} numbers (a buffer of {len})"
                ))
            })?;
        self.allocated = allocated;
        self.buffers.push(vec![0.0; len]);
        self.fixed.push(false);
        self.constant.push(false);
        Ok(self.buffers.len() - 1)
    }

    fn constant(&mut self, tensor: &pb::TensorProto) -> Lowered<Value> {
        const FLOAT: i32 = 1;
        const INT64: i32 = 7;
        if tensor.data_location == Some(1) {
            return unsupported(format!(
                "{} keeps its data in an external file",
                tensor.name
            ));
        }
        let shape = tensor
            .dims
            .iter()
            .map(|&d| dimension(d))
            .collect::<Lowered<Vec<usize>>>()?;
        if shape.len() > MAX_RANK {
            return unsupported(format!("{} has rank {}", tensor.name, shape.len()));
        }
        // Integer constants may be empty (no axes); float ones become buffers.
        let count = match tensor.data_type {
            FLOAT => elements(&shape)?,
            _ => shape
                .iter()
                .try_fold(1usize, |count, &d| count.checked_mul(d))
                .filter(|&count| count <= MAX_ELEMENTS)
                .ok_or_else(|| Unsupported(format!("{} of shape {shape:?}", tensor.name)))?,
        };
        match tensor.data_type {
            FLOAT => {
                if !tensor.raw_data.is_empty() && tensor.raw_data.len() != count * 4 {
                    return unsupported(format!("{} has a ragged raw_data", tensor.name));
                }
                let values: Vec<f32> = if tensor.raw_data.is_empty() {
                    tensor.float_data.clone()
                } else {
                    tensor
                        .raw_data
                        .chunks_exact(4)
                        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                        .collect()
                };
                if values.len() != count {
                    return unsupported(format!(
                        "{} holds {} numbers for shape {shape:?}",
                        tensor.name,
                        values.len()
                    ));
                }
                let buffer = self.buffer(values.len())?;
                self.buffers[buffer] = values;
                self.fixed[buffer] = true;
                self.constant[buffer] = true;
                Ok(Value::Tensor {
                    buffer,
                    shape,
                    layout: Layout::Standard,
                    boolean: false,
                })
            }
            INT64 => {
                if !tensor.raw_data.is_empty() && tensor.raw_data.len() != count * 8 {
                    return unsupported(format!("{} has a ragged raw_data", tensor.name));
                }
                let values: Vec<i64> = if tensor.raw_data.is_empty() {
                    tensor.int64_data.clone()
                } else {
                    tensor
                        .raw_data
                        .chunks_exact(8)
                        .map(|b| {
                            i64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]])
                        })
                        .collect()
                };
                if values.len() != count {
                    return unsupported(format!(
                        "{} holds {} integers for shape {shape:?}",
                        tensor.name,
                        values.len()
                    ));
                }
                Ok(Value::Ints { values, shape })
            }
            other => unsupported(format!("{} has element type {other}", tensor.name)),
        }
    }

    fn value(&self, name: &str) -> Lowered<&Value> {
        self.values
            .get(name)
            .ok_or_else(|| Unsupported(format!("{name} is not computed before it is used")))
    }

    /// The float tensor `name`, in the standard layout (converted from NHWC if need be).
    fn standard(&mut self, name: &str) -> Lowered<Value> {
        let value = self.value(name)?.clone();
        match value {
            Value::Tensor {
                buffer,
                ref shape,
                layout: Layout::Nhwc,
                boolean,
            } => {
                let (c, h, w) = (shape[1], shape[2], shape[3]);
                let to = self.buffer(elements(shape)?)?;
                self.steps.push(Step::NhwcToNchw {
                    from: buffer,
                    to,
                    size: [h, w, c],
                });
                let converted = Value::Tensor {
                    buffer: to,
                    shape: shape.clone(),
                    layout: Layout::Standard,
                    boolean,
                };
                self.values.insert(name.to_owned(), converted.clone());
                Ok(converted)
            }
            other => Ok(other),
        }
    }

    fn tensor(&mut self, name: &str) -> Lowered<(BufferId, Vec<usize>)> {
        match self.standard(name)? {
            Value::Tensor { buffer, shape, .. } => Ok((buffer, shape)),
            Value::Ints { .. } => unsupported(format!("{name} is an integer constant")),
        }
    }

    fn ints(&self, name: &str) -> Lowered<Vec<i64>> {
        match self.value(name)? {
            Value::Ints { values, .. } => Ok(values.clone()),
            Value::Tensor { .. } => unsupported(format!("{name} must be an integer constant")),
        }
    }

    /// A float constant's numbers (weights).
    fn weights(&self, name: &str) -> Lowered<(Vec<f32>, Vec<usize>)> {
        match self.value(name)? {
            Value::Tensor {
                buffer,
                shape,
                layout: Layout::Standard,
                boolean: false,
            } if self.constant[*buffer] => Ok((self.buffers[*buffer].clone(), shape.clone())),
            _ => unsupported(format!("{name} must be a float constant")),
        }
    }

    /// Names `value`. A tensor's shape must hold between one and [`MAX_ELEMENTS`] numbers
    /// (and its buffer as many): every size later derived from it stays in range.
    fn define(&mut self, name: &str, value: Value) -> Lowered<()> {
        if let Value::Tensor { buffer, shape, .. } = &value {
            let count = elements(shape)?;
            if shape.len() > MAX_RANK || self.buffers[*buffer].len() < count {
                return unsupported(format!("{name}: shape {shape:?} for its buffer"));
            }
        }
        self.values.insert(name.to_owned(), value);
        Ok(())
    }

    fn define_tensor(
        &mut self,
        name: &str,
        buffer: BufferId,
        shape: Vec<usize>,
        layout: Layout,
    ) -> Lowered<()> {
        self.define(
            name,
            Value::Tensor {
                buffer,
                shape,
                layout,
                boolean: false,
            },
        )
    }

    fn push(&mut self, output: &str, step: Step) {
        self.producer.insert(output.to_owned(), self.steps.len());
        self.steps.push(step);
    }

    fn single_reader(&self, name: &str) -> bool {
        self.readers.get(name).copied() == Some(1)
    }

    fn node(&mut self, node: &pb::NodeProto) -> Lowered<()> {
        if !node.domain.is_empty() && node.domain != "ai.onnx" {
            return unsupported(format!("operator domain {}", node.domain));
        }
        let attributes = Attributes(&node.attribute);
        let input = |i: usize| {
            node.input
                .get(i)
                .map(String::as_str)
                .filter(|s| !s.is_empty())
        };
        let first = || input(0).ok_or_else(|| Unsupported("no input".into()));
        let output = node
            .output
            .first()
            .map(String::as_str)
            .ok_or_else(|| Unsupported("no output".into()))?;
        match node.op_type.as_str() {
            "Constant" => {
                let Some(tensor) = attributes.tensor("value") else {
                    return unsupported("a Constant without a tensor value");
                };
                let value = self.constant(tensor)?;
                self.define(output, value)?;
            }
            "Identity" => {
                let value = self.value(first()?)?.clone();
                self.define(output, value)?;
            }
            "Conv" => self.conv(node, &attributes, first()?, output)?,
            "MaxPool" => self.max_pool(&attributes, first()?, output)?,
            "Relu" => self.relu(first()?, output)?,
            "Flatten" => {
                let (buffer, shape) = self.tensor(first()?)?;
                // Axis in [-rank, rank]: a negative one counts from the end, rank itself
                // leaves an inner dimension of 1.
                let rank = shape.len();
                let axis = attributes.int("axis").unwrap_or(1);
                let axis = if axis < 0 { axis + rank as i64 } else { axis };
                let axis = usize::try_from(axis)
                    .ok()
                    .filter(|&a| a <= rank)
                    .ok_or_else(|| Unsupported(format!("Flatten axis {axis} of rank {rank}")))?;
                let outer: usize = shape[..axis].iter().product();
                let inner: usize = shape[axis..].iter().product();
                self.define_tensor(output, buffer, vec![outer, inner], Layout::Standard)?;
            }
            "Reshape" => {
                let (buffer, shape) = self.tensor(first()?)?;
                let target = self.ints(input(1).ok_or_else(|| Unsupported("no shape".into()))?)?;
                let reshaped = reshape(
                    &shape,
                    &target,
                    attributes.int("allowzero").unwrap_or(0) != 0,
                )?;
                self.alias(first()?, output, buffer, reshaped)?;
            }
            "Squeeze" | "Unsqueeze" => {
                let value = self.standard(first()?)?;
                let axes = self.axes(&attributes, input(1), 13)?;
                let squeeze = node.op_type == "Squeeze";
                if !squeeze && axes.is_empty() {
                    return unsupported("an Unsqueeze without axes");
                }
                match value {
                    Value::Tensor { buffer, shape, .. } => {
                        let reshaped = squeeze_shape(&shape, &axes, squeeze)?;
                        self.alias(first()?, output, buffer, reshaped)?;
                    }
                    Value::Ints { values, shape } => {
                        let reshaped = squeeze_shape(&shape, &axes, squeeze)?;
                        self.define(
                            output,
                            Value::Ints {
                                values,
                                shape: reshaped,
                            },
                        )?;
                    }
                }
            }
            "Transpose" => self.transpose(&attributes, first()?, output)?,
            "Gather" => self.gather(&attributes, first()?, input(1), output)?,
            "Concat" => self.concat(node, &attributes, output)?,
            "Gemm" => self.gemm(node, &attributes, output)?,
            "MatMul" => self.matmul(first()?, input(1), output)?,
            "Add" | "Sub" | "Mul" | "Div" | "Equal" => {
                self.binary(&node.op_type, first()?, input(1), output)?
            }
            "ReduceMax" | "ReduceSum" => {
                self.reduce(node, &attributes, first()?, input(1), output)?
            }
            "Cast" => {
                if attributes.int("to") != Some(1) {
                    return unsupported("a cast to anything but float");
                }
                match self.standard(first()?)? {
                    Value::Tensor { buffer, shape, .. } => {
                        self.define_tensor(output, buffer, shape, Layout::Standard)?
                    }
                    Value::Ints { .. } => return unsupported("a cast of integers"),
                }
            }
            "LSTM" => self.lstm(node, &attributes)?,
            other => return unsupported(format!("the operator {other} is not in the engine")),
        }
        Ok(())
    }

    /// `output` is `input`'s numbers under another shape: no copy.
    fn alias(
        &mut self,
        input: &str,
        output: &str,
        buffer: BufferId,
        shape: Vec<usize>,
    ) -> Lowered<()> {
        let boolean = matches!(self.value(input)?, Value::Tensor { boolean: true, .. });
        self.define(
            output,
            Value::Tensor {
                buffer,
                shape,
                layout: Layout::Standard,
                boolean,
            },
        )
    }

    /// The `axes` of a Squeeze, Unsqueeze or Reduce: an attribute before `input_from` (the
    /// operator set that made it an input), the constant second input from then on.
    fn axes(
        &self,
        attributes: &Attributes<'_>,
        input: Option<&str>,
        input_from: i64,
    ) -> Lowered<Vec<i64>> {
        let attribute = attributes.ints("axes");
        if self.opset >= input_from {
            if attribute.is_some() {
                return unsupported(format!(
                    "an axes attribute at opset {} (an input from {input_from})",
                    self.opset
                ));
            }
            input.map_or(Ok(Vec::new()), |name| self.ints(name))
        } else {
            if input.is_some() {
                return unsupported(format!(
                    "an axes input at opset {} (an attribute before {input_from})",
                    self.opset
                ));
            }
            Ok(attribute.unwrap_or_default())
        }
    }

    fn conv(
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

    fn max_pool(&mut self, attributes: &Attributes<'_>, input: &str, output: &str) -> Lowered<()> {
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
            let lanes = self.winograd_lanes;
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
                let layer = lanes
                    .filter(|&lanes| ic.is_multiple_of(lanes) && oc.is_multiple_of(2 * lanes))
                    .and_then(|_| {
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

    /// A Relu right after a convolution or a dense layer that only it reads is folded into
    /// that step; otherwise it is a step of its own.
    fn relu(&mut self, input: &str, output: &str) -> Lowered<()> {
        if self.single_reader(input)
            && let Some(&index) = self.producer.get(input)
        {
            let folded = match &mut self.steps[index] {
                Step::Conv { relu, .. } | Step::Dense { relu, .. } => {
                    *relu = true;
                    true
                }
                _ => false,
            };
            if folded {
                let value = self.value(input)?.clone();
                self.producer.insert(output.to_owned(), index);
                return self.define(output, value);
            }
        }
        let value = self.value(input)?.clone();
        let Value::Tensor {
            buffer,
            shape,
            layout,
            boolean: false,
        } = value
        else {
            return unsupported("a Relu of something that is not a float tensor");
        };
        let len = elements(&shape)?;
        let to = self.buffer(len)?;
        self.push(
            output,
            Step::Relu {
                from: buffer,
                to,
                len,
            },
        );
        self.define_tensor(output, to, shape, layout)
    }

    fn transpose(&mut self, attributes: &Attributes<'_>, input: &str, output: &str) -> Lowered<()> {
        let (buffer, shape) = self.tensor(input)?;
        let rank = shape.len();
        let perm: Vec<usize> = match attributes.ints("perm") {
            Some(perm) => perm.iter().map(|&p| dimension(p)).collect::<Lowered<_>>()?,
            None => (0..rank).rev().collect(),
        };
        let mut sorted = perm.clone();
        sorted.sort_unstable();
        if sorted != (0..rank).collect::<Vec<_>>() {
            return unsupported(format!("perm {perm:?} for rank {rank}"));
        }
        let transposed: Vec<usize> = perm.iter().map(|&p| shape[p]).collect();
        // Moving only dimensions of size 1 leaves the numbers where they are.
        let moved: Vec<usize> = perm.iter().copied().filter(|&p| shape[p] != 1).collect();
        if moved.windows(2).all(|w| w[0] < w[1]) {
            return self.alias(input, output, buffer, transposed);
        }
        if rank > MAX_RANK {
            return unsupported(format!("rank {rank}"));
        }
        let strides = standard_strides(&shape);
        let to = self.buffer(elements(&shape)?)?;
        let source = Strided::new(
            &transposed,
            &perm.iter().map(|&p| strides[p]).collect::<Vec<_>>(),
        );
        self.push(
            output,
            Step::Gather {
                from: buffer,
                source,
                to,
            },
        );
        self.define_tensor(output, to, transposed, Layout::Standard)
    }

    fn gather(
        &mut self,
        attributes: &Attributes<'_>,
        input: &str,
        indices: Option<&str>,
        output: &str,
    ) -> Lowered<()> {
        let (buffer, shape) = self.tensor(input)?;
        let indices_name = indices.ok_or_else(|| Unsupported("no indices".into()))?;
        let Value::Ints {
            values,
            shape: index_shape,
        } = self.value(indices_name)?.clone()
        else {
            return unsupported("indices that are not constants");
        };
        let axis = normalise_axis(attributes.int("axis").unwrap_or(0), shape.len())?;
        let dim = shape[axis];
        let picked = values
            .iter()
            .map(|&i| {
                let i = if i < 0 { i + dim as i64 } else { i };
                usize::try_from(i)
                    .ok()
                    .filter(|&i| i < dim)
                    .ok_or_else(|| Unsupported(format!("index {i} of {dim}")))
            })
            .collect::<Lowered<Vec<usize>>>()?;
        let mut gathered: Vec<usize> = shape[..axis].to_vec();
        gathered.extend(&index_shape);
        gathered.extend(&shape[axis + 1..]);
        let outer: usize = shape[..axis].iter().product();
        let inner: usize = shape[axis + 1..].iter().product();
        if outer
            .checked_mul(picked.len())
            .is_none_or(|slices| slices > 4096)
        {
            return unsupported("a gather of more than 4096 slices");
        }
        if gathered.len() > MAX_RANK {
            return unsupported(format!("a gather into rank {}", gathered.len()));
        }
        let to = self.buffer(elements(&gathered)?)?;
        for o in 0..outer {
            for (n, &i) in picked.iter().enumerate() {
                self.steps.push(Step::Copy {
                    from: buffer,
                    from_offset: (o * dim + i) * inner,
                    to,
                    to_offset: (o * picked.len() + n) * inner,
                    len: inner,
                });
            }
        }
        self.define_tensor(output, to, gathered, Layout::Standard)
    }

    fn concat(
        &mut self,
        node: &pb::NodeProto,
        attributes: &Attributes<'_>,
        output: &str,
    ) -> Lowered<()> {
        let parts = node
            .input
            .iter()
            .filter(|i| !i.is_empty())
            .map(|name| self.tensor(name))
            .collect::<Lowered<Vec<_>>>()?;
        let Some((_, first)) = parts.first() else {
            return unsupported("a Concat of nothing");
        };
        let axis = normalise_axis(attributes.int("axis").unwrap_or(0), first.len())?;
        let mut joined = first.clone();
        joined[axis] = 0;
        for (_, shape) in &parts {
            let same = shape.len() == first.len()
                && shape
                    .iter()
                    .zip(first)
                    .enumerate()
                    .all(|(d, (a, b))| d == axis || a == b);
            if !same {
                return unsupported(format!("concatenating {shape:?} to {first:?}"));
            }
            joined[axis] = joined[axis]
                .checked_add(shape[axis])
                .ok_or_else(|| Unsupported("a concatenation too long".into()))?;
        }
        let outer: usize = first[..axis].iter().product();
        let inner: usize = first[axis + 1..].iter().product();
        if outer
            .checked_mul(parts.len())
            .is_none_or(|slices| slices > 4096)
        {
            return unsupported("a concatenation of more than 4096 slices");
        }
        let to = self.buffer(elements(&joined)?)?;
        let row = joined[axis] * inner;
        for o in 0..outer {
            let mut at = 0;
            for (buffer, shape) in &parts {
                let len = shape[axis] * inner;
                self.steps.push(Step::Copy {
                    from: *buffer,
                    from_offset: o * len,
                    to,
                    to_offset: o * row + at,
                    len,
                });
                at += len;
            }
        }
        self.define_tensor(output, to, joined, Layout::Standard)
    }

    fn gemm(
        &mut self,
        node: &pb::NodeProto,
        attributes: &Attributes<'_>,
        output: &str,
    ) -> Lowered<()> {
        let a = node
            .input
            .first()
            .ok_or_else(|| Unsupported("no A".into()))?;
        let b = node
            .input
            .get(1)
            .ok_or_else(|| Unsupported("no B".into()))?;
        if attributes.int("transA").unwrap_or(0) != 0 {
            return unsupported("transA");
        }
        let (x, x_shape) = self.tensor(a)?;
        let [m, k] = x_shape[..] else {
            return unsupported(format!("A of shape {x_shape:?}"));
        };
        let (weights, w_shape) = self.weights(b)?;
        let transposed = attributes.int("transB").unwrap_or(0) != 0;
        let (wk, n) = match (&w_shape[..], transposed) {
            (&[rows, cols], false) => (rows, cols),
            (&[rows, cols], true) => (cols, rows),
            _ => return unsupported(format!("B of shape {w_shape:?}")),
        };
        if wk != k {
            return unsupported(format!("A {x_shape:?} times B {w_shape:?}"));
        }
        let alpha = attributes.float("alpha").unwrap_or(1.0);
        let beta = attributes.float("beta").unwrap_or(1.0);
        let mut relaid = vec![0.0; elements(&[n, k])?];
        for row in 0..n {
            for col in 0..k {
                let w = if transposed {
                    weights[row * k + col]
                } else {
                    weights[col * n + row]
                };
                relaid[row * k + col] = alpha * w;
            }
        }
        let bias = match node.input.get(2).filter(|s| !s.is_empty()) {
            Some(name) => {
                let (c, c_shape) = self.weights(name)?;
                row_vector(&c, &c_shape, n)?
                    .into_iter()
                    .map(|v| beta * v)
                    .collect()
            }
            None => vec![0.0; n],
        };
        self.dense(output, x, relaid, bias, vec![m, n])
    }

    fn matmul(&mut self, a: &str, b: Option<&str>, output: &str) -> Lowered<()> {
        let (x, x_shape) = self.tensor(a)?;
        let (weights, w_shape) = self.weights(b.ok_or_else(|| Unsupported("no B".into()))?)?;
        let [k, n] = w_shape[..] else {
            return unsupported(format!("B of shape {w_shape:?}"));
        };
        let Some((&xk, leading)) = x_shape.split_last() else {
            return unsupported("A is a scalar");
        };
        if xk != k {
            return unsupported(format!("A {x_shape:?} times B {w_shape:?}"));
        }
        let mut relaid = vec![0.0; elements(&[n, k])?];
        for row in 0..n {
            for col in 0..k {
                relaid[row * k + col] = weights[col * n + row];
            }
        }
        let mut shape = leading.to_vec();
        shape.push(n);
        self.dense(output, x, relaid, vec![0.0; n], shape)
    }

    /// A dense layer on the rows of `x` (weights `[out][in]`) into a new value of `shape`,
    /// whose last dimension is the outputs and the rest the rows.
    fn dense(
        &mut self,
        output: &str,
        x: BufferId,
        weights: Vec<f32>,
        bias: Vec<f32>,
        shape: Vec<usize>,
    ) -> Lowered<()> {
        let outputs = bias.len();
        let count = elements(&shape)?;
        if outputs == 0 || weights.is_empty() || !weights.len().is_multiple_of(outputs) {
            return unsupported(format!(
                "a dense layer of {} weights for {outputs} outputs",
                weights.len()
            ));
        }
        let rows = count / outputs;
        let inputs = weights.len() / outputs;
        // The panels' padded width: at most 64 more outputs than the layer has.
        elements(&[outputs + 64, inputs])?;
        let weights = DenseWeights::from_rows(&weights, outputs, inputs, self.dense_width);
        let to = self.buffer(count)?;
        self.push(
            output,
            Step::Dense {
                from: x,
                weights,
                bias,
                rows,
                relu: false,
                to,
            },
        );
        self.define_tensor(output, to, shape, Layout::Standard)
    }

    fn binary(&mut self, op: &str, a: &str, b: Option<&str>, output: &str) -> Lowered<()> {
        let b = b.ok_or_else(|| Unsupported("one operand".into()))?;
        // A constant row added to a dense layer's output that only it reads: into the bias.
        if op == "Add" {
            for (product, addend) in [(a, b), (b, a)] {
                if self.fold_bias(product, addend, output)? {
                    return Ok(());
                }
            }
        }
        let (a_buffer, a_shape) = self.tensor(a)?;
        let (b_buffer, b_shape) = self.tensor(b)?;
        let rank = a_shape.len().max(b_shape.len());
        if rank > MAX_RANK {
            return unsupported(format!("rank {rank}"));
        }
        let pad = |s: &[usize]| {
            let mut padded = vec![1; rank - s.len()];
            padded.extend(s);
            padded
        };
        let (a_full, b_full) = (pad(&a_shape), pad(&b_shape));
        let mut shape = Vec::with_capacity(rank);
        for (&x, &y) in a_full.iter().zip(&b_full) {
            shape.push(match (x, y) {
                _ if x == y => x,
                (1, y) => y,
                (x, 1) => x,
                _ => return unsupported(format!("broadcasting {a_shape:?} with {b_shape:?}")),
            });
        }
        let broadcast = |full: &[usize]| {
            let strides = standard_strides(full);
            full.iter()
                .zip(&strides)
                .map(|(&d, &s)| if d == 1 { 0 } else { s })
                .collect::<Vec<_>>()
        };
        let op = match op {
            "Add" => BinaryOp::Add,
            "Sub" => BinaryOp::Sub,
            "Mul" => BinaryOp::Mul,
            "Div" => BinaryOp::Div,
            _ => BinaryOp::Equal,
        };
        let to = self.buffer(elements(&shape)?)?;
        self.push(
            output,
            Step::Binary {
                op,
                a: a_buffer,
                a_index: Strided::new(&shape, &broadcast(&a_full)),
                b: b_buffer,
                b_index: Strided::new(&shape, &broadcast(&b_full)),
                to,
            },
        );
        self.define(
            output,
            Value::Tensor {
                buffer: to,
                shape,
                layout: Layout::Standard,
                boolean: op == BinaryOp::Equal,
            },
        )
    }

    fn fold_bias(&mut self, product: &str, addend: &str, output: &str) -> Lowered<bool> {
        if !self.single_reader(product) {
            return Ok(false);
        }
        let Some(&index) = self.producer.get(product) else {
            return Ok(false);
        };
        let Ok((constant, shape)) = self.weights(addend) else {
            return Ok(false);
        };
        // The sum broadcasts to the product's shape only if the addend's rank is no higher
        // (a `[1, n]` bias on a `[n]` product makes `[1, n]`): otherwise a Binary step.
        let product_rank = match self.value(product)? {
            Value::Tensor { shape, .. } => shape.len(),
            Value::Ints { .. } => return Ok(false),
        };
        if shape.len() > product_rank {
            return Ok(false);
        }
        let Step::Dense {
            bias, relu: false, ..
        } = &self.steps[index]
        else {
            return Ok(false);
        };
        let Ok(row) = row_vector(&constant, &shape, bias.len()) else {
            return Ok(false);
        };
        if let Step::Dense { bias, .. } = &mut self.steps[index] {
            for (b, r) in bias.iter_mut().zip(row) {
                *b += r;
            }
        }
        let value = self.value(product)?.clone();
        self.producer.insert(output.to_owned(), index);
        self.define(output, value)?;
        Ok(true)
    }

    fn reduce(
        &mut self,
        node: &pb::NodeProto,
        attributes: &Attributes<'_>,
        input: &str,
        axes_input: Option<&str>,
        output: &str,
    ) -> Lowered<()> {
        let (buffer, shape) = self.tensor(input)?;
        let rank = shape.len();
        if rank > MAX_RANK {
            return unsupported(format!("rank {rank}"));
        }
        // ReduceSum took its axes as an input from opset 13, ReduceMax from 18; the
        // `noop_with_empty_axes` attribute came with the input.
        let input_from = if node.op_type == "ReduceMax" { 18 } else { 13 };
        let axes = self.axes(attributes, axes_input, input_from)?;
        let noop = attributes.int("noop_with_empty_axes");
        if noop.is_some() && self.opset < input_from {
            return unsupported(format!("noop_with_empty_axes at opset {}", self.opset));
        }
        let axes = if axes.is_empty() {
            if noop.unwrap_or(0) != 0 {
                return self.alias(input, output, buffer, shape);
            }
            (0..rank).collect::<Vec<_>>()
        } else {
            axes.iter()
                .map(|&a| normalise_axis(a, rank))
                .collect::<Lowered<Vec<_>>>()?
        };
        let keep = attributes.int("keepdims").unwrap_or(1) != 0;
        let reduced: Vec<usize> = (0..rank)
            .filter_map(|d| match (axes.contains(&d), keep) {
                (true, true) => Some(1),
                (true, false) => None,
                (false, _) => Some(shape[d]),
            })
            .collect();
        // Iterate the input in order; each element lands at its reduced position.
        let kept: Vec<usize> = (0..rank)
            .map(|d| if axes.contains(&d) { 1 } else { shape[d] })
            .collect();
        let kept_strides = standard_strides(&kept);
        let target: Vec<usize> = (0..rank)
            .map(|d| {
                if axes.contains(&d) {
                    0
                } else {
                    kept_strides[d]
                }
            })
            .collect();
        let op = if node.op_type == "ReduceMax" {
            ReduceOp::Max
        } else {
            ReduceOp::Sum
        };
        let to = self.buffer(elements(&kept)?)?;
        self.push(
            output,
            Step::Reduce {
                op,
                from: buffer,
                target: Strided::new(&shape, &target),
                to,
            },
        );
        if reduced.is_empty() {
            // A reduction to a scalar: the engine's values have at least one dimension.
            return unsupported("a reduction to a scalar");
        }
        self.define_tensor(output, to, reduced, Layout::Standard)
    }

    fn lstm(&mut self, node: &pb::NodeProto, attributes: &Attributes<'_>) -> Lowered<()> {
        let input = |i: usize| {
            node.input
                .get(i)
                .map(String::as_str)
                .filter(|s| !s.is_empty())
        };
        let output = |i: usize| {
            node.output
                .get(i)
                .map(String::as_str)
                .filter(|s| !s.is_empty())
        };
        if attributes
            .string("direction")
            .is_some_and(|d| d != "forward")
            || attributes.strings("activations").is_some()
            || attributes.float("clip").is_some()
            || attributes.int("input_forget").unwrap_or(0) != 0
            || attributes.int("layout").unwrap_or(0) != 0
        {
            return unsupported("an LSTM other than forward with default activations");
        }
        if input(4).is_some() || input(7).is_some() {
            return unsupported("sequence lengths or peepholes");
        }
        let (x, x_shape) = self.tensor(input(0).ok_or_else(|| Unsupported("no X".into()))?)?;
        let [1, 1, features] = x_shape[..] else {
            return unsupported(format!("X of shape {x_shape:?}: one step of one sequence"));
        };
        let (w, w_shape) = self.weights(input(1).ok_or_else(|| Unsupported("no W".into()))?)?;
        let (r, r_shape) = self.weights(input(2).ok_or_else(|| Unsupported("no R".into()))?)?;
        let units = r_shape.last().copied().unwrap_or(0);
        // units and features come from constants' shapes (at most MAX_ELEMENTS each).
        if units == 0 || w_shape != [1, 4 * units, features] || r_shape != [1, 4 * units, units] {
            return unsupported(format!("W {w_shape:?}, R {r_shape:?}"));
        }
        if let Some(hidden) = attributes.int("hidden_size")
            && hidden != units as i64
        {
            return unsupported("hidden_size differs from R");
        }
        let gates = 4 * units;
        let mut bias = vec![0.0; gates];
        if let Some(name) = input(3) {
            let (b, b_shape) = self.weights(name)?;
            if b_shape != [1, 2 * gates] {
                return unsupported(format!("B of shape {b_shape:?}"));
            }
            for (g, value) in bias.iter_mut().enumerate() {
                *value = b[g] + b[gates + g];
            }
        }
        // One dense layer on [x, h]: weights [gate][x ..., h ...].
        let width = features + units;
        // The panels' padded width: at most 64 more rows than the gates.
        elements(&[gates + 64, width])?;
        let mut weights = vec![0.0; gates * width];
        for g in 0..gates {
            weights[g * width..g * width + features]
                .copy_from_slice(&w[g * features..(g + 1) * features]);
            weights[g * width + features..(g + 1) * width]
                .copy_from_slice(&r[g * units..(g + 1) * units]);
        }
        let state = |lowerer: &mut Self, index: usize| -> Lowered<BufferId> {
            match input(index) {
                Some(name) => {
                    let (buffer, shape) = lowerer.tensor(name)?;
                    if shape != [1, 1, units] {
                        return unsupported(format!("initial state of shape {shape:?}"));
                    }
                    Ok(buffer)
                }
                None => {
                    let zero = lowerer.buffer(units)?;
                    lowerer.fixed[zero] = true;
                    Ok(zero)
                }
            }
        };
        let (h_in, c_in) = (state(self, 5)?, state(self, 6)?);
        let joined = self.buffer(width)?;
        let gate_values = self.buffer(gates)?;
        let (h_out, c_out) = (self.buffer(units)?, self.buffer(units)?);
        let weights = DenseWeights::from_rows(&weights, gates, width, self.dense_width);
        self.steps.push(Step::Lstm {
            x,
            h_in,
            c_in,
            joined,
            weights,
            bias,
            gates: gate_values,
            h_out,
            c_out,
        });
        if let Some(y) = output(0) {
            self.define_tensor(y, h_out, vec![1, 1, 1, units], Layout::Standard)?;
        }
        if let Some(y_h) = output(1) {
            self.define_tensor(y_h, h_out, vec![1, 1, units], Layout::Standard)?;
        }
        if let Some(y_c) = output(2) {
            self.define_tensor(y_c, c_out, vec![1, 1, units], Layout::Standard)?;
        }
        Ok(())
    }
}

/// A node's attributes by name.
struct Attributes<'a>(&'a [pb::AttributeProto]);

impl Attributes<'_> {
    fn find(&self, name: &str) -> Option<&pb::AttributeProto> {
        self.0.iter().find(|a| a.name == name)
    }

    fn int(&self, name: &str) -> Option<i64> {
        self.find(name).map(|a| a.i)
    }

    fn float(&self, name: &str) -> Option<f32> {
        self.find(name).map(|a| a.f)
    }

    fn ints(&self, name: &str) -> Option<Vec<i64>> {
        self.find(name).map(|a| a.ints.clone())
    }

    fn string(&self, name: &str) -> Option<String> {
        self.find(name)
            .map(|a| String::from_utf8_lossy(&a.s).into_owned())
    }

    fn strings(&self, name: &str) -> Option<usize> {
        self.find(name).map(|a| a.strings.len())
    }

    fn tensor(&self, name: &str) -> Option<&pb::TensorProto> {
        self.find(name).and_then(|a| a.t.as_ref())
    }
}

fn normalise_axis(axis: i64, rank: usize) -> Lowered<usize> {
    let axis = if axis < 0 { axis + rank as i64 } else { axis };
    usize::try_from(axis)
        .ok()
        .filter(|&a| a < rank.max(1))
        .ok_or_else(|| Unsupported(format!("axis {axis} of rank {rank}")))
}

/// `count` sizes from 1 to [`MAX_ELEMENTS`] (strides, kernels).
fn positive(values: Vec<i64>, count: usize) -> Lowered<Vec<usize>> {
    if values.len() != count || values.iter().any(|&v| v < 1) {
        return unsupported(format!("{values:?}"));
    }
    values.into_iter().map(dimension).collect()
}

/// `count` sizes from 0 to [`MAX_ELEMENTS`] (paddings).
fn non_negative(values: Vec<i64>, count: usize) -> Lowered<Vec<usize>> {
    if values.len() != count {
        return unsupported(format!("{values:?}"));
    }
    values.into_iter().map(dimension).collect()
}

fn standard_strides(shape: &[usize]) -> Vec<usize> {
    let mut strides = vec![1; shape.len()];
    for d in (0..shape.len().saturating_sub(1)).rev() {
        strides[d] = strides[d + 1] * shape[d + 1];
    }
    strides
}

/// A constant's numbers as a row of `n` (shape `[n]`, `[1, n]` or a scalar).
fn row_vector(values: &[f32], shape: &[usize], n: usize) -> Lowered<Vec<f32>> {
    match shape {
        [] | [1] | [1, 1] if values.len() == 1 => Ok(vec![values[0]; n]),
        [m] | [1, m] if *m == n => Ok(values.to_vec()),
        _ => unsupported(format!("a bias of shape {shape:?} for {n} outputs")),
    }
}

fn reshape(shape: &[usize], target: &[i64], allow_zero: bool) -> Lowered<Vec<usize>> {
    let total: usize = shape.iter().product();
    let mut out = Vec::with_capacity(target.len());
    let mut infer = None;
    for (d, &t) in target.iter().enumerate() {
        match t {
            -1 if infer.is_none() => {
                infer = Some(d);
                out.push(1);
            }
            0 if !allow_zero => out.push(
                *shape
                    .get(d)
                    .ok_or_else(|| Unsupported("reshape 0 past the rank".into()))?,
            ),
            t if t >= 0 => out.push(dimension(t)?),
            _ => return unsupported(format!("reshape to {target:?}")),
        }
    }
    let known = out
        .iter()
        .try_fold(1usize, |known, &d| known.checked_mul(d))
        .ok_or_else(|| Unsupported(format!("reshape to {target:?}")))?;
    if let Some(d) = infer {
        if known == 0 || !total.is_multiple_of(known) {
            return unsupported(format!("reshape {shape:?} to {target:?}"));
        }
        out[d] = total / known;
    }
    if known != total && infer.is_none() {
        return unsupported(format!("reshape {shape:?} to {target:?}"));
    }
    Ok(out)
}

fn squeeze_shape(shape: &[usize], axes: &[i64], squeeze: bool) -> Lowered<Vec<usize>> {
    if squeeze {
        let rank = shape.len();
        let axes = if axes.is_empty() {
            (0..rank).filter(|&d| shape[d] == 1).collect::<Vec<_>>()
        } else {
            axes.iter()
                .map(|&a| normalise_axis(a, rank))
                .collect::<Lowered<_>>()?
        };
        if axes.iter().any(|&a| shape[a] != 1) {
            return unsupported(format!("squeezing {axes:?} of {shape:?}"));
        }
        Ok((0..rank)
            .filter(|d| !axes.contains(d))
            .map(|d| shape[d])
            .collect())
    } else {
        let rank = shape.len() + axes.len();
        let axes = axes
            .iter()
            .map(|&a| normalise_axis(a, rank))
            .collect::<Lowered<Vec<_>>>()?;
        let mut rest = shape.iter();
        (0..rank)
            .map(|d| {
                if axes.contains(&d) {
                    Ok(1)
                } else {
                    rest.next()
                        .copied()
                        .ok_or_else(|| Unsupported("unsqueeze axes".into()))
                }
            })
            .collect()
    }
}
