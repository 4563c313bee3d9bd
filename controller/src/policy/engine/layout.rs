//! How the engine lays out what it computes on, at the bottom of the engine: buffers are
//! named by index ([`BufferId`]), weights sit on 64-byte boundaries ([`AlignedWeights`]),
//! dense weights in column panels ([`DenseWeights`]), a convolution is described by its
//! [`ConvShape`] and an element-wise operand's broadcast or a transpose by [`Strided`]. It
//! imports nothing of the engine: the kernels, the plan and the lowering all build on it.

/// The shape of one convolution on a zero-bordered NHWC input.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct ConvShape {
    /// The padded input's width (its height is implied by the output), and channels.
    pub padded_width: usize,
    pub in_channels: usize,
    pub out_channels: usize,
    pub kernel: [usize; 2],
    pub stride: [usize; 2],
    /// Output height and width.
    pub out: [usize; 2],
}

/// One convolution layer as every kernel reads it: its shape, its weights laid out
/// `[ky][kx][in][out]`, its bias, and whether a ReLU follows (folded into the kernel).
#[derive(Clone, Copy, Debug)]
pub(crate) struct ConvLayer<'a> {
    pub shape: &'a ConvShape,
    pub weights: &'a [f32],
    pub bias: &'a [f32],
    pub relu: bool,
}

pub(crate) type BufferId = usize;

/// Weights whose first value sits on a 64-byte boundary. The vector kernels then read them
/// with aligned loads, which SSE folds into its `mulps` as a memory operand (an unaligned
/// one it cannot): no register is spent holding a weight vector, which on the V5's eight
/// registers is what made the compiler spill accumulators to the stack.
///
/// Safe code: the values start at the first aligned index of an over-allocated `Vec`, and a
/// `Vec`'s heap buffer stays where it is when the `Vec` moves.
#[derive(Clone, PartialEq)]
pub(crate) struct AlignedWeights {
    /// The values, with `SLACK` spare floats around them.
    storage: Vec<f32>,
    start: usize,
}

impl AlignedWeights {
    /// The boundary, in bytes: an AVX-512 register's width (and a cache line).
    pub(crate) const ALIGN: usize = 64;
    const SLACK: usize = Self::ALIGN / size_of::<f32>();

    pub(crate) fn new(values: &[f32]) -> Self {
        let mut storage = vec![0.0; values.len() + Self::SLACK];
        // Below SLACK for a 4-byte-aligned buffer; should it ever say "cannot", the values
        // start at 0 and the vector kernels, which check, leave the work to the generic ones.
        let start = match storage.as_ptr().align_offset(Self::ALIGN) {
            offset if offset < Self::SLACK => offset,
            _ => 0,
        };
        storage[start..start + values.len()].copy_from_slice(values);
        Self { storage, start }
    }

    pub(crate) fn as_slice(&self) -> &[f32] {
        let len = self.storage.len() - Self::SLACK;
        &self.storage[self.start..self.start + len]
    }
}

impl core::fmt::Debug for AlignedWeights {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        self.as_slice().fmt(f)
    }
}

/// A dense layer's weights in column panels, `[panel][input][width]`: `width` outputs per
/// panel (a multiple of eight, the last panel padded with zero columns). The kernel keeps a
/// panel's outputs in vector registers and walks the inputs once per panel, reading its
/// weights as one contiguous stream; an input that is zero (most features after ReLU and
/// max-pool are) is skipped together with its row of weights. The `[out][in]` layout needed
/// every weight of the 2560x128 layer on every step, 1.3 MB, more than the Atoms' L2.
#[derive(Clone, PartialEq)]
pub(crate) struct DenseWeights {
    panels: AlignedWeights,
    inputs: usize,
    outputs: usize,
    width: usize,
}

impl DenseWeights {
    /// From `rows` laid out `[out][in]` (`outputs` rows of `inputs`), `width` columns a
    /// panel, at most `max_width` and no wider than the outputs need (rounded up to eight).
    pub(crate) fn from_rows(rows: &[f32], outputs: usize, inputs: usize, max_width: usize) -> Self {
        let mut width = 8;
        while width < max_width && width < outputs {
            width *= 2;
        }
        let panels = outputs.div_ceil(width);
        let mut values = vec![0.0; panels * inputs * width];
        for (o, row) in rows.chunks_exact(inputs).take(outputs).enumerate() {
            let (panel, column) = (o / width, o % width);
            for (i, &w) in row.iter().enumerate() {
                values[(panel * inputs + i) * width + column] = w;
            }
        }
        Self {
            panels: AlignedWeights::new(&values),
            inputs,
            outputs,
            width,
        }
    }

    /// `[panel][input][width]`.
    pub(crate) fn panels(&self) -> &[f32] {
        self.panels.as_slice()
    }

    pub(crate) fn inputs(&self) -> usize {
        self.inputs
    }

    pub(crate) fn outputs(&self) -> usize {
        self.outputs
    }

    /// Outputs per panel: 8, 16, 32 or 64.
    pub(crate) fn width(&self) -> usize {
        self.width
    }
}

impl core::fmt::Debug for DenseWeights {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "DenseWeights {{ {} -> {}, panels of {} }}",
            self.inputs, self.outputs, self.width
        )
    }
}

/// The highest rank the element-wise steps index.
pub(crate) const MAX_RANK: usize = 6;

