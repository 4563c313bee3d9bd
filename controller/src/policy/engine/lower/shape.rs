//! Operators that move numbers without computing: Flatten, Reshape, Squeeze and Unsqueeze (as
//! aliases of a buffer), Transpose, Gather with constant indices, and Concat.

use super::*;

impl Lowerer {
    /// `output` is `input`'s numbers under another shape: no copy.
    pub(super) fn alias(
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
    pub(super) fn axes(
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

    pub(super) fn transpose(&mut self, op: &Operation<'_>) -> Lowered<()> {
        let (attributes, input, output) = (&op.attributes, op.first()?, op.output);
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

    pub(super) fn gather(&mut self, op: &Operation<'_>) -> Lowered<()> {
        let (attributes, input, output) = (&op.attributes, op.first()?, op.output);
        let indices = op.input(1);
        let (buffer, shape) = self.tensor(input)?;
        let indices_name = indices.or_unsupported("no indices")?;
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
        let (outer, inner) = copied_slices(&shape, axis, picked.len(), "a gather")?;
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

    pub(super) fn concat(&mut self, op: &Operation<'_>) -> Lowered<()> {
        let (node, attributes, output) = (op.node, &op.attributes, op.output);
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
                .or_unsupported("a concatenation too long")?;
        }
        let (outer, inner) = copied_slices(first, axis, parts.len(), "a concatenation")?;
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
}

/// The slices a copy along `axis` of `shape` moves, `count` of them per outer index: the
/// outer count and each slice's length. More than 4096 copy steps are refused (`what`
/// names the operation).
fn copied_slices(
    shape: &[usize],
    axis: usize,
    count: usize,
    what: &str,
) -> Lowered<(usize, usize)> {
    let outer: usize = shape[..axis].iter().product();
    let inner: usize = shape[axis + 1..].iter().product();
    if outer.checked_mul(count).is_none_or(|slices| slices > 4096) {
        return unsupported(format!("{what} of more than 4096 slices"));
    }
    Ok((outer, inner))
}
