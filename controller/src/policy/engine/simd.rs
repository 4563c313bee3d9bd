//! Vector kernels for x86: the convolution and the dense layer written over explicit vector
//! registers (`__m128` for the SSE sets, `__m256` with FMA for AVX2), so that the
//! accumulators of a block of output pixels stay in registers. Left to itself the compiler
//! splits fixed-size float arrays into scalars and vectorises only part of them back (the
//! generic kernels in [`super::kernels`] ran at about a third of tract's speed for that
//! reason); these are the engine's hot loops and are worth the `std::arch`.
//!
//! Every function here is `#[inline(always)]` and only ever inlined into the functions of
//! `super::x86` compiled with the matching `#[target_feature]`; that is what makes the
//! intrinsics sound to call.
#![allow(unsafe_code)]

#[cfg(target_arch = "x86")]
use std::arch::x86::*;
#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

use super::kernels::ConvShape;

/// A vector of `LANES` floats and the operations the kernels need.
pub(crate) trait Vector: Copy {
    const LANES: usize;
    fn zero() -> Self;
    fn splat(x: f32) -> Self;
    /// The first `LANES` values of `values` (which must hold that many).
    fn load(values: &[f32]) -> Self;
    /// The `LANES` values from `values`.
    ///
    /// # Safety
    /// `values` must point at `LANES` readable floats.
    unsafe fn load_unchecked(values: *const f32) -> Self;
    /// The `LANES` values from `values`, which sit on a boundary of `LANES` floats.
    ///
    /// # Safety
    /// `values` must point at `LANES` readable floats and be aligned to `LANES * 4` bytes.
    unsafe fn load_aligned_unchecked(values: *const f32) -> Self;
    fn store(self, values: &mut [f32]);
    /// `a * b + c`: fused where the set has FMA.
    fn mul_add(a: Self, b: Self, c: Self) -> Self;
    fn max(a: Self, b: Self) -> Self;
    fn sum(self) -> f32;
}

/// Four floats in an SSE register; product and sum rounded separately.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Sse(__m128);

// SAFETY (all `unsafe` blocks of this impl): SSE and SSE2 are the baseline of both x86
// targets this crate builds for (x86-64, and i686 whose Rust target enables SSE2), and these
// functions run inside `super::x86`'s functions compiled with at least SSE2; every load and
// store is checked to stay inside its slice first.
impl Vector for Sse {
    const LANES: usize = 4;

    #[inline(always)]
    fn zero() -> Self {
        Self(unsafe { _mm_setzero_ps() })
    }

    #[inline(always)]
    fn splat(x: f32) -> Self {
        Self(unsafe { _mm_set1_ps(x) })
    }

    #[inline(always)]
    fn load(values: &[f32]) -> Self {
        let values = &values[..4];
        Self(unsafe { _mm_loadu_ps(values.as_ptr()) })
    }

    #[inline(always)]
    unsafe fn load_unchecked(values: *const f32) -> Self {
        // SAFETY: the caller's promise, and the baseline SSE (above).
        Self(unsafe { _mm_loadu_ps(values) })
    }

    #[inline(always)]
    unsafe fn load_aligned_unchecked(values: *const f32) -> Self {
        // SAFETY: the caller's promise (alignment included), and the baseline SSE (above).
        Self(unsafe { _mm_load_ps(values) })
    }

    #[inline(always)]
    fn store(self, values: &mut [f32]) {
        let values = &mut values[..4];
        unsafe { _mm_storeu_ps(values.as_mut_ptr(), self.0) }
    }

    #[inline(always)]
    fn mul_add(a: Self, b: Self, c: Self) -> Self {
        Self(unsafe { _mm_add_ps(_mm_mul_ps(a.0, b.0), c.0) })
    }

    #[inline(always)]
    fn max(a: Self, b: Self) -> Self {
        Self(unsafe { _mm_max_ps(a.0, b.0) })
    }

    #[inline(always)]
    fn sum(self) -> f32 {
        let mut lanes = [0.0f32; 4];
        self.store(&mut lanes);
        (lanes[0] + lanes[2]) + (lanes[1] + lanes[3])
    }
}

