//! A 5x5 convolution of stride two followed by a 2x2 max-pool of stride two, computed with
//! fewer multiplications: Winograd's minimal filtering, F(2x2, 3x3), on the input's four
//! phases.
//!
//! Why: the direct convolution is bound by its multiply-adds, and the kernels already run
//! at about three quarters of the arithmetic peak (`CompiledNetwork::profile`); the only way
//! left to a faster layer is less arithmetic. The top camera's second layer (16 to 32
//! channels) is 57 % of the CNN's multiply-adds.
//!
//! How:
//! - Phases. With `ky = 2i + a` and `kx = 2j + b`, a stride-two convolution is the sum over
//!   the four phases `(a, b)` of stride-one convolutions of the subsampled input
//!   `X_ab[r][s] = X[2r + a][2s + b]` with the 3x3 kernels `K_ab[i][j] = K[2i + a][2j + b]`
//!   (zero where `2i + a` or `2j + b` passes 4). The four phases are four times the input
//!   channels of one 3x3 stride-one convolution.
//! - F(2x2, 3x3) computes a 2x2 tile of that convolution from a 4x4 tile of its input with
//!   16 products per input and output channel instead of 36: `Y = A^T [(G g G^T) ⊙ (B^T d
//!   B)] A`. Summed over the input channels, the 16 element-wise products become 16 matrix
//!   products (tiles by `4 * in` times `4 * in` by `out`), where the time goes.
//! - A 2x2 output tile is exactly one window of the 2x2 pool, so the pool (and the bias and
//!   ReLU, both monotone, after the maximum) fold into the output transform: the full-size
//!   map never exists.
//!
//! Per output value and input channel: 16 multiply-adds against the direct 25 (0.64 of the
//! arithmetic; the zero taps of the odd phases cost a little of the 0.44 F(2x2, 3x3) would
//! give alone). The transforms add and subtract only, and `B`, `A` hold 0 and ±1, so the
//! rounding differs from the direct sum by a few units in the last place (checked against
//! tract: within 1e-5 on every fixture and shipped model, `tests/engine_parity.rs`).
//!
//! Measured (AMD EPYC Zen 3, one thread, `profile_the_cnn_fixture`): the top camera's
//! second layer 83 -> 63 µs with AVX2+FMA and 236 -> 189 µs with SSE (146 µs once SSE took
//! one tile by all 32 output channels per block: its broadcasts are shuffles, on the pipes
//! the arithmetic uses, so each must feed as many multiplies as it can); the CNN fixture's
//! forward 167 -> 143 µs (AVX2+FMA). Its multiply-adds: 6.33 M -> 4.95 M. The products run at
//! about 90 % of the AVX2 peak; the transforms take about a sixth of the layer.
//!
//! A 2x2 output tile reads an 8x8 patch of the padded input: the eighth row and column meet
//! only the zero taps, but they are read (a zero weight after `G` is not zero), so the
//! padded buffer must hold them; [`Layer::new`] checks, and the lowering gives the padded
//! buffer the rows it lacks (they stay zero).

use crate::policy::engine::layout::AlignedWeights;

/// The transform points of F(2x2, 3x3): a 4x4 tile.
pub(crate) const POINTS: usize = 16;

/// Floats a scratch buffer holds beyond its use, to start its use on a 64-byte boundary
/// (the engine's buffers are `Vec<f32>`, on the allocator's 16).
const SCRATCH_SLACK: usize = 16;

/// `G`, the kernel transform (3 taps to 4 points).
const G: [[f64; 3]; 4] = [
    [1.0, 0.0, 0.0],
    [0.5, 0.5, 0.5],
    [0.5, -0.5, 0.5],
    [0.0, 0.0, 1.0],
];

/// Which layers an instruction set's kernels take by this method ([`crate::policy::engine::Isa::winograd_fit`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Fit {
    /// The lanes of the kernels' vectors: the input channels must be a whole number of
    /// them, the output channels of twice as many.
    pub lanes: usize,
    /// The fewest input channels a layer must have to gain: below it the transforms cost
    /// more than the saved multiply-adds.
    pub min_in_channels: usize,
}

impl Fit {
    /// Whether a layer of `in_channels` to `out_channels` suits the kernels.
    pub(crate) fn takes(self, in_channels: usize, out_channels: usize) -> bool {
        in_channels >= self.min_in_channels
            && in_channels.is_multiple_of(self.lanes)
            && out_channels.is_multiple_of(2 * self.lanes)
    }
}

