//! Small ONNX graphs written in code, for the engine's property tests, the structure-aware
//! fuzz target and the hostile-model tests: nodes, attributes, constants and typed inputs,
//! as the `onnx` package's `helper` module makes them in Python.

use tract_onnx::pb;
use tract_onnx::pb::attribute_proto::AttributeType;

/// An attribute's value.
#[derive(Clone, Debug)]
pub enum Attribute {
    Int(i64),
    Float(f32),
    Ints(Vec<i64>),
    Text(String),
}

/// A node `op_type(inputs) -> outputs` with `attributes`.
pub fn node(
    op_type: &str,
    inputs: &[&str],
    outputs: &[&str],
    attributes: &[(&str, Attribute)],
) -> pb::NodeProto {
    pb::NodeProto {
        op_type: op_type.to_owned(),
        name: format!("{op_type}_{}", outputs.first().copied().unwrap_or("")),
        input: inputs.iter().map(|&i| i.to_owned()).collect(),
        output: outputs.iter().map(|&o| o.to_owned()).collect(),
        attribute: attributes
            .iter()
            .map(|(name, value)| attribute(name, value))
            .collect(),
        ..Default::default()
    }
}

fn attribute(name: &str, value: &Attribute) -> pb::AttributeProto {
    let mut proto = pb::AttributeProto {
        name: name.to_owned(),
        ..Default::default()
    };
    let kind = match value {
        Attribute::Int(i) => {
            proto.i = *i;
            AttributeType::Int
        }
        Attribute::Float(f) => {
            proto.f = *f;
            AttributeType::Float
        }
        Attribute::Ints(ints) => {
            proto.ints = ints.clone();
            AttributeType::Ints
        }
        Attribute::Text(text) => {
            proto.s = text.as_bytes().to_vec();
            AttributeType::String
        }
    };
    proto.r#type = kind as i32;
    proto
}

/// A float constant of `shape` (as an initializer or a Constant's value).
pub fn floats(name: &str, shape: &[i64], values: &[f32]) -> pb::TensorProto {
    let float_data = values.to_vec();
    pb::TensorProto {
        float_data,
        ..constant(name, shape, pb::tensor_proto::DataType::Float)
    }
}

/// An int64 constant of `shape` (shapes, axes, indices).
pub fn ints(name: &str, shape: &[i64], values: &[i64]) -> pb::TensorProto {
    let int64_data = values.to_vec();
    pb::TensorProto {
        int64_data,
        ..constant(name, shape, pb::tensor_proto::DataType::Int64)
    }
}

/// A constant's name, shape and type, without its values.
fn constant(name: &str, shape: &[i64], data_type: pb::tensor_proto::DataType) -> pb::TensorProto {
    pb::TensorProto {
        name: name.to_owned(),
        dims: shape.to_vec(),
        data_type: data_type as i32,
        ..Default::default()
    }
}

pub fn value_info(name: &str, shape: Option<&[usize]>) -> pb::ValueInfoProto {
    use pb::tensor_shape_proto::{Dimension, dimension};
    let shape = shape.map(|shape| pb::TensorShapeProto {
        dim: shape
            .iter()
            .map(|&d| Dimension {
                value: Some(dimension::Value::DimValue(d as i64)),
                ..Default::default()
            })
            .collect(),
    });
    pb::ValueInfoProto {
        name: name.to_owned(),
        r#type: Some(pb::TypeProto {
            value: Some(pb::type_proto::Value::TensorType(pb::type_proto::Tensor {
                elem_type: pb::tensor_proto::DataType::Float as i32,
                shape,
            })),
            ..Default::default()
        }),
        ..Default::default()
    }
}

/// A model of `nodes` at `opset`: f32 inputs of the given shapes, outputs by name (shapes
/// left to inference), constants as initializers.
pub fn model(
    opset: i64,
    inputs: &[(&str, &[usize])],
    nodes: Vec<pb::NodeProto>,
    initializers: Vec<pb::TensorProto>,
    outputs: &[&str],
) -> pb::ModelProto {
    pb::ModelProto {
        ir_version: 8,
        opset_import: vec![pb::OperatorSetIdProto {
            domain: String::new(),
            version: opset,
        }],
        graph: Some(pb::GraphProto {
            name: "built".into(),
            node: nodes,
            initializer: initializers,
            input: inputs
                .iter()
                .map(|(name, shape)| value_info(name, Some(shape)))
                .collect(),
            output: outputs.iter().map(|name| value_info(name, None)).collect(),
            ..Default::default()
        }),
        ..Default::default()
    }
}
