//! The static execution plan: steps over buffers that were all allocated at load. This
//! module says what a step is (its shapes, weights and buffers, and what it costs);
//! [`run`] is the loop that runs them. Running a plan allocates nothing: a step borrows its
//! output buffer out of the list (`mem::take` leaves an empty `Vec`, which costs no
//! allocation), computes from the others, and puts it back.

mod run;

pub(crate) use run::run;

use super::kernels::PoolShape;
#[cfg(target_arch = "x86_64")]
use super::kernels::int8::PooledPixelWeights;
use super::kernels::int8::{Int8Kernel, QuadPanels, Window, ZeroGroups};
use super::kernels::winograd;
use super::layout::{AlignedWeights, BufferId, ConvShape, DenseWeights, Grid, Strided};

/// A max-pool folded into the convolution before it: the convolution's rows under one row
/// of pooling windows (`kernel[0]` of them) are computed into `scratch` and pooled at once,
/// so the full-size map is never written out. Only for windows that do not overlap
/// vertically (`stride[0] >= kernel[0]`), so that each convolution row is computed once.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct ConvPool {
    pub kernel: [usize; 2],
    pub stride: [usize; 2],
    /// The pooled map's height and width.
    pub out: [usize; 2],
    /// `kernel[0]` rows of the convolution's output.
    pub scratch: BufferId,
    /// The padded image's phase planes, where the layer is one the instruction set may run
    /// vectorised over pooled pixels ([`super::kernels::single_channel_pool`]).
    pub planes: Option<BufferId>,
}

/// A convolution and its pool as [`winograd`] computes them: the transformed weights and the
/// scratch of one row of tiles.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct WinogradConv {
    pub layer: winograd::Layer,
    pub weights: AlignedWeights,
    /// `[tile][point][4 * in]`
    pub transformed: BufferId,
    /// `[tile][point][out]`
    pub products: BufferId,
}

/// What an int8 layer does with its exact integer sums, output by output: back to the float
/// its QDQ graph computes (`(sum - zero x sum of weights) x input scale x weight scale +
/// bias`), then the output's own `QuantizeLinear`/`DequantizeLinear` pair where the graph
/// has one (`output`), then the ReLU where the graph has one. The ReLU and the grid commute
/// (the grid is monotonic and holds 0.0), so their order in the graph does not matter.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Epilogue {
    /// The input's zero point times each output's sum of weights (a convolution's for each
    /// output pixel of a row in turn: [`Self::tiled`]).
    pub offsets: Vec<i32>,
    /// Input scale times each output's weight scale (tiled as `offsets`).
    pub scales: Vec<f32>,
    /// Tiled as `offsets`.
    pub bias: Vec<f32>,
    pub relu: bool,
    pub output: Option<Grid>,
}

impl Epilogue {
    /// The epilogue of each sum of `sums` (whole cells of one sum per output: output pixels
    /// or pooled outputs, or one row of a dense layer) into the same place in `out`. One
    /// call for a whole row of cells: the case and its constants are set up once, where one
    /// call a cell cost about 35 instructions each on the V5 (callgrind).
    #[inline(always)]
    fn apply(&self, sums: &[i32], out: &mut [f32]) {
        // One loop per case, each a straight line the compiler vectorises inside the
        // instruction set's function (three passes over the outputs cost about 16
        // instructions an output; callgrind, host AVX2, int8 CNN forward).
        match (self.output, self.relu) {
            (None, false) => self.each(sums, out, |y| y),
            (None, true) => self.each(sums, out, |y| y.max(0.0)),
            (Some(grid), false) => self.each(sums, out, |y| grid.snap(y)),
            (Some(grid), true) => self.each(sums, out, |y| grid.snap(y).max(0.0)),
        }
    }

    /// `out[o] = finish((sums[o] - offset) x scale + bias)`, one loop over the whole row of
    /// cells (the terms are [`Self::tiled`] to it: with a loop per cell, its set-up and
    /// tail cost more than its eight outputs on the V5, callgrind).
    #[inline(always)]
    fn each(&self, sums: &[i32], out: &mut [f32], finish: impl Fn(f32) -> f32) {
        assert!(
            sums.len() == out.len() && sums.len() <= self.offsets.len(),
            "int8 epilogue of {} sums for {} terms",
            sums.len(),
            self.offsets.len()
        );
        let terms = sums
            .iter()
            .zip(&self.offsets)
            .zip(self.scales.iter().zip(&self.bias));
        for (y, ((&sum, &offset), (&scale, &bias))) in out.iter_mut().zip(terms) {
            // Exact: the lowering caps the inputs so that both terms stay below 2^30.
            *y = finish((sum - offset) as f32 * scale + bias);
        }
    }