/// A convolution-and-pool layer as the Winograd kernels take it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Layer {
    /// The padded input's width and its number of rows (including rows past the
    /// convolution's own, which the last tiles read).
    pub padded: [usize; 2],
    pub in_channels: usize,
    pub out_channels: usize,
    /// The pooled map's height and width: one 2x2 output tile each.
    pub tiles: [usize; 2],
}

impl Layer {
    /// The layer for a convolution of `kernel` and `stride` on a padded input of
    /// `padded_width` and `padded_rows` (`[width, rows]`), pooled by `pool_kernel` and
    /// `pool_stride` into `tiles`, or `None` where this method does not apply: a kernel
    /// other than 5x5 with stride two, a pool other than 2x2 with stride two, or a last tile
    /// whose columns would pass the padded width. `padded_rows` may be short of the last
    /// tile's rows: [`Self::padded_rows_needed`] says how many it needs.
    pub(crate) fn new(
        [kernel, stride]: [[usize; 2]; 2],
        [pool_kernel, pool_stride]: [[usize; 2]; 2],
        [padded_width, padded_rows]: [usize; 2],
        [in_channels, out_channels]: [usize; 2],
        tiles @ [th, tw]: [usize; 2],
    ) -> Option<Self> {
        // Sizes from a model file: every product checked, so none wraps on a 32-bit robot.
        let product = |factors: &[usize]| {
            factors
                .iter()
                .try_fold(1usize, |n, &f| n.checked_mul(f))
                .filter(|&n| n <= isize::MAX as usize / 4)
        };
        let rows = (th.checked_sub(1)?).checked_mul(4)?.checked_add(8)?;
        let applies = kernel == [5, 5]
            && stride == [2, 2]
            && pool_kernel == [2, 2]
            && pool_stride == [2, 2]
            && tw > 0
            && (tw - 1)
                .checked_mul(4)
                .and_then(|n| n.checked_add(8))
                .is_some_and(|n| n <= padded_width)
            && product(&[padded_width, padded_rows.max(rows), in_channels]).is_some()
            && product(&[POINTS, tw, 4, in_channels, 2]).is_some()
            && product(&[POINTS, tw, out_channels, 2]).is_some()
            && product(&[POINTS, 4, in_channels, out_channels]).is_some()
            && product(&[th, tw, out_channels]).is_some();
        applies.then(|| Self {
            padded: [padded_width, padded_rows.max(rows)],
            in_channels,
            out_channels,
            tiles,
        })
    }

    /// Rows of the padded input the tiles read: the buffer must hold this many.
    pub(crate) fn padded_rows_needed(&self) -> usize {
        self.padded[1]
    }

    /// The scratch one row of tiles needs: transformed inputs `[tile][point][4 * in]` and
    /// products `[tile][point][out]`, each with [`SCRATCH_SLACK`] floats to start on a
    /// vector boundary.
    pub(crate) fn scratch(&self) -> [usize; 2] {
        let tw = self.tiles[1];
        [
            POINTS * tw * 4 * self.in_channels + SCRATCH_SLACK,
            POINTS * tw * self.out_channels + SCRATCH_SLACK,
        ]
    }

    /// The multiply-adds of one run: the 16 matrix products of every row of tiles.
    pub(crate) fn multiply_adds(&self) -> usize {
        let [th, tw] = self.tiles;
        POINTS * th * tw * 4 * self.in_channels * self.out_channels
    }
}

/// The transformed weights `U[point][phase * in + c][out]` (`G g G^T` of each phase's 3x3
/// kernel) from the direct layout `[ky][kx][in][out]` of a 5x5 kernel, computed in `f64` and
/// rounded once.
pub(crate) fn transform_weights(
    direct: &[f32],
    in_channels: usize,
    out_channels: usize,
) -> AlignedWeights {
    let (ic, oc) = (in_channels, out_channels);
    let at = |ky: usize, kx: usize, c: usize, o: usize| -> f64 {
        if ky < 5 && kx < 5 {
            f64::from(direct[((ky * 5 + kx) * ic + c) * oc + o])
        } else {
            0.0
        }
    };
    let mut u = vec![0.0f32; POINTS * 4 * ic * oc];
    for (a, b) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
        let phase = 2 * a + b;
        for c in 0..ic {
            for o in 0..oc {
                for (r, gr) in G.iter().enumerate() {
                    for (s, gs) in G.iter().enumerate() {
                        let mut sum = 0.0;
                        for (i, &gri) in gr.iter().enumerate() {
                            for (j, &gsj) in gs.iter().enumerate() {
                                sum += gri * at(2 * i + a, 2 * j + b, c, o) * gsj;
                            }
                        }
                        u[((r * 4 + s) * 4 * ic + phase * ic + c) * oc + o] = sum as f32;
                    }
                }
            }
        }
    }
    AlignedWeights::new(&u)
}

