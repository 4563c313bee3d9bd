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
//! float, Identity and Constant; and a QDQ graph's QuantizeLinear and DequantizeLinear
//! (uint8 activations per tensor, int8 weights per channel or per tensor), whose Conv and
//! Gemm become integer steps (`quantized.rs`). Anything else is refused with the reason,
//! and the network runs under tract instead.
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

use super::kernels::PoolShape;
use super::kernels::int8::Int8Kernel;
use super::kernels::winograd;
use super::layout::{AlignedWeights, BufferId, ConvShape, DenseWeights, Grid, MAX_RANK, Strided};
use super::plan::{BinaryOp, ConvPool, QuantizedPool, ReduceOp, Step, WinogradConv};

// The operators by family, each an `impl Lowerer` of its own; this file holds the lowering's
// state, the graph walk that dispatches on each node, and what the families share.
mod conv;
mod dense;
mod elementwise;
mod pool_fusion;
mod quantized;
mod recurrent;
mod shape;

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

/// A constant's declared dimensions, each checked by [`dimension`]; data kept in an external
/// file is refused.
fn declared_shape(tensor: &pb::TensorProto) -> Lowered<Vec<usize>> {
    if tensor.data_location == Some(1) {
        return unsupported(format!(
            "{} keeps its data in an external file",
            tensor.name
        ));
    }
    tensor.dims.iter().map(|&d| dimension(d)).collect()
}

fn unsupported<T>(why: impl Into<String>) -> Lowered<T> {
    Err(Unsupported(why.into()))
}

/// An absent value as an unsupported graph, `why` saying what is missing.
trait OrUnsupported<T> {
    fn or_unsupported(self, why: &str) -> Lowered<T>;
}

impl<T> OrUnsupported<T> for Option<T> {
    fn or_unsupported(self, why: &str) -> Lowered<T> {
        self.ok_or_else(|| Unsupported(why.to_owned()))
    }
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
    /// The layers the kernels take by Winograd ([`super::Isa::winograd_fit`]).
    winograd: Option<winograd::Fit>,
    /// The int8 kernel of a QDQ graph's integer steps ([`super::Isa::int8_kernel`]).
    int8: Int8Kernel,
    /// Integer constants (int8, uint8, int32), which only `DequantizeLinear` reads.
    codes: HashMap<String, quantized::Codes>,
    /// `QuantizeLinear` outputs waiting for their `DequantizeLinear`: what they quantize
    /// and onto which grid.
    pending: HashMap<String, (String, Grid)>,
    /// `DequantizeLinear` outputs of int8 weights, as integers.
    integer_weights: HashMap<String, quantized::IntegerWeights>,
    /// Buffers whose every number lies on a grid.
    grids: HashMap<BufferId, Grid>,
}

