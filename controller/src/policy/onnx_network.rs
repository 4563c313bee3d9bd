//! One ONNX network under tract: read, checked against what the controller will feed it,
//! optimised and planned once at load; then run step after step on the same state.

use std::fs;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use tract_onnx::pb;
use tract_onnx::prelude::*;

use super::{PolicyError, PolicyLoadError};

/// ONNX's code for 32-bit floats.
const ONNX_FLOAT: i32 = 1;

/// A tensor the controller feeds into a network or reads from it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Port {
    Top,
    Bottom,
    Command,
    /// The command the controller sent last, `[1, 3]` (in).
    Previous,
    /// LSTM hidden state, in or out.
    Hidden,
    /// LSTM cell state, in or out.
    Cell,
    /// A modal CNN's command hypotheses, `[1, count, 3]` (out).
    Hypotheses,
    /// A modal CNN's choice logits, `[1, count]` (out).
    Logits,
}

/// What a network must take and give: names (from the manifest) and shapes (the contract's).
#[derive(Debug)]
pub(crate) struct Interface<'a> {
    pub inputs: &'a [(Port, &'a str, &'a [usize])],
    pub outputs: &'a [(Port, &'a str, &'a [usize])],
    pub opset: i64,
}

/// A planned network and its reusable run state.
pub(crate) struct OnnxNetwork {
    path: PathBuf,
    state: TypedSimpleState,
    /// Which port feeds each model input, in the model's input order.
    feeds: TVec<Port>,
    /// Which port each model output is, in the model's output order.
    products: TVec<Port>,
}

impl std::fmt::Debug for OnnxNetwork {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OnnxNetwork")
            .field("path", &self.path)
            .field("feeds", &self.feeds)
            .field("products", &self.products)
            .finish_non_exhaustive()
    }
}

impl OnnxNetwork {
    /// Reads, checks and plans the network at `path`; also returns the file's parsed graph.
    pub(crate) fn load(
        path: &Path,
        interface: &Interface<'_>,
    ) -> Result<(Self, pb::ModelProto), PolicyLoadError> {
        let bytes = fs::read(path).map_err(|source| PolicyLoadError::Io {
            path: path.to_owned(),
            source,
        })?;
        let onnx = tract_onnx::onnx();
        let proto = onnx
            .proto_model_for_read(&mut &bytes[..])
            .map_err(|error| onnx_error(path, "is not a readable ONNX model", &error))?;
        check_proto(path, &proto, interface)?;

        let mut model = onnx
            .model_for_proto_model(&proto)
            .map_err(|error| onnx_error(path, "cannot be translated by tract", &error))?;
        let mut feeds = TVec::new();
        let input_names: Vec<String> = model
            .input_outlets()
            .map_err(|error| onnx_error(path, "has no usable inputs", &error))?
            .iter()
            .map(|outlet| model.node(outlet.node).name.clone())
            .collect();
        for (index, name) in input_names.iter().enumerate() {
            let (port, _, shape) = find(interface.inputs, name).ok_or_else(|| {
                mismatch(path, "inputs", names(interface.inputs), input_names.clone())
            })?;
            model
                .set_input_fact(index, f32::fact(shape).into())
                .map_err(|error| onnx_error(path, "refuses the input shapes", &error))?;
            feeds.push(port);
        }
        let model = model
            .into_optimized()
            .map_err(|error| onnx_error(path, "cannot be optimised for these inputs", &error))?;

        let mut products = TVec::new();
        let outlets = model
            .output_outlets()
            .map_err(|error| onnx_error(path, "has no usable outputs", &error))?
            .to_vec();
        // Optimisation may relabel outlets; the outputs keep the file's order.
        let output_names: Vec<String> = proto
            .graph
            .iter()
            .flat_map(|graph| graph.output.iter().map(|output| output.name.clone()))
            .collect();
        if output_names.len() != outlets.len() {
            return Err(mismatch(
                path,
                "outputs",
                names(interface.outputs),
                output_names,
            ));
        }
        for (outlet, name) in outlets.iter().zip(&output_names) {
            let (port, _, shape) = find(interface.outputs, name).ok_or_else(|| {
                mismatch(
                    path,
                    "outputs",
                    names(interface.outputs),
                    output_names.clone(),
                )
            })?;
            let fact = model
                .outlet_fact(*outlet)
                .map_err(|error| onnx_error(path, "has an unusable output", &error))?;
            let found = fact.shape.as_concrete().map(<[usize]>::to_vec);
            if found.as_deref() != Some(shape) || fact.datum_type != f32::datum_type() {
                return Err(PolicyLoadError::Mismatch {
                    path: path.to_owned(),
                    what: format!("output {name:?}"),
                    expected: format!("f32 {shape:?}"),
                    found: format!("{:?} {}", fact.datum_type, describe_shape(found.as_deref())),
                });
            }
            products.push(port);
        }
        let plan = model
            .into_runnable()
            .map_err(|error| onnx_error(path, "cannot be planned", &error))?;
        let state = TypedSimpleState::new(&plan)
            .map_err(|error| onnx_error(path, "cannot be given a run state", &error))?;
        Ok((
            Self {
                path: path.to_owned(),
                state,
                feeds,
                products,
            },
            proto,
        ))
    }