/// One layer's convolution and pool as [`conv_pool`] computes them: the layer, its
/// zero-bordered NHWC input, the transformed weights ([`transform_weights`]), bias and ReLU,
/// the two scratch buffers ([`Layer::scratch`]) and the pooled map.
#[derive(Debug)]
pub(crate) struct Operands<'a> {
    pub layer: &'a Layer,
    pub padded: &'a [f32],
    pub weights: &'a [f32],
    pub bias: &'a [f32],
    pub relu: bool,
    pub transformed: &'a mut [f32],
    pub products: &'a mut [f32],
    pub out: &'a mut [f32],
}

#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
pub(crate) use vector::conv_pool;

#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
mod vector {
    #![allow(unsafe_code)]

    use super::{Layer, Operands, POINTS, SCRATCH_SLACK};
    use crate::policy::engine::kernels::simd::Vector;

    /// `B^T d` along one dimension: four vectors into four.
    #[inline(always)]
    fn input_transform<V: Vector>([d0, d1, d2, d3]: [V; 4]) -> [V; 4] {
        [
            V::sub(d0, d2),
            V::add(d1, d2),
            V::sub(d2, d1),
            V::sub(d1, d3),
        ]
    }

    /// `B^T` over one column of a phase: the four inputs from `x`, `stride` floats apart.
    ///
    /// # Safety
    /// `x + i * stride` must point at `LANES` readable floats for `i` in `0..4`.
    #[inline(always)]
    unsafe fn column<V: Vector>(x: *const f32, stride: usize) -> [V; 4] {
        // SAFETY: the caller's promise. (Loads in a loop, not `array::from_fn`: a closure does
        // not inherit the caller's target features, and its intrinsics then stay calls.)
        let mut d = [V::zero(); 4];
        for (i, d) in d.iter_mut().enumerate() {
            *d = unsafe { V::load_unchecked(x.add(i * stride)) };
        }
        input_transform(d)
    }

    /// `A^T m` along one dimension: four vectors into two.
    #[inline(always)]
    fn output_transform<V: Vector>([m0, m1, m2, m3]: [V; 4]) -> [V; 2] {
        [V::add(V::add(m0, m1), m2), V::sub(V::sub(m1, m2), m3)]
    }

    /// The part of `scratch` from its first `LANES`-float boundary on, `len` long, if it
    /// holds that much: vector stores that straddle cache lines cost a third of the layer.
    #[inline(always)]
    fn aligned<V: Vector>(scratch: &mut [f32], len: usize) -> Option<&mut [f32]> {
        let skip = scratch.as_ptr().align_offset(V::LANES * size_of::<f32>());
        scratch.get_mut(skip..skip.checked_add(len)?)
    }

