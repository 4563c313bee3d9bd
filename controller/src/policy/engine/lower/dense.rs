//! Dense layers: Gemm, and a MatMul with a constant right side, whose following Add is folded
//! into the bias.

use super::*;

impl Lowerer {
    pub(super) fn gemm(&mut self, op: &Operation<'_>) -> Lowered<()> {
        let (node, attributes, output) = (op.node, &op.attributes, op.output);
        let a = node.input.first().or_unsupported("no A")?;
        let b = node.input.get(1).or_unsupported("no B")?;
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
        if let Some(step) = self.quantized_gemm(x, [m, k, n], b, transposed, alpha, bias.clone())? {
            let to = step.to;
            self.push(output, Step::QuantizedDense(Box::new(step)));
            return self.define_tensor(output, to, vec![m, n], Layout::Standard);
        }
        self.dense(output, x, relaid, bias, vec![m, n])
    }

    pub(super) fn matmul(&mut self, a: &str, b: Option<&str>, output: &str) -> Lowered<()> {
        let (x, x_shape) = self.tensor(a)?;
        let (weights, w_shape) = self.weights(b.or_unsupported("no B")?)?;
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
    pub(super) fn dense(
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

    pub(super) fn fold_bias(&mut self, product: &str, addend: &str, output: &str) -> Lowered<bool> {
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
}