/// Lowers `graph` for inputs of the given shapes;
/// `dense_width`: the most outputs a dense layer's weight panel holds (the kernels' choice,
/// [`super::Isa::dense_panel_width`]); `winograd`: which 5x5 stride-two convolutions with
/// their 2x2 pool the kernels take by [`super::kernels::winograd`], if any; `int8`: the kernel of a QDQ graph's integer steps.
pub(crate) fn lower(
    model: &pb::ModelProto,
    inputs: &[(&str, &[usize])],
    dense_width: usize,
    winograd: Option<winograd::Fit>,
    int8: Int8Kernel,
) -> Lowered<Lowering> {
    let graph = model.graph.as_ref().or_unsupported("no graph")?;
    let opset = model
        .opset_import
        .iter()
        .find(|import| import.domain.is_empty() || import.domain == "ai.onnx")
        .map(|import| import.version)
        .or_unsupported("no operator set for the default domain")?;
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
        winograd,
        int8,
        codes: HashMap::new(),
        pending: HashMap::new(),
        integer_weights: HashMap::new(),
        grids: HashMap::new(),
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
        if let Some(codes) = lowerer.integer_constant(initializer)? {
            lowerer.codes.insert(initializer.name.clone(), codes);
            continue;
        }
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
    quantized::fold_snaps(&mut lowerer.steps, &outputs);
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
        let shape = declared_shape(tensor)?;
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
                let values = tensor_numbers(
                    tensor,
                    &tensor.float_data,
                    count,
                    "numbers",
                    f32::from_le_bytes,
                )?;
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
                let values = tensor_numbers(
                    tensor,
                    &tensor.int64_data,
                    count,
                    "integers",
                    i64::from_le_bytes,
                )?;
                Ok(Value::Ints { values, shape })
            }
            other => unsupported(format!("{} has element type {other}", tensor.name)),
        }
    }

    fn value(&self, name: &str) -> Lowered<&Value> {
        self.values.get(name).ok_or_else(|| {
            Unsupported(
                if self.codes.contains_key(name) || self.pending.contains_key(name) {
                    format!("{name} is integers, which only a DequantizeLinear reads here")
                } else {
                    format!("{name} is not computed before it is used")
                },
            )
        })
    }

    /// The float tensor `name` as it is (buffer, shape, layout); `what` names the operation
    /// for the error where `name` is something else.
    fn float_tensor(&self, name: &str, what: &str) -> Lowered<(BufferId, Vec<usize>, Layout)> {
        match self.value(name)? {
            Value::Tensor {
                buffer,
                shape,
                layout,
                boolean: false,
            } => Ok((*buffer, shape.clone(), *layout)),
            _ => unsupported(format!("{what} of something that is not a float tensor")),
        }
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
                self.keep_grid(buffer, to);
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
        let output = node
            .output
            .first()
            .map(String::as_str)
            .or_unsupported("no output")?;
        let op = Operation {
            node,
            attributes: Attributes(&node.attribute),
            output,
        };
        let (attributes, input, first) = (&op.attributes, |i| op.input(i), || op.first());
        match node.op_type.as_str() {
            "Constant" => {
                let Some(tensor) = attributes.tensor("value") else {
                    return unsupported("a Constant without a tensor value");
                };
                if let Some(codes) = self.integer_constant(tensor)? {
                    self.codes.insert(output.to_owned(), codes);
                    return Ok(());
                }
                let value = self.constant(tensor)?;
                self.define(output, value)?;
            }
            "Identity" => {
                let value = self.value(first()?)?.clone();
                self.define(output, value)?;
            }
            "Conv" => self.conv(&op)?,
            "MaxPool" => self.max_pool(&op)?,
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
                let target = self.ints(input(1).or_unsupported("no shape")?)?;
                let reshaped = reshape(
                    &shape,
                    &target,
                    attributes.int("allowzero").unwrap_or(0) != 0,
                )?;
                self.alias(first()?, output, buffer, reshaped)?;
            }
            "Squeeze" | "Unsqueeze" => {
                let value = self.standard(first()?)?;
                let axes = self.axes(attributes, input(1), 13)?;
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
            "Transpose" => self.transpose(&op)?,
            "Gather" => self.gather(&op)?,
            "Concat" => self.concat(&op)?,
            "Gemm" => self.gemm(&op)?,
            "MatMul" => self.matmul(first()?, input(1), output)?,
            "Add" | "Sub" | "Mul" | "Div" | "Equal" => {
                self.binary(&node.op_type, first()?, input(1), output)?
            }
            "ReduceMax" | "ReduceSum" => self.reduce(&op)?,
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
            "LSTM" => self.lstm(&op)?,
            "QuantizeLinear" => self.quantize_linear(&op)?,
            "DequantizeLinear" => self.dequantize_linear(&op)?,
            other => return unsupported(format!("the operator {other} is not in the engine")),
        }
        Ok(())
    }
}

/// A constant's `count` numbers: its `raw_data` read as little-endian `N`-byte values where
/// it has any, else its typed field (`what` names them in the error).
fn tensor_numbers<T: Clone, const N: usize>(
    tensor: &pb::TensorProto,
    typed: &[T],
    count: usize,
    what: &str,
    from_le_bytes: fn([u8; N]) -> T,
) -> Lowered<Vec<T>> {
    let raw = &tensor.raw_data;
    if !raw.is_empty() && Some(raw.len()) != count.checked_mul(N) {
        return unsupported(format!("{} has a ragged raw_data", tensor.name));
    }
    let values: Vec<T> = if raw.is_empty() {
        typed.to_vec()
    } else {
        raw.as_chunks::<N>()
            .0
            .iter()
            .map(|b| from_le_bytes(*b))
            .collect()
    };
    if values.len() != count {
        return unsupported(format!(
            "{} holds {} {what} for shape {:?}",
            tensor.name,
            values.len(),
            tensor.dims
        ));
    }
    Ok(values)
}

/// The node being lowered: its inputs by position, its attributes and its (first) output.
struct Operation<'n> {
    node: &'n pb::NodeProto,
    attributes: Attributes<'n>,
    output: &'n str,
}

impl<'n> Operation<'n> {
    /// Input `i`, where the node has it (an empty name is an optional input left out).
    fn input(&self, i: usize) -> Option<&'n str> {
        self.node
            .input
            .get(i)
            .map(String::as_str)
            .filter(|s| !s.is_empty())
    }

    fn first(&self) -> Lowered<&'n str> {
        self.input(0).or_unsupported("no input")
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
            0 if !allow_zero => out.push(*shape.get(d).or_unsupported("reshape 0 past the rank")?),
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
                    rest.next().copied().or_unsupported("unsqueeze axes")
                }
            })
            .collect()
    }
}