    /// Runs one step with `feed(port)` giving each input; returns the outputs by port.
    pub(crate) fn run(
        &mut self,
        feed: impl Fn(Port) -> TValue,
    ) -> Result<TVec<(Port, TValue)>, PolicyError> {
        let inputs: TVec<TValue> = self.feeds.iter().map(|&port| feed(port)).collect();
        let outputs = self.state.run(inputs).map_err(|error| {
            PolicyError::Inference(format!("{}: {error:#}", self.path.display()))
        })?;
        Ok(self.products.iter().copied().zip(outputs).collect())
    }
}

/// Checks the file's own declarations (opset, names, element types, shapes) before tract
/// sees it, so that a mismatch is reported in the contract's terms.
fn check_proto(
    path: &Path,
    proto: &pb::ModelProto,
    interface: &Interface<'_>,
) -> Result<(), PolicyLoadError> {
    let opset = proto
        .opset_import
        .iter()
        .find(|import| import.domain.is_empty() || import.domain == "ai.onnx")
        .map(|import| import.version);
    if opset != Some(interface.opset) {
        return Err(PolicyLoadError::Mismatch {
            path: path.to_owned(),
            what: "ONNX operator set".into(),
            expected: format!("{} (from the manifest)", interface.opset),
            found: opset.map_or("none".into(), |v| v.to_string()),
        });
    }
    let Some(graph) = &proto.graph else {
        return Err(PolicyLoadError::Onnx {
            path: path.to_owned(),
            problem: "has no graph".into(),
        });
    };
    // Before tract plans anything: sizes that hang or crash its planner are refused here.
    super::model_limits::check(proto).map_err(|problem| PolicyLoadError::Onnx {
        path: path.to_owned(),
        problem,
    })?;
    let initializers: Vec<&str> = graph.initializer.iter().map(|t| t.name.as_str()).collect();
    let graph_inputs: Vec<&pb::ValueInfoProto> = graph
        .input
        .iter()
        .filter(|input| !initializers.contains(&input.name.as_str()))
        .collect();
    check_values(path, "inputs", &graph_inputs, interface.inputs)?;
    let graph_outputs: Vec<&pb::ValueInfoProto> = graph.output.iter().collect();
    check_values(path, "outputs", &graph_outputs, interface.outputs)
}

fn check_values(
    path: &Path,
    what: &str,
    values: &[&pb::ValueInfoProto],
    expected: &[(Port, &str, &[usize])],
) -> Result<(), PolicyLoadError> {
    let mut found_names: Vec<String> = values.iter().map(|v| v.name.clone()).collect();
    let mut expected_names = names(expected);
    found_names.sort();
    expected_names.sort();
    if found_names != expected_names {
        return Err(mismatch(path, what, expected_names, found_names));
    }
    for value in values {
        let Some((_, name, shape)) = find(expected, &value.name) else {
            continue;
        };
        let Some(pb::type_proto::Value::TensorType(tensor)) =
            value.r#type.as_ref().and_then(|t| t.value.as_ref())
        else {
            continue; // No declared type: tract infers it from the fed shapes.
        };
        let declared: Option<Vec<i64>> = tensor.shape.as_ref().map(|shape| {
            shape
                .dim
                .iter()
                .map(|dim| match dim.value {
                    Some(pb::tensor_shape_proto::dimension::Value::DimValue(v)) => v,
                    _ => -1,
                })
                .collect()
        });
        let matches_shape = declared.as_ref().is_none_or(|dims| {
            dims.len() == shape.len()
                && dims
                    .iter()
                    .zip(shape)
                    .all(|(&d, &s)| d == -1 || usize::try_from(d) == Ok(s))
        });
        if tensor.elem_type != ONNX_FLOAT || !matches_shape {
            let dims = declared.map_or("unknown shape".into(), |dims| {
                let dims: Vec<String> = dims
                    .iter()
                    .map(|&d| if d < 0 { "?".into() } else { d.to_string() })
                    .collect();
                format!("[{}]", dims.join(", "))
            });
            return Err(PolicyLoadError::Mismatch {
                path: path.to_owned(),
                what: format!("{} {name:?}", &what[..what.len() - 1]),
                expected: format!("f32 {shape:?}"),
                found: format!("ONNX element type {} {dims}", tensor.elem_type),
            });
        }
    }
    Ok(())
}

fn find<'a>(
    ports: &[(Port, &'a str, &'a [usize])],
    name: &str,
) -> Option<(Port, &'a str, &'a [usize])> {
    ports.iter().copied().find(|(_, n, _)| *n == name)
}

fn names(ports: &[(Port, &str, &[usize])]) -> Vec<String> {
    ports
        .iter()
        .map(|(_, name, _)| (*name).to_owned())
        .collect()
}

fn describe_shape(shape: Option<&[usize]>) -> String {
    shape.map_or("of unknown shape".into(), |s| format!("{s:?}"))
}

fn mismatch(path: &Path, what: &str, expected: Vec<String>, found: Vec<String>) -> PolicyLoadError {
    PolicyLoadError::Mismatch {
        path: path.to_owned(),
        what: what.into(),
        expected: format!("{expected:?}"),
        found: format!("{found:?}"),
    }
}

fn onnx_error(path: &Path, problem: &str, error: &TractError) -> PolicyLoadError {
    PolicyLoadError::Onnx {
        path: path.to_owned(),
        problem: format!("{problem}: {error:#}"),
    }
}

/// A zero-filled f32 tensor of `shape`, to be shared with tract by reference count.
pub(crate) fn zero_tensor(path: &Path, shape: &[usize]) -> Result<Arc<Tensor>, PolicyLoadError> {
    Tensor::zero::<f32>(shape)
        .map(Arc::new)
        .map_err(|error| onnx_error(path, "cannot get its input buffers", &error))
}