    /// The layer's pooled map (NHWC, `tiles` by `out_channels`) from its zero-bordered NHWC
    /// input `padded` (`[rows][width][in]`): for each row of tiles, the inputs' transform into
    /// `transformed`, the 16 matrix products with `weights` (from
    /// [`super::transform_weights`]) into `products` in blocks of `P` tiles by `VECS` vectors
    /// of output channels, then the output transform, maximum, bias and ReLU into `out`.
    /// Returns false, having written nothing, where the channels are not whole vectors and
    /// groups or a buffer is short.
    #[inline(always)]
    pub(crate) fn conv_pool<V: Vector, const P: usize, const VECS: usize>(
        conv: &mut Operands<'_>,
    ) -> bool {
        let (layer, padded, weights, bias, relu) =
            (conv.layer, conv.padded, conv.weights, conv.bias, conv.relu);
        let (transformed, products, out) =
            (&mut *conv.transformed, &mut *conv.products, &mut *conv.out);
        let (ic, oc) = (layer.in_channels, layer.out_channels);
        let [width, rows] = layer.padded;
        let [th, tw] = layer.tiles;
        let [transformed_len, products_len] = layer.scratch().map(|len| len - SCRATCH_SLACK);
        let (Some(transformed), Some(products)) = (
            aligned::<V>(transformed, transformed_len),
            aligned::<V>(products, products_len),
        ) else {
            return false;
        };
        // Checked arithmetic throughout: these bounds are what every unchecked offset below
        // rests on (`Layer::new` refuses sizes whose products wrap).
        let fits = |factors: &[usize], len: usize| {
            factors
                .iter()
                .try_fold(1usize, |n, &f| n.checked_mul(f))
                .is_some_and(|n| n <= len)
        };
        let reach = |tiles: usize| tiles.checked_sub(1).map(|t| 4 * t + 8);
        if ic == 0
            || !ic.is_multiple_of(V::LANES)
            || oc == 0
            || !oc.is_multiple_of(VECS * V::LANES)
            || tw < P
            || !fits(&[rows, width, ic], padded.len())
            || reach(th).is_none_or(|needed| rows < needed)
            || reach(tw).is_none_or(|needed| width < needed)
            || !fits(&[POINTS, 4, ic, oc], weights.len())
            || !weights
                .as_ptr()
                .addr()
                .is_multiple_of(V::LANES * size_of::<f32>())
            || !fits(&[th, tw, oc], out.len())
            || bias.len() < oc
        {
            return false;
        }
        let scratch = Scratch {
            transformed,
            products,
        };
        // The networks' sizes known when compiling: every offset inside a tile a constant.
        match (ic, oc) {
            (16, 32) => rows_of_tiles::<V, P, VECS, 16, 32>(
                layer, padded, weights, bias, relu, scratch, out,
            ),
            (8, 16) => {
                rows_of_tiles::<V, P, VECS, 8, 16>(layer, padded, weights, bias, relu, scratch, out)
            }
            _ => {
                rows_of_tiles::<V, P, VECS, 0, 0>(layer, padded, weights, bias, relu, scratch, out)
            }
        }
        true
    }