/// Eight floats in an AVX register; multiply-add fused.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Avx(__m256);

// SAFETY (all `unsafe` blocks of this impl): only inlined into `super::x86::run_avx2_fma`,
// compiled with AVX, AVX2 and FMA, which `CompiledNetwork::lower` selects only on a CPU that
// has them; every load and store is checked to stay inside its slice first.
impl Vector for Avx {
    const LANES: usize = 8;

    #[inline(always)]
    fn zero() -> Self {
        Self(unsafe { _mm256_setzero_ps() })
    }

    #[inline(always)]
    fn splat(x: f32) -> Self {
        Self(unsafe { _mm256_set1_ps(x) })
    }

    #[inline(always)]
    fn load(values: &[f32]) -> Self {
        let values = &values[..8];
        Self(unsafe { _mm256_loadu_ps(values.as_ptr()) })
    }

    #[inline(always)]
    unsafe fn load_unchecked(values: *const f32) -> Self {
        // SAFETY: the caller's promise, and the AVX this is compiled with (above).
        Self(unsafe { _mm256_loadu_ps(values) })
    }

    #[inline(always)]
    unsafe fn load_aligned_unchecked(values: *const f32) -> Self {
        // SAFETY: the caller's promise (alignment included), and the AVX this is compiled
        // with (above).
        Self(unsafe { _mm256_load_ps(values) })
    }

    #[inline(always)]
    fn store(self, values: &mut [f32]) {
        let values = &mut values[..8];
        unsafe { _mm256_storeu_ps(values.as_mut_ptr(), self.0) }
    }

    #[inline(always)]
    fn mul_add(a: Self, b: Self, c: Self) -> Self {
        Self(unsafe { _mm256_fmadd_ps(a.0, b.0, c.0) })
    }

    #[inline(always)]
    fn max(a: Self, b: Self) -> Self {
        Self(unsafe { _mm256_max_ps(a.0, b.0) })
    }

    #[inline(always)]
    fn sum(self) -> f32 {
        let mut lanes = [0.0f32; 8];
        self.store(&mut lanes);
        ((lanes[0] + lanes[4]) + (lanes[1] + lanes[5]))
            + ((lanes[2] + lanes[6]) + (lanes[3] + lanes[7]))
    }
}

/// Rows `first_row..` of [`super::kernels::conv`] (as many as `out` holds) over vectors:
/// the output channels in groups of `VECS` vectors of `V`, `P` pixels per block, so that
/// `P x VECS` accumulators, `VECS` weight vectors and the broadcast input fit the register
/// file. `IC` and `KW` are the number of input channels and the kernel's width when known
/// at compile time (the inner loops are then unrolled), 0 when not. A row whose width is not a whole number of blocks ends with
/// a block that overlaps the one before (those pixels are computed twice, identically)
/// rather than with single pixels. Returns false (nothing written) when the output channels
/// are not a whole number of groups or `IC` does not match.
#[inline(always)]
pub(crate) fn conv_rows<
    V: Vector,
    const VECS: usize,
    const P: usize,
    const IC: usize,
    const KW: usize,
