//! One LSTM step (forward, the default activations), its gates by one dense layer.

use super::*;

impl Lowerer {
    pub(super) fn lstm(&mut self, op: &Operation<'_>) -> Lowered<()> {
        let (node, attributes) = (op.node, &op.attributes);
        let input = |i: usize| op.input(i);
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
        let (x, x_shape) = self.tensor(input(0).or_unsupported("no X")?)?;
        let [1, 1, features] = x_shape[..] else {
            return unsupported(format!("X of shape {x_shape:?}: one step of one sequence"));
        };
        let (w, w_shape) = self.weights(input(1).or_unsupported("no W")?)?;
        let (r, r_shape) = self.weights(input(2).or_unsupported("no R")?)?;
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