    /// One row of tiles' scratch, on `LANES`-float boundaries: transformed inputs
    /// `[tile][point][4 * in]` and products `[tile][point][out]`.
    struct Scratch<'a> {
        transformed: &'a mut [f32],
        products: &'a mut [f32],
    }

    /// [`conv_pool`] once its sizes are checked; `IC` and `OC`: the channels when known at
    /// compile time, 0 when not.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)] // one layer
    fn rows_of_tiles<
        V: Vector,
        const P: usize,
        const VECS: usize,
        const IC: usize,
        const OC: usize,
    >(
        layer: &Layer,
        padded: &[f32],
        weights: &[f32],
        bias: &[f32],
        relu: bool,
        scratch: Scratch<'_>,
        out: &mut [f32],
    ) {
        let ic = if IC == 0 { layer.in_channels } else { IC };
        let oc = if OC == 0 { layer.out_channels } else { OC };
        let k = 4 * ic;
        let width = layer.padded[0];
        let [th, tw] = layer.tiles;
        let Scratch {
            transformed,
            products,
        } = scratch;
        let row = width * ic;
        for ty in 0..th {
            // Inputs: each tile's four phases, a 4x4 patch of every other row and column,
            // transformed along its columns, then along its rows. Neighbouring tiles share
            // two columns of each phase: those columns' transforms are computed once.
            for (phase, (a, b)) in [(0, 0), (0, 1), (1, 0), (1, 1)].into_iter().enumerate() {
                let top = (4 * ty + a) * row;
                for c in (0..ic).step_by(V::LANES) {
                    // Column q of the phase: padded column b + 2q.
                    // SAFETY (each `column`): rows 4 ty + a + 2r < 4 (th - 1) + 8 <= rows and
                    // columns b + 2q <= b + 2 (2 (tw - 1) + 3) < 4 (tw - 1) + 8 <= width
                    // (checked by `conv_pool`), c + LANES <= ic: inside `padded`, which
                    // holds rows * width * ic values.
                    let x = unsafe { padded.as_ptr().add(top + b * ic + c) };
                    let mut t = [[V::zero(); 4]; 4];
                    t[0] = unsafe { column(x, 2 * row) };
                    t[1] = unsafe { column(x.add(2 * ic), 2 * row) };
                    for tx in 0..tw {
                        let x = unsafe { x.add(4 * tx * ic) };
                        t[2] = unsafe { column(x.add(4 * ic), 2 * row) };
                        t[3] = unsafe { column(x.add(6 * ic), 2 * row) };
                        // SAFETY: tile tx's 16 * k values lie inside `transformed`
                        // (tw * 16 * k, checked), and point * k + phase * ic + c + LANES
                        // <= 16 * k.
                        let target = unsafe {
                            transformed
                                .as_mut_ptr()
                                .add(tx * POINTS * k + phase * ic + c)
                        };
                        // Row r of the four columns' transforms: r indexes their insides.
                        #[allow(clippy::needless_range_loop)]
                        for r in 0..4 {
                            let v = input_transform([t[0][r], t[1][r], t[2][r], t[3][r]]);
                            for (s, v) in v.into_iter().enumerate() {
                                unsafe { v.store_unchecked(target.add((r * 4 + s) * k)) };
                            }
                        }
                        t[0] = t[2];
                        t[1] = t[3];
                    }
                }
            }
            // The 16 matrix products: for each point, [tile][k] by [k][out].
            for point in 0..POINTS {
                let u = &weights[point * k * oc..(point + 1) * k * oc];
                for group in (0..oc).step_by(VECS * V::LANES) {
                    for block in 0..tw / P {
                        product_block::<V, P, VECS, IC, OC>(
                            transformed,
                            u,
                            [k, oc],
                            [block * P, point, group],
                            products,
                        );
                    }
                    if !tw.is_multiple_of(P) {
                        // The last block overlaps the one before: those tiles are computed
                        // twice, identically.
                        product_block::<V, P, VECS, IC, OC>(
                            transformed,
                            u,
                            [k, oc],
                            [tw - P, point, group],
                            products,
                        );
                    }
                }
            }
            // Outputs: A^T M A, the 2x2 tile's maximum, bias, ReLU.
            let zero = V::zero();
            let out_row = &mut out[ty * tw * oc..(ty + 1) * tw * oc];
            for tx in 0..tw {
                let tile = &products[tx * POINTS * oc..(tx + 1) * POINTS * oc];
                for o in (0..oc).step_by(V::LANES) {
                    let mut m = [V::zero(); POINTS];
                    for (point, m) in m.iter_mut().enumerate() {
                        // SAFETY: point * oc + o + LANES <= 16 * oc, the tile's length.
                        *m =
                            unsafe { V::load_aligned_unchecked(tile.as_ptr().add(point * oc + o)) };
                    }
                    let mut t = [[V::zero(); 2]; 4];
                    for (s, t) in t.iter_mut().enumerate() {
                        *t = output_transform([m[s], m[4 + s], m[8 + s], m[12 + s]]);
                    }
                    let [y00, y01] = output_transform([t[0][0], t[1][0], t[2][0], t[3][0]]);
                    let [y10, y11] = output_transform([t[0][1], t[1][1], t[2][1], t[3][1]]);
                    let most = V::max(V::max(y00, y01), V::max(y10, y11));
                    let value = V::add(most, V::load(&bias[o..]));
                    let value = if relu { V::max(value, zero) } else { value };
                    value.store(&mut out_row[tx * oc + o..]);
                }
            }
        }
    }

    /// Tiles `first..first + P` of one point's product `m[tile][point][o] = Σ_i
    /// t[tile][point][i] u[i][o]`, output channels `group..group + VECS * LANES`.
    #[inline(always)]
    fn product_block<
        V: Vector,
        const P: usize,
        const VECS: usize,
        const IC: usize,
        const OC: usize,
    >(
        transformed: &[f32],
        u: &[f32],
        [k, oc]: [usize; 2],
        [first, point, group]: [usize; 3],
        products: &mut [f32],
    ) {
        let k = if IC == 0 { k } else { 4 * IC };
        let oc = if OC == 0 { oc } else { OC };
        let tile = POINTS * k;
        // The caller checked the sizes: `transformed` holds tiles first..first + P, `u` k
        // rows of oc from a LANES boundary (group is a multiple of LANES).
        let inputs =
            &transformed[first * tile + point * k..(first + P - 1) * tile + (point + 1) * k];
        let u = &u[..k * oc];
        let mut acc = [[V::zero(); VECS]; P];
        if V::quad_broadcast_fits(P * VECS) && k.is_multiple_of(4) {
            // SSE: four inputs of a tile broadcast by one load and four shuffles (a broadcast
            // each takes a load and a shuffle), the weights read by the multiplies from
            // memory; the same products summed in the same order as below.
            for i in (0..k).step_by(4) {
                for (p, acc) in acc.iter_mut().enumerate() {
                    // SAFETY: p * tile + i + 4 <= (P - 1) * tile + k, the length of
                    // `inputs`; the weights as below.
                    let xs = unsafe { V::splat4(inputs.as_ptr().add(p * tile + i)) };
                    for (j, &x) in xs.iter().enumerate() {
                        for (v, acc) in acc.iter_mut().enumerate() {
                            let w = unsafe {
                                V::load_aligned_unchecked(
                                    u.as_ptr().add((i + j) * oc + group + v * V::LANES),
                                )
                            };
                            *acc = V::mul_add(x, w, *acc);
                        }
                    }
                }
            }
            store_block::<V, P, VECS>(&acc, [first, point, group, oc], products);
            return;
        }
        for i in 0..k {
            // SAFETY: i < k and group + VECS * LANES <= oc, so each vector lies inside row i
            // of `u`, from a LANES-float boundary (the weights start on one, oc and group are
            // multiples of LANES); p * tile + i < (P - 1) * tile + k, the length of `inputs`.
            let mut w = [V::zero(); VECS];
            for (v, w) in w.iter_mut().enumerate() {
                *w = unsafe {
                    V::load_aligned_unchecked(u.as_ptr().add(i * oc + group + v * V::LANES))
                };
            }
            for (p, acc) in acc.iter_mut().enumerate() {
                let x = V::splat(unsafe { *inputs.get_unchecked(p * tile + i) });
                for (acc, &w) in acc.iter_mut().zip(&w) {
                    *acc = V::mul_add(x, w, *acc);
                }
            }
        }
        store_block::<V, P, VECS>(&acc, [first, point, group, oc], products);
    }

    /// A block's accumulators into `products[tile][point][o]`.
    #[inline(always)]
    fn store_block<V: Vector, const P: usize, const VECS: usize>(
        acc: &[[V; VECS]; P],
        [first, point, group, oc]: [usize; 4],
        products: &mut [f32],
    ) {
        let products = &mut products[first * POINTS * oc..];
        for (p, acc) in acc.iter().enumerate() {
            for (v, acc) in acc.iter().enumerate() {
                acc.store(&mut products[(p * POINTS + point) * oc + group + v * V::LANES..]);
            }
        }
    }
}

