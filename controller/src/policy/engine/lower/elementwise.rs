//! Element-wise operators: Relu, the broadcasting Add, Sub, Mul, Div and Equal, and the
//! reductions ReduceMax and ReduceSum.

use super::*;

impl Lowerer {
    /// A Relu right after a convolution or a dense layer that only it reads is folded into
    /// that step; otherwise it is a step of its own.
    pub(super) fn relu(&mut self, input: &str, output: &str) -> Lowered<()> {
        if self.single_reader(input)
            && let Some(&index) = self.producer.get(input)
        {
            let folded = match &mut self.steps[index] {
                Step::Conv { relu, .. } | Step::Dense { relu, .. } => {
                    *relu = true;
                    true
                }
                Step::QuantizedConv(conv) => {
                    conv.epilogue.relu = true;
                    true
                }
                Step::QuantizedDense(dense) => {
                    dense.epilogue.relu = true;
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
        let (buffer, shape, layout) = self.float_tensor(input, "a Relu")?;
        let len = elements(&shape)?;
        let to = self.buffer(len)?;
        self.keep_grid(buffer, to);
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

    pub(super) fn binary(
        &mut self,
        op: &str,
        a: &str,
        b: Option<&str>,
        output: &str,
    ) -> Lowered<()> {
        let b = b.or_unsupported("one operand")?;
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

    pub(super) fn reduce(&mut self, op: &Operation<'_>) -> Lowered<()> {
        let (node, attributes, output) = (op.node, &op.attributes, op.output);
        let (input, axes_input) = (op.first()?, op.input(1));
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
}