    /// The per-output terms repeated for `cells` cells one after the other, so that
    /// [`Self::apply`] takes a row of that many cells (output pixels or pooled outputs) in
    /// one loop.
    pub(crate) fn tiled(mut self, cells: usize) -> Self {
        self.offsets = self.offsets.repeat(cells);
        self.scales = self.scales.repeat(cells);
        self.bias = self.bias.repeat(cells);
        self
    }
}

/// An int8 convolution (a QDQ graph's `Conv` between int8 weights and an input on a grid):
/// the input's codes into a zero-bordered byte map, then per output pixel its window and
/// one int8 dense product with every output channel's weights.
pub(crate) struct QuantizedConv {
    /// The float map, `[h][w][c]` (or `[c][h][w]`, `from_nchw`), on the grid `input`.
    pub from: BufferId,
    pub size: [usize; 3],
    pub from_nchw: bool,
    /// Top and left padding.
    pub origin: [usize; 2],
    pub input: Grid,
    pub window: Window,
    /// Output height and width (channels: the weights' outputs).
    pub out_size: [usize; 2],
    /// `[out channel][ky][kx][c]` rows.
    pub weights: QuadPanels,
    pub kernel: Int8Kernel,
    /// Whether the kernel skips groups of sixteen zero codes: not on a camera's pixels.
    pub zeros: ZeroGroups,
    pub epilogue: Epilogue,
    /// Scratch, allocated at load: the padded map's codes (the border holds the zero
    /// point; [`Window::slack`] bytes after it), the windows of one row of outputs (pixels,
    /// or pool cells of several pixels each), each [`Window::padded_len`] bytes, and that
    /// row's sums.
    pub codes: Vec<u8>,
    pub windows: Vec<u8>,
    pub sums: Vec<i32>,
    /// NHWC floats: the pooled map where `pool` is set, else the convolution's.
    pub out: BufferId,
    pub pool: Option<QuantizedPool>,
    /// The weights laid out for the kernel that computes a one-channel layer's pool cells
    /// over pooled pixels, where the layer is that kernel's (x86-64 only: the V5's eight
    /// registers are not the sixteen its sums and loads were laid out for).
    #[cfg(target_arch = "x86_64")]
    pub pooled_pixels: Option<PooledPixelWeights>,
}

/// A max-pool folded into the int8 convolution before it. Each pooled output is the epilogue
/// of the largest sum in its window: the epilogue is non-decreasing in the sum (positive
/// scales, then the grid and the ReLU, both monotonic; the lowering folds only then), so
/// taking the largest sum first gives the very numbers a separate pool of the epilogue's
/// floats gives, with one epilogue per pooled output instead of one per pixel, and no pixel
/// computed that no window reads.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct QuantizedPool {
    pub kernel: [usize; 2],
    pub stride: [usize; 2],
    /// The pooled map's height and width.
    pub out: [usize; 2],
}

impl core::fmt::Debug for QuantizedConv {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let [kh, kw] = self.window.kernel;
        let [oh, ow] = self.out_size;
        write!(
            f,
            "QuantizedConv {{ {kh}x{kw}x{} -> {}, {oh}x{ow}, {}",
            self.window.channels,
            self.weights.outputs(),
            self.kernel.name()
        )?;
        if let Some(pool) = &self.pool {
            let ([ph, pw], [sh, sw], [h, w]) = (pool.kernel, pool.stride, pool.out);
            write!(f, ", max-pool {ph}x{pw} stride {sh}x{sw} -> {h}x{w}")?;
        }
        write!(f, " }}")
    }
}

/// An int8 dense layer (a QDQ graph's `Gemm`/`MatMul` between int8 weights and an input on
/// a grid), row by row.
pub(crate) struct QuantizedDense {
    pub from: BufferId,
    pub input: Grid,
    pub rows: usize,
    /// `[out][in]` rows.
    pub weights: QuadPanels,
    pub kernel: Int8Kernel,
    pub epilogue: Epilogue,
    /// Scratch: one row's codes (padded to whole quads with zeros) and sums.
    pub codes: Vec<u8>,
    pub sums: Vec<i32>,
    pub to: BufferId,
}