#[cfg(test)]
// The references follow the formulas, indices and all.
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;

    /// Reproducible values of both signs.
    pub(super) fn values(n: usize, seed: u64) -> Vec<f32> {
        let mut state = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        (0..n)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                ((state >> 40) as f32 / (1u64 << 24) as f32 - 0.5) * 2.0
            })
            .collect()
    }

    /// The transformed weights, run through F(2x2, 3x3) by the book in `f64`, give the
    /// direct convolution's pooled map.
    #[test]
    fn transformed_weights_give_the_direct_convolution() {
        let (ic, oc) = (3, 2);
        let (width, rows) = (12, 12);
        let padded = values(rows * width * ic, 1);
        let direct = values(25 * ic * oc, 2);
        let u = transform_weights(&direct, ic, oc);
        let u = u.as_slice();
        const BT: [[f64; 4]; 4] = [
            [1.0, 0.0, -1.0, 0.0],
            [0.0, 1.0, 1.0, 0.0],
            [0.0, -1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0, -1.0],
        ];
        const AT: [[f64; 4]; 2] = [[1.0, 1.0, 1.0, 0.0], [0.0, 1.0, -1.0, -1.0]];
        let x = |y: usize, x: usize, c: usize| f64::from(padded[(y * width + x) * ic + c]);
        for (ty, tx) in [(0, 0), (1, 1), (0, 1)] {
            for o in 0..oc {
                let mut m = [[0.0f64; 4]; 4];
                for (phase, (a, b)) in [(0, 0), (0, 1), (1, 0), (1, 1)].into_iter().enumerate() {
                    for c in 0..ic {
                        for r in 0..4 {
                            for s in 0..4 {
                                let mut v = 0.0;
                                for i in 0..4 {
                                    for j in 0..4 {
                                        v += BT[r][i]
                                            * x(4 * ty + a + 2 * i, 4 * tx + b + 2 * j, c)
                                            * BT[s][j];
                                    }
                                }
                                let weight =
                                    f64::from(u[((r * 4 + s) * 4 * ic + phase * ic + c) * oc + o]);
                                m[r][s] += v * weight;
                            }
                        }
                    }
                }
                for dy in 0..2 {
                    for dx in 0..2 {
                        let mut y = 0.0;
                        for r in 0..4 {
                            for s in 0..4 {
                                y += AT[dy][r] * m[r][s] * AT[dx][s];
                            }
                        }
                        let (oy, ox) = (2 * ty + dy, 2 * tx + dx);
                        let mut expected = 0.0;
                        for ky in 0..5 {
                            for kx in 0..5 {
                                for c in 0..ic {
                                    expected += x(2 * oy + ky, 2 * ox + kx, c)
                                        * f64::from(direct[((ky * 5 + kx) * ic + c) * oc + o]);
                                }
                            }
                        }
                        assert!(
                            (y - expected).abs() < 1e-5,
                            "tile {ty},{tx} out {o}: {y} vs {expected}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn only_five_by_five_stride_two_pooled_two_by_two_applies() {
        let conv = [[5, 5], [2, 2]];
        let pool = [[2, 2], [2, 2]];
        let layer = Layer::new(conv, pool, [44, 34], [16, 32], [7, 10])
            .expect("the top camera's second layer");
        assert_eq!(layer.padded_rows_needed(), 34);
        assert_eq!(layer.multiply_adds(), 16 * 7 * 10 * 64 * 32);
        // The bottom camera's second layer: its last tiles read a row past the padding.
        let bottom = Layer::new(conv, pool, [24, 19], [8, 16], [4, 5]).expect("applies");
        assert_eq!(bottom.padded_rows_needed(), 20);
        assert!(Layer::new([[3, 3], [1, 1]], pool, [44, 34], [16, 32], [7, 10]).is_none());
        assert!(Layer::new(conv, [[3, 3], [2, 2]], [44, 34], [16, 32], [7, 10]).is_none());
        // Columns past the width cannot be added as rows can.
        assert!(Layer::new(conv, pool, [43, 34], [16, 32], [7, 10]).is_none());
    }
}

/// The vector kernels against the direct convolution, on each vector set this CPU runs, for
/// the networks' channel counts (compiled-in sizes) and others (the general loop).
#[cfg(all(test, any(target_arch = "x86", target_arch = "x86_64")))]
#[allow(unsafe_code)] // calling kernels compiled for a set this test checked the CPU has
mod vector_tests {
    use super::tests::values;
    use super::*;
    use crate::policy::engine::Isa;
    use crate::policy::engine::kernels::simd::{Avx, Avx512, Sse, Vector};

    /// A layer's inputs and outputs: the padded input, direct weights, bias.
    struct Case {
        layer: Layer,
        padded: Vec<f32>,
        direct: Vec<f32>,
        bias: Vec<f32>,
    }

    impl Case {
        fn new(ic: usize, oc: usize, tiles @ [th, tw]: [usize; 2], seed: u64) -> Self {
            let (width, rows) = (4 * (tw - 1) + 8, 4 * (th - 1) + 8);
            let layer = Layer::new(
                [[5, 5], [2, 2]],
                [[2, 2], [2, 2]],
                [width, rows],
                [ic, oc],
                tiles,
            )
            .expect("applies");
            Self {
                layer,
                padded: values(rows * width * ic, seed),
                direct: values(25 * ic * oc, seed + 1),
                bias: values(oc, seed + 2),
            }
        }

        /// The pooled map by the book: 5x5 stride-two sums in `f64`, maximum, bias, ReLU.
        fn expected(&self) -> Vec<f64> {
            let Layer {
                padded: [width, _],
                in_channels: ic,
                out_channels: oc,
                tiles: [th, tw],
            } = self.layer;
            let x = |y: usize, x: usize, c: usize| f64::from(self.padded[(y * width + x) * ic + c]);
            let mut out = Vec::new();
            for ty in 0..th {
                for tx in 0..tw {
                    for o in 0..oc {
                        let mut most = f64::NEG_INFINITY;
                        for (oy, ox) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                            let (oy, ox) = (2 * ty + oy, 2 * tx + ox);
                            let mut sum = 0.0;
                            for ky in 0..5 {
                                for kx in 0..5 {
                                    for c in 0..ic {
                                        sum += x(2 * oy + ky, 2 * ox + kx, c)
                                            * f64::from(
                                                self.direct[((ky * 5 + kx) * ic + c) * oc + o],
                                            );
                                    }
                                }
                            }
                            most = most.max(sum);
                        }
                        out.push((most + f64::from(self.bias[o])).max(0.0));
                    }
                }
            }
            out
        }

        /// The kernel's pooled map, or `None` where it declined the layer.
        fn run(&self, kernel: Kernel) -> Option<Vec<f32>> {
            let weights = transform_weights(
                &self.direct,
                self.layer.in_channels,
                self.layer.out_channels,
            );
            let [transformed, products] = self.layer.scratch();
            let (mut transformed, mut products) = (vec![0.0; transformed], vec![0.0; products]);
            let [th, tw] = self.layer.tiles;
            let mut out = vec![0.0; th * tw * self.layer.out_channels];
            // SAFETY: `kernels` offers only the sets this CPU runs.
            let done = unsafe {
                kernel(&mut Operands {
                    layer: &self.layer,
                    padded: &self.padded,
                    weights: weights.as_slice(),
                    bias: &self.bias,
                    relu: true,
                    transformed: &mut transformed,
                    products: &mut products,
                    out: &mut out,
                })
            };
            done.then_some(out)
        }
    }

    type Kernel = unsafe fn(&mut Operands<'_>) -> bool;

    /// The SSE kernel with `P` tiles by `VECS` vectors per block: five by two (the layers whose
    /// channels fill neither 16 nor 32), and the blockings the engine runs for 32 and 16
    /// output channels (`SseKernels::winograd_conv_pool`), one by eight and one by four on
    /// x86-64, one by two (broadcasting four inputs at a time there) on the V5's i686.
    fn sse<const P: usize, const VECS: usize>(conv: &mut Operands<'_>) -> bool {
        conv_pool::<Sse, P, VECS>(conv)
    }

    #[target_feature(enable = "avx,avx2,fma")]
    fn avx(conv: &mut Operands<'_>) -> bool {
        conv_pool::<Avx, 5, 2>(conv)
    }

    #[target_feature(enable = "avx,avx2,fma,avx512f")]
    fn avx512(conv: &mut Operands<'_>) -> bool {
        conv_pool::<Avx512, 5, 2>(conv)
    }

    /// Each vector set and blocking this CPU runs: its kernel, its lanes and the output
    /// channels one block covers (a layer's must be a multiple).
    fn kernels() -> Vec<(&'static str, Kernel, usize, usize)> {
        let lanes = Sse::LANES;
        let mut kernels: Vec<(&'static str, Kernel, usize, usize)> = vec![
            ("sse 5x2", sse::<5, 2>, lanes, 2 * lanes),
            ("sse 1x8", sse::<1, 8>, lanes, 8 * lanes),
            ("sse 1x4", sse::<1, 4>, lanes, 4 * lanes),
            ("sse 1x2", sse::<1, 2>, lanes, 2 * lanes),
        ];
        if Isa::Avx2Fma.is_available() {
            kernels.push(("avx2", avx, Avx::LANES, 2 * Avx::LANES));
        }
        if Isa::Avx512.is_available() {
            kernels.push(("avx512", avx512, Avx512::LANES, 2 * Avx512::LANES));
        }
        kernels
    }

    #[test]
    fn every_vector_set_computes_the_direct_convolution_and_pool() {
        for (name, kernel, lanes, group) in kernels() {
            // The networks' two layers (compiled-in sizes), then others: more input channels,
            // more output groups, a row of tiles that is not whole blocks.
            let shapes = [
                (16, 32, [7, 10]),
                (8, 16, [4, 5]),
                (lanes, 4 * lanes, [2, 6]),
                (3 * lanes, 2 * lanes, [3, 7]),
                (2 * lanes, 16 * lanes, [3, 5]),
            ];
            for (seed, (ic, oc, tiles)) in shapes.into_iter().enumerate() {
                if !ic.is_multiple_of(lanes) || !oc.is_multiple_of(group) {
                    continue;
                }
                let case = Case::new(ic, oc, tiles, 10 * seed as u64);
                let out = case
                    .run(kernel)
                    .unwrap_or_else(|| panic!("{name}: {ic} -> {oc} declined"));
                for (i, (&got, want)) in out.iter().zip(case.expected()).enumerate() {
                    assert!(
                        (f64::from(got) - want).abs() <= 1e-4 * want.abs().max(1.0),
                        "{name}, {ic} -> {oc}, value {i}: {got} against {want}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_layer_whose_channels_are_not_whole_vectors_is_declined() {
        for (name, kernel, lanes, group) in kernels() {
            let case = Case::new(lanes + 1, group, [2, 6], 1);
            assert!(case.run(kernel).is_none(), "{name}");
            let case = Case::new(lanes, group + 1, [2, 6], 1);
            assert!(case.run(kernel).is_none(), "{name}");
        }
    }
}