>(
    shape: &ConvShape,
    padded: &[f32],
    weights: &[f32],
    bias: &[f32],
    relu: bool,
    first_row: usize,
    out: &mut [f32],
) -> bool {
    let oc = shape.out_channels;
    let group = VECS * V::LANES;
    if oc == 0
        || !oc.is_multiple_of(group)
        || (IC != 0 && IC != shape.in_channels)
        || (KW != 0 && KW != shape.kernel[1])
        || weights.len() < shape.kernel[0] * shape.kernel[1] * shape.in_channels * oc
        || !weights
            .as_ptr()
            .addr()
            .is_multiple_of(V::LANES * size_of::<f32>())
    {
        return false;
    }
    let [_, ow] = shape.out;
    for (i, out_row) in out.chunks_exact_mut(ow * oc).enumerate() {
        let oy = first_row + i;
        for g in 0..oc / group {
            let channels = g * group;
            let bias: [V; VECS] =
                core::array::from_fn(|v| V::load(&bias[channels + v * V::LANES..]));
            let blocks = ow / P;
            let block_at = |ox: usize, target: &mut [f32]| {
                conv_block::<V, VECS, P, IC, KW>(
                    shape,
                    padded,
                    weights,
                    &bias,
                    relu,
                    [oy, ox],
                    channels,
                    target,
                );
            };
            for block in 0..blocks {
                block_at(
                    block * P,
                    &mut out_row[block * P * oc..(block + 1) * P * oc],
                );
            }
            if blocks == 0 {
                // A row narrower than one block: single pixels.
                for ox in 0..ow {
                    conv_block::<V, VECS, 1, IC, KW>(
                        shape,
                        padded,
                        weights,
                        &bias,
                        relu,
                        [oy, ox],
                        channels,
                        &mut out_row[ox * oc..(ox + 1) * oc],
                    );
                }
            } else if !ow.is_multiple_of(P) {
                block_at(ow - P, &mut out_row[(ow - P) * oc..]);
            }
        }
    }
    true
}

/// `P` output pixels from `(oy, ox)` on, output channels `channels..channels + VECS * LANES`.
#[inline(always)]
#[allow(clippy::too_many_arguments)] // one block of one convolution
fn conv_block<V: Vector, const VECS: usize, const P: usize, const IC: usize, const KW: usize>(
    shape: &ConvShape,
    padded: &[f32],
    weights: &[f32],
    bias: &[V; VECS],
    relu: bool,
    [oy, ox]: [usize; 2],
    channels: usize,
    target: &mut [f32],
) {
    let ic = if IC == 0 { shape.in_channels } else { IC };
    let oc = shape.out_channels;
    let kh = shape.kernel[0];
    let kw = if KW == 0 { shape.kernel[1] } else { KW };
    let [sy, sx] = shape.stride;
    let row = shape.padded_width * ic;
    let step = sx * ic;
    let mut acc = [*bias; P];
    for ky in 0..kh {
        let input_row = &padded[(oy * sy + ky) * row..(oy * sy + ky + 1) * row];
        let taps_row = &weights[ky * kw * ic * oc..(ky + 1) * kw * ic * oc];
        let first = ox * sx * ic;
        let span = &input_row[first..first + (P - 1) * step + kw * ic];
        // The slices are checked once here; the loop below reads inside them without a
        // check per value, which on the V5 would cost more than the arithmetic.
        let (taps, span) = (taps_row.as_ptr(), span.as_ptr());
        for kx in 0..kw {
            for c in 0..ic {
                // SAFETY: kx < kw, c < ic and channels + (v + 1) * LANES <= oc (`conv_rows`
                // checks that the groups tile the channels), so the weight offset plus LANES
                // stays inside `taps_row` (kw * ic * oc values); the offset is a multiple of
                // LANES (oc and channels are) and `conv_rows` checked that `weights` starts on
                // a LANES-float boundary, as `taps_row` does (ky * kw * ic * oc in); p < P, so
                // p * step + kx * ic + c < (P - 1) * step + kw * ic, the length of `span`.
                let w: [V; VECS] = core::array::from_fn(|v| unsafe {
                    V::load_aligned_unchecked(
                        taps.add((kx * ic + c) * oc + channels + v * V::LANES),
                    )
                });
                for (p, acc) in acc.iter_mut().enumerate() {
                    let x = V::splat(unsafe { *span.add(p * step + kx * ic + c) });
                    for (acc, &w) in acc.iter_mut().zip(&w) {
                        *acc = V::mul_add(x, w, *acc);
                    }
                }
            }
        }
    }
    let zero = V::zero();
    for (p, acc) in acc.iter().enumerate() {
        for (v, &a) in acc.iter().enumerate() {
            let value = if relu { V::max(a, zero) } else { a };
            value.store(&mut target[p * oc + channels + v * V::LANES..]);
        }
    }
}