impl core::fmt::Debug for QuantizedDense {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "QuantizedDense {{ {} -> {}, {} row(s), {} }}",
            self.weights.inputs(),
            self.weights.outputs(),
            self.rows,
            self.kernel.name()
        )
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum BinaryOp {
    Add,
    Sub,
    Mul,
    Div,
    /// 1.0 where equal, else 0.0.
    Equal,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum ReduceOp {
    Max,
    Sum,
}

/// One step of a plan. Weights live in the step, laid out for its kernel.
#[derive(Debug)]
pub(crate) enum Step {
    /// Copies a `[h][w][c]` map (or a `[c][h][w]` one, `from_nchw`) into the interior of a
    /// zero-bordered NHWC buffer at `origin` (top and left padding); the border stays zero.
    Pad {
        from: BufferId,
        to: BufferId,
        size: [usize; 3],
        origin: [usize; 2],
        padded_width: usize,
        from_nchw: bool,
    },
    /// A convolution, with its ReLU and the max-pool after it where the graph has them.
    Conv {
        padded: BufferId,
        weights: AlignedWeights,
        bias: Vec<f32>,
        shape: ConvShape,
        relu: bool,
        /// When set, `out` holds the pooled map and the full-size one never exists.
        pool: Option<ConvPool>,
        /// With a pool, the same layer with fewer multiplications, where the kernels take it.
        winograd: Option<WinogradConv>,
        out: BufferId,
    },
    MaxPool {
        from: BufferId,
        to: BufferId,
        shape: PoolShape,
    },
    NhwcToNchw {
        from: BufferId,
        to: BufferId,
        size: [usize; 3],
    },
    /// `rows` rows of `from` times `weights` plus `bias`.
    Dense {
        from: BufferId,
        weights: DenseWeights,
        bias: Vec<f32>,
        rows: usize,
        relu: bool,
        to: BufferId,
    },
    /// One LSTM step: `[x, h_in]` into `joined`, one dense layer into `gates`, then the
    /// cell update from `c_in` into `c_out` and `h_out`.
    Lstm {
        x: BufferId,
        h_in: BufferId,
        c_in: BufferId,
        joined: BufferId,
        weights: DenseWeights,
        bias: Vec<f32>,
        gates: BufferId,
        h_out: BufferId,
        c_out: BufferId,
    },
    Copy {
        from: BufferId,
        from_offset: usize,
        to: BufferId,
        to_offset: usize,
        len: usize,
    },
    /// `to[i] = from[source offset of i]`: a transpose.
    Gather {
        from: BufferId,
        source: Strided,
        to: BufferId,
    },
    Relu {
        from: BufferId,
        to: BufferId,
        len: usize,
    },
    Binary {
        op: BinaryOp,
        a: BufferId,
        a_index: Strided,
        b: BufferId,
        b_index: Strided,
        to: BufferId,
    },
    /// Element `i` of `from` goes into `to[target offset of i]`.
    Reduce {
        op: ReduceOp,
        from: BufferId,
        target: Strided,
        to: BufferId,
    },
    /// A `QuantizeLinear`/`DequantizeLinear` pair no step before it could take in.
    SnapToGrid {
        from: BufferId,
        to: BufferId,
        len: usize,
        grid: Grid,
    },
    QuantizedConv(Box<QuantizedConv>),
    QuantizedDense(Box<QuantizedDense>),
}

impl Step {
    /// The multiply-adds one run of this step computes: a convolution's output pixels (the
    /// rows a folded pool reads) times its window, a dense layer's or an LSTM gate layer's
    /// weights (zero inputs counted too: they are skipped at run time, as many as there are).
    pub(crate) fn multiply_adds(&self) -> u64 {
        let count = match self {
            Self::Conv {
                winograd: Some(winograd),
                ..
            } => winograd.layer.multiply_adds(),
            Self::Conv { shape, pool, .. } => {
                let [oh, ow] = shape.out;
                let rows = pool.map_or(oh, |pool| pool.out[0] * pool.kernel[0]);
                rows * ow
                    * shape.kernel[0]
                    * shape.kernel[1]
                    * shape.in_channels
                    * shape.out_channels
            }
            Self::Dense { weights, rows, .. } => rows * weights.inputs() * weights.outputs(),
            Self::Lstm { weights, .. } => weights.inputs() * weights.outputs(),
            Self::QuantizedConv(conv) => {
                let pixels = conv.pool.as_ref().map_or(conv.out_size, |pool| {
                    [pool.out[0] * pool.kernel[0], pool.out[1] * pool.kernel[1]]
                });
                pixels[0]
                    * pixels[1]
                    * conv.window.kernel[0]
                    * conv.window.row()
                    * conv.weights.outputs()
            }
            Self::QuantizedDense(dense) => {
                dense.rows * dense.weights.inputs() * dense.weights.outputs()
            }
            _ => 0,
        };
        count as u64
    }

    /// A short name for reports (`dribble-controller forward --layers`): the operator, and
    /// for the layers with weights their kernel and channels.
    pub(crate) fn describe(&self) -> String {
        match self {
            Self::Conv {
                shape,
                pool,
                winograd,
                ..
            } => format!(
                "conv {}x{} {}->{}{}{}{}",
                shape.kernel[0],
                shape.kernel[1],
                shape.in_channels,
                shape.out_channels,
                if shape.stride != [1, 1] {
                    " strided"
                } else {
                    ""
                },
                if pool.is_some() { " +pool" } else { "" },
                if winograd.is_some() { " winograd" } else { "" },
            ),
            Self::QuantizedConv(conv) => format!(
                "int8 conv {}x{} {}->{}{}",
                conv.window.kernel[0],
                conv.window.kernel[1],
                conv.size[2],
                conv.weights.outputs(),
                if conv.pool.is_some() { " +pool" } else { "" },
            ),
            Self::Dense { weights, .. } => {
                format!("dense {}->{}", weights.inputs(), weights.outputs())
            }
            Self::QuantizedDense(dense) => format!(
                "int8 dense {}->{}",
                dense.weights.inputs(),
                dense.weights.outputs()
            ),
            Self::Lstm { weights, .. } => {
                format!("lstm {}->{}", weights.inputs(), weights.outputs())
            }
            Self::Pad { .. } => "pad".into(),
            Self::MaxPool { .. } => "max-pool".into(),
            Self::NhwcToNchw { .. } => "nhwc-to-nchw".into(),
            Self::Copy { .. } => "copy".into(),
            Self::Gather { .. } => "gather".into(),
            Self::Relu { .. } => "relu".into(),
            Self::Binary { op, .. } => format!("{op:?}").to_lowercase(),
            Self::Reduce { op, .. } => format!("{op:?}").to_lowercase(),
            Self::SnapToGrid { .. } => "snap-to-grid".into(),
        }
    }

    /// The bytes of the weights this step reads each run (f32 or int8 codes).
    pub(crate) fn weight_bytes(&self) -> u64 {
        let bytes = match self {
            Self::Conv { shape, .. } => {
                4 * shape.kernel[0] * shape.kernel[1] * shape.in_channels * shape.out_channels
            }
            Self::Dense { weights, .. } | Self::Lstm { weights, .. } => {
                4 * weights.inputs() * weights.outputs()
            }
            Self::QuantizedConv(conv) => {
                conv.window.kernel[0] * conv.window.row() * conv.weights.outputs()
            }
            Self::QuantizedDense(dense) => dense.weights.inputs() * dense.weights.outputs(),
            _ => 0,
        };
        bytes as u64
    }

    /// The buffers this step reads, and the ones it writes.
    pub(crate) fn buffers(&self) -> (Vec<BufferId>, Vec<BufferId>) {
        match self {
            Self::Pad { from, to, .. }
            | Self::MaxPool { from, to, .. }
            | Self::NhwcToNchw { from, to, .. }
            | Self::Dense { from, to, .. }
            | Self::Copy { from, to, .. }
            | Self::Gather { from, to, .. }
            | Self::Relu { from, to, .. }
            | Self::Reduce { from, to, .. }
            | Self::SnapToGrid { from, to, .. } => (vec![*from], vec![*to]),
            Self::QuantizedConv(conv) => (vec![conv.from], vec![conv.out]),
            Self::QuantizedDense(dense) => (vec![dense.from], vec![dense.to]),
            Self::Conv {
                padded,
                pool,
                winograd,
                out,
                ..
            } => {
                let mut writes = vec![*out];
                writes.extend(
                    pool.iter()
                        .flat_map(|pool| [Some(pool.scratch), pool.planes])
                        .flatten(),
                );
                if let Some(winograd) = winograd {
                    writes.extend([winograd.transformed, winograd.products]);
                }
                (vec![*padded], writes)
            }
            Self::Binary { a, b, to, .. } => (vec![*a, *b], vec![*to]),
            Self::Lstm {
                x,
                h_in,
                c_in,
                joined,
                gates,
                h_out,
                c_out,
                ..
            } => (
                vec![*x, *h_in, *c_in],
                vec![*joined, *gates, *h_out, *c_out],
            ),
        }
    }
}