/// Walks a tensor of `shape` in row-major order and gives, for each element, an offset
/// under other `strides` (a broadcast operand, a transposed source, a reduction target).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Strided {
    rank: usize,
    shape: [usize; MAX_RANK],
    strides: [usize; MAX_RANK],
}

impl Strided {
    /// `shape` and `strides` of equal length, at most [`MAX_RANK`] (checked when lowering).
    pub(crate) fn new(shape: &[usize], strides: &[usize]) -> Self {
        let rank = shape.len().min(MAX_RANK);
        let mut s = Self {
            rank,
            shape: [1; MAX_RANK],
            strides: [0; MAX_RANK],
        };
        s.shape[..rank].copy_from_slice(&shape[..rank]);
        s.strides[..rank].copy_from_slice(&strides[..rank]);
        s
    }

    pub(crate) fn len(&self) -> usize {
        self.shape[..self.rank].iter().product()
    }

    /// Calls `visit(element, offset)` for every element in row-major order.
    #[inline(always)]
    pub(crate) fn for_each(&self, mut visit: impl FnMut(usize, usize)) {
        let mut index = [0usize; MAX_RANK];
        let mut offset = 0;
        for element in 0..self.len() {
            visit(element, offset);
            for d in (0..self.rank).rev() {
                index[d] += 1;
                offset += self.strides[d];
                if index[d] < self.shape[d] {
                    break;
                }
                offset -= self.strides[d] * self.shape[d];
                index[d] = 0;
            }
        }
    }
}

/// The uint8 grid of a QDQ graph's activation (`QuantizeLinear` then `DequantizeLinear` with
/// one `scale` and `zero` point): the values `(code - zero) * scale` for codes 0..=255. A
/// buffer whose numbers all lie on a grid holds, exactly, the integers an int8 step reads.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Grid {
    scale: f32,
    /// `1 / scale`: multiplying by it is exact on values that lie on the grid and saves the
    /// V5 a division per number (its `divss` takes tens of cycles). On a value that is not
    /// yet on the grid (the graph's input) it can round a number within an ulp of a tie the
    /// other way than ONNX's `x / scale` does; the load check bounds what that changes.
    inverse: f32,
    zero: u8,
}

impl Grid {
    /// `scale` finite and positive (the lowering refuses others).
    pub(crate) fn new(scale: f32, zero: u8) -> Option<Self> {
        (scale.is_finite() && scale > 0.0 && (1.0 / scale).is_finite()).then(|| Self {
            scale,
            inverse: 1.0 / scale,
            zero,
        })
    }

    pub(crate) fn scale(self) -> f32 {
        self.scale
    }

    pub(crate) fn zero(self) -> u8 {
        self.zero
    }

    /// `1 / scale`, as the coding multiplies by it.
    pub(crate) fn inverse(self) -> f32 {
        self.inverse
    }

    /// `x / scale` rounded half to even and clamped so that adding the zero point gives
    /// 0..=255: the code minus the zero point, as an integer-valued float. The rounding
    /// adds and takes away 1.5 x 2^23, which rounds to an integer in the current
    /// (nearest-even) mode on every instruction set, without SSE4.1's `roundps` (the V5 has
    /// none) or a call into libm; every operation is one the compiler vectorises.
    ///
    /// `max` then `min`, not `clamp`: `clamp` asserts its bounds' order and passes a NaN on,
    /// which kept the compiler from turning the coding loops into `maxps`/`minps` (a NaN
    /// becomes the lowest code here; the load check compares the outputs with tract's).
    /// Callgrind, host SSSE3, int8 CNN forward: 6.2 M instructions with `clamp`, 5.0 M
    /// without. The clamp to the codes is against constants (0 and 255, the zero point
    /// added first, exactly: both are integers below 2^24): against `-zero` and
    /// `255 - zero`, values the compiler cannot prove are not NaN, each `max` and `min`
    /// became six instructions instead of one (callgrind, V5 i686, the epilogues).
    #[inline(always)]
    fn steps(self, x: f32) -> f32 {
        self.code_value(x) - f32::from(self.zero)
    }

    /// The code of `x` as an integer-valued float, 0.0..=255.0 ([`Self::steps`]).
    #[inline(always)]
    #[allow(clippy::manual_clamp)]
    fn code_value(self, x: f32) -> f32 {
        let steps = (x * self.inverse).max(-512.0).min(512.0);
        (((steps + ROUND) - ROUND) + f32::from(self.zero))
            .max(0.0)
            .min(255.0)
    }

    /// `QuantizeLinear`: the code of `x`, saturated to 0..=255 (NaN gives a code too; the
    /// load check compares the outputs with tract's).
    #[inline(always)]
    pub(crate) fn code(self, x: f32) -> u8 {
        // An integer from 0 to 255 plus 1.5 x 2^23 holds that integer in its low byte.
        ((self.code_value(x) + ROUND).to_bits() & 0xff) as u8
    }

    /// The nearest value on the grid: `QuantizeLinear` then `DequantizeLinear`.
    #[inline(always)]
    pub(crate) fn snap(self, x: f32) -> f32 {
        self.steps(x) * self.scale
    }
}

/// 1.5 x 2^23: adding it to a float below 2^22 in magnitude leaves that number rounded to an
/// integer in the low bits of the mantissa.
const ROUND: f32 = 12_582_912.0;