/// [`super::kernels::max_pool_nhwc`] over vectors; channels that are not a whole number
/// of vectors go to that scalar version.
#[inline(always)]
pub(crate) fn max_pool<V: Vector>(
    input: &[f32],
    size @ [_, w, c]: [usize; 3],
    kernel: [usize; 2],
    stride: [usize; 2],
    [oh, ow]: [usize; 2],
    out: &mut [f32],
) {
    if c == 0 || !c.is_multiple_of(V::LANES) {
        super::kernels::max_pool_nhwc(input, size, kernel, stride, [oh, ow], out);
        return;
    }
    if kernel == [2, 2] && stride == [2, 2] {
        // The networks' pool: two input rows per output row, two pixels per output pixel,
        // walked as slices so that nothing is recomputed or checked per vector. (A NaN in
        // the map may come through here; the controller refuses a non-finite command.)
        let input_rows = input.chunks_exact(2 * w * c);
        for (out_row, rows) in out.chunks_exact_mut(ow * c).zip(input_rows).take(oh) {
            let (upper, lower) = rows.split_at(w * c);
            let pairs = upper.chunks_exact(2 * c).zip(lower.chunks_exact(2 * c));
            for (target, (upper, lower)) in out_row.chunks_exact_mut(c).zip(pairs) {
                for channel in (0..c).step_by(V::LANES) {
                    let left = V::max(V::load(&upper[channel..]), V::load(&lower[channel..]));
                    let right = V::max(
                        V::load(&upper[c + channel..]),
                        V::load(&lower[c + channel..]),
                    );
                    V::max(left, right).store(&mut target[channel..]);
                }
            }
        }
        return;
    }
    for oy in 0..oh {
        for ox in 0..ow {
            let target = &mut out[(oy * ow + ox) * c..(oy * ow + ox + 1) * c];
            for channel in (0..c).step_by(V::LANES) {
                let mut max = V::splat(f32::NEG_INFINITY);
                for ky in 0..kernel[0] {
                    for kx in 0..kernel[1] {
                        let (y, x) = (oy * stride[0] + ky, ox * stride[1] + kx);
                        let value = V::load(&input[(y * w + x) * c + channel..]);
                        // The running maximum second: a NaN in the map is skipped, as
                        // `f32::max` would.
                        max = V::max(value, max);
                    }
                }
                max.store(&mut target[channel..]);
            }
        }
    }
}

/// [`super::kernels::dense`] over vectors: four rows at a time.
#[inline(always)]
pub(crate) fn dense<V: Vector>(x: &[f32], weights: &[f32], bias: &[f32], y: &mut [f32]) {
    let k = x.len();
    let whole = k - k % V::LANES;
    let n = y.len();
    let mut start = 0;
    while start + 4 <= n {
        let rows: [&[f32]; 4] =
            core::array::from_fn(|r| &weights[(start + r) * k..(start + r + 1) * k]);
        let mut acc = [V::zero(); 4];
        let mut i = 0;
        let pointers: [*const f32; 4] = core::array::from_fn(|r| rows[r].as_ptr());
        while i < whole {
            // SAFETY: i + LANES <= whole <= k, the length of `x` and of every row.
            let xv = unsafe { V::load_unchecked(x.as_ptr().add(i)) };
            let w: [V; 4] =
                core::array::from_fn(|r| unsafe { V::load_unchecked(pointers[r].add(i)) });
            for r in 0..4 {
                acc[r] = V::mul_add(xv, w[r], acc[r]);
            }
            i += V::LANES;
        }
        for r in 0..4 {
            let mut sum = acc[r].sum();
            for j in whole..k {
                sum += x[j] * rows[r][j];
            }
            y[start + r] = sum + bias[start + r];
        }
        start += 4;
    }
    for row in start..n {
        let w = &weights[row * k..(row + 1) * k];
        let mut acc = V::zero();
        let mut i = 0;
        while i < whole {
            acc = V::mul_add(V::load(&x[i..]), V::load(&w[i..]), acc);
            i += V::LANES;
        }
        let mut sum = acc.sum();
        for j in whole..k {
            sum += x[j] * w[j];
        }
        y[row] = sum + bias[row];
    }
}
