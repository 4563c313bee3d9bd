//! Vector kernels for x86: the convolution and the dense layer written over explicit vector
//! registers (`__m128` for the SSE sets, `__m256` with FMA for AVX2, `__m512` for AVX-512),
//! so that the
//! accumulators of a block of output pixels stay in registers. Left to itself the compiler
//! splits fixed-size float arrays into scalars and vectorises only part of them back (the
//! generic kernels in [`super::portable`] ran at about a third of tract's speed for that
//! reason); these are the engine's hot loops and are worth the `std::arch`.
//!
//! Every function here is `#[inline(always)]` and only ever inlined into the functions of
//! `crate::policy::engine::x86` compiled with the matching `#[target_feature]`; that is what makes the
//! intrinsics sound to call.
#![allow(unsafe_code)]

#[cfg(target_arch = "x86")]
use std::arch::x86::*;
#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

use super::PoolShape;
use super::portable::nonzero_indices;
use crate::policy::engine::layout::{ConvLayer, ConvShape, DenseWeights};

/// A vector of `LANES` floats and the operations the kernels need.
pub(crate) trait Vector: Copy {
    const LANES: usize;
    /// Whether [`Self::splat4`] beats four [`Self::splat`]s: true for SSE, whose broadcast
    /// of a scalar from memory takes two instructions (a load and a shuffle) where one load
    /// and one shuffle per value serve four; AVX broadcasts from memory in one.
    const QUAD_BROADCAST: bool;
    /// Whether a block of products that keeps `accumulators` vectors in registers broadcasts
    /// its inputs with [`Self::splat4`]: where the set prefers it ([`Self::QUAD_BROADCAST`]),
    /// or where the four broadcasts fit in its registers beside those accumulators.
    #[inline(always)]
    fn quad_broadcast_fits(_accumulators: usize) -> bool {
        Self::QUAD_BROADCAST
    }
    fn zero() -> Self;
    fn splat(x: f32) -> Self;
    /// Four vectors, each the broadcast of one of `values[0..4]`.
    ///
    /// # Safety
    /// `values` must point at four readable floats.
    unsafe fn splat4(values: *const f32) -> [Self; 4];
    /// A kernel window of a single pixel into four vectors of output channels: `rows` rows
    /// of `pixels * channels` consecutive inputs (`taps` a row), `x_row` floats apart, the
    /// weights of tap `t` of row `r` at `w[(r * taps + t) * w_stride ..]`;
    /// `acc[v] += x * w[.. + v * LANES]` tap by tap in that order. Returns false, having done
    /// nothing, where the set has no such kernel.
    ///
    /// # Safety
    /// `x` must point at `rows` rows of `taps` readable floats, `x_row` floats apart, and `w`
    /// at `rows * taps` rows `w_stride` floats apart, each with `4 * LANES` readable floats
    /// from a `LANES`-float boundary; `w_stride` a multiple of `LANES`.
    #[inline(always)]
    unsafe fn window_of_taps4(
        _acc: &mut [Self; 4],
        _x: *const f32,
        _x_row: usize,
        _w: *const f32,
        [_rows, _pixels, _channels]: [usize; 3],
        _w_stride: usize,
    ) -> bool {
        false
    }
    /// The first `LANES` values of `values` (which must hold that many).
    fn load(values: &[f32]) -> Self;
    /// The `LANES` values from `values`, which sit on a boundary of `LANES` floats.
    ///
    /// # Safety
    /// `values` must point at `LANES` readable floats and be aligned to `LANES * 4` bytes.
    unsafe fn load_aligned_unchecked(values: *const f32) -> Self;
    fn store(self, values: &mut [f32]);
    /// The `LANES` values from `values`, on any boundary.
    ///
    /// # Safety
    /// `values` must point at `LANES` readable floats.
    unsafe fn load_unchecked(values: *const f32) -> Self;
    /// Stores the `LANES` values at `values`, on any boundary.
    ///
    /// # Safety
    /// `values` must point at `LANES` writable floats.
    unsafe fn store_unchecked(self, values: *mut f32);
    /// `a * b + c`: fused where the set has FMA.
    fn mul_add(a: Self, b: Self, c: Self) -> Self;
    fn add(a: Self, b: Self) -> Self;
    fn sub(a: Self, b: Self) -> Self;
    fn max(a: Self, b: Self) -> Self;
}

/// The methods every vector type writes in the same words, each with its own intrinsics:
/// `LANES`, `zero`, `splat`, the bounds-checked `load` and `store`, the unchecked loads and
/// store, `add`, `sub` and `max`. Invoked inside each `impl Vector`, whose own SAFETY note
/// (the instruction set its functions are compiled with) covers the `unsafe` blocks here.
macro_rules! vector_ops {
    (
        lanes: $lanes:literal,
        zero: $zero:ident,
        splat: $splat:ident,
        load: $load:ident,
        load_aligned: $load_aligned:ident,
        store: $store:ident,
        add: $add:ident,
        sub: $sub:ident,
        max: $max:ident,
    ) => {
        const LANES: usize = $lanes;

        #[inline(always)]
        fn zero() -> Self {
            Self(unsafe { $zero() })
        }

        #[inline(always)]
        fn splat(x: f32) -> Self {
            Self(unsafe { $splat(x) })
        }

        #[inline(always)]
        fn load(values: &[f32]) -> Self {
            let values = &values[..$lanes];
            Self(unsafe { $load(values.as_ptr()) })
        }

        #[inline(always)]
        unsafe fn load_aligned_unchecked(values: *const f32) -> Self {
            // SAFETY: the caller's promise (alignment included), and the instruction set
            // the impl is compiled with.
            Self(unsafe { $load_aligned(values) })
        }

        #[inline(always)]
        fn store(self, values: &mut [f32]) {
            let values = &mut values[..$lanes];
            unsafe { $store(values.as_mut_ptr(), self.0) }
        }

        #[inline(always)]
        unsafe fn load_unchecked(values: *const f32) -> Self {
            // SAFETY: the caller's promise.
            Self(unsafe { $load(values) })
        }

        #[inline(always)]
        unsafe fn store_unchecked(self, values: *mut f32) {
            // SAFETY: the caller's promise.
            unsafe { $store(values, self.0) }
        }

        #[inline(always)]
        fn add(a: Self, b: Self) -> Self {
            Self(unsafe { $add(a.0, b.0) })
        }

        #[inline(always)]
        fn sub(a: Self, b: Self) -> Self {
            Self(unsafe { $sub(a.0, b.0) })
        }

        #[inline(always)]
        fn max(a: Self, b: Self) -> Self {
            Self(unsafe { $max(a.0, b.0) })
        }
    };
}

/// Four floats in an SSE register; product and sum rounded separately.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Sse(__m128);

// SAFETY (all `unsafe` blocks of this impl): SSE and SSE2 are the baseline of both x86
// targets this crate builds for (x86-64, and i686 whose Rust target enables SSE2), and these
// functions run inside `crate::policy::engine::x86`'s functions compiled with at least SSE2; every load and
// store is checked to stay inside its slice first.
impl Vector for Sse {
    vector_ops! {
        lanes: 4,
        zero: _mm_setzero_ps,
        splat: _mm_set1_ps,
        load: _mm_loadu_ps,
        load_aligned: _mm_load_ps,
        store: _mm_storeu_ps,
        add: _mm_add_ps,
        sub: _mm_sub_ps,
        max: _mm_max_ps,
    }

    // Not on the 32-bit V5 build: its eight registers cannot hold the four broadcasts beside
    // the accumulators, and the spills cost more than the shuffles save (callgrind:
    // 7.97 M instructions per CNN forward against 7.85 M).
    const QUAD_BROADCAST: bool = cfg!(target_arch = "x86_64");

    /// On the V5's eight registers too for at most two accumulators: with the four broadcasts
    /// and a product, seven of them (the Winograd products' one-tile-by-two-vectors blocks).
    #[inline(always)]
    fn quad_broadcast_fits(accumulators: usize) -> bool {
        Self::QUAD_BROADCAST || accumulators <= 2
    }

    /// On the 32-bit V5 build, in assembly: the whole window in one loop nest, four taps at
    /// a time where a row has them (their inputs loaded once and broadcast by `pshufd`),
    /// four accumulators, a product and the broadcasts in seven of the eight registers.
    /// Written out because the compiler, given the same loops in intrinsics, interleaves the
    /// taps and spills accumulators to the stack (callgrind: about a fifth of the
    /// convolution's instructions were spills and reloads), and spends as many again on
    /// each short row's loop. The arithmetic and its order are those of the intrinsics:
    /// `mulps`, then `addps`, tap by tap.
    ///
    /// The networks' own layouts (the first layer's 5x5 window of one channel, the second
    /// layers' windows of 8- and 16-channel pixels) go to [`super::window_asm`], which
    /// writes the weight offsets into the instructions; this loop takes the rest.
    #[cfg(target_arch = "x86")]
    #[inline(always)]
    unsafe fn window_of_taps4(
        acc: &mut [Self; 4],
        x: *const f32,
        x_row: usize,
        w: *const f32,
        [rows, pixels, channels]: [usize; 3],
        w_stride: usize,
    ) -> bool {
        if rows == 0 {
            return true;
        }
        let mut vectors = acc.map(|a| a.0);
        // SAFETY: the caller's promise, which is `window`'s for every layout it takes.
        if unsafe {
            super::window_asm::window(
                &mut vectors,
                x,
                x_row,
                w,
                [rows, pixels, channels],
                w_stride,
            )
        } {
            *acc = vectors.map(Self);
            return true;
        }
        let taps = pixels * channels;
        let [mut a0, mut a1, mut a2, mut a3] = vectors;
        // Quads and single taps a row, bytes from a row's end to the next row's start, rows
        // left (counted down by the loop), bytes from one tap's weights to the next.
        let mut counts: [usize; 5] = [
            taps / 4,
            taps % 4,
            (x_row - taps) * size_of::<f32>(),
            rows,
            w_stride * size_of::<f32>(),
        ];
        // One tap: the broadcast input in {b} times the tap's four weight vectors at {w},
        // into the accumulators; then {w} moves to the next tap's weights.
        macro_rules! tap {
            () => {
                concat!(
                    "movaps {t}, xmmword ptr [{w}]\n",
                    "mulps {t}, {b}\n",
                    "addps {a0}, {t}\n",
                    "movaps {t}, xmmword ptr [{w} + 16]\n",
                    "mulps {t}, {b}\n",
                    "addps {a1}, {t}\n",
                    "movaps {t}, xmmword ptr [{w} + 32]\n",
                    "mulps {t}, {b}\n",
                    "addps {a2}, {t}\n",
                    "mulps {b}, xmmword ptr [{w} + 48]\n",
                    "addps {a3}, {b}\n",
                    "add {w}, dword ptr [{p} + 16]\n",
                )
            };
        }
        // Lane `$lane` of the four inputs in {v}, broadcast, as one tap.
        macro_rules! quad_tap {
            ($lane:literal) => {
                concat!("pshufd {b}, {v}, ", $lane, "\n", tap!())
            };
        }
        // SAFETY: the caller's promise: the loops read, row by row, the row's inputs and,
        // tap by tap, four aligned vectors of the tap's weights, in order; they write only
        // `counts`' rows-left field.
        unsafe {
            core::arch::asm!(
                "3:",
                "mov {n}, dword ptr [{p}]",
                "test {n}, {n}",
                "jz 5f",
                "2:",
                "movups {v}, xmmword ptr [{x}]",
                quad_tap!("0x00"),
                quad_tap!("0x55"),
                quad_tap!("0xaa"),
                quad_tap!("0xff"),
                "add {x}, 16",
                "dec {n}",
                "jnz 2b",
                "5:",
                "mov {n}, dword ptr [{p} + 4]",
                "test {n}, {n}",
                "jz 6f",
                "4:",
                "movss {b}, dword ptr [{x}]",
                "shufps {b}, {b}, 0",
                tap!(),
                "add {x}, 4",
                "dec {n}",
                "jnz 4b",
                "6:",
                "add {x}, dword ptr [{p} + 8]",
                "dec dword ptr [{p} + 12]",
                "jnz 3b",
                x = inout(reg) x => _,
                w = inout(reg) w => _,
                n = out(reg) _,
                p = in(reg) counts.as_mut_ptr(),
                a0 = inout(xmm_reg) a0,
                a1 = inout(xmm_reg) a1,
                a2 = inout(xmm_reg) a2,
                a3 = inout(xmm_reg) a3,
                v = out(xmm_reg) _,
                b = out(xmm_reg) _,
                t = out(xmm_reg) _,
                options(nostack),
            );
        }
        *acc = [Self(a0), Self(a1), Self(a2), Self(a3)];
        true
    }

    #[inline(always)]
    unsafe fn splat4(values: *const f32) -> [Self; 4] {
        // SAFETY: the caller's promise, and the baseline SSE (above).
        unsafe {
            let v = _mm_loadu_ps(values);
            [
                Self(_mm_shuffle_ps::<0x00>(v, v)),
                Self(_mm_shuffle_ps::<0x55>(v, v)),
                Self(_mm_shuffle_ps::<0xAA>(v, v)),
                Self(_mm_shuffle_ps::<0xFF>(v, v)),
            ]
        }
    }

    #[inline(always)]
    fn mul_add(a: Self, b: Self, c: Self) -> Self {
        Self(unsafe { _mm_add_ps(_mm_mul_ps(a.0, b.0), c.0) })
    }
}

/// Eight floats in an AVX register; multiply-add fused.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Avx(__m256);

// SAFETY (all `unsafe` blocks of this impl): only inlined into `super::x86::run_avx2_fma`,
// compiled with AVX, AVX2 and FMA, which `CompiledNetwork::lower` selects only on a CPU that
// has them; every load and store is checked to stay inside its slice first.
impl Vector for Avx {
    vector_ops! {
        lanes: 8,
        zero: _mm256_setzero_ps,
        splat: _mm256_set1_ps,
        load: _mm256_loadu_ps,
        load_aligned: _mm256_load_ps,
        store: _mm256_storeu_ps,
        add: _mm256_add_ps,
        sub: _mm256_sub_ps,
        max: _mm256_max_ps,
    }

    const QUAD_BROADCAST: bool = false;

    #[inline(always)]
    unsafe fn splat4(values: *const f32) -> [Self; 4] {
        // SAFETY: the caller's promise, and the AVX this is compiled with (above).
        core::array::from_fn(|i| Self(unsafe { _mm256_broadcast_ss(&*values.add(i)) }))
    }

    #[inline(always)]
    fn mul_add(a: Self, b: Self, c: Self) -> Self {
        Self(unsafe { _mm256_fmadd_ps(a.0, b.0, c.0) })
    }
}

/// Sixteen floats in an AVX-512 register; multiply-add fused.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Avx512(__m512);

// SAFETY (all `unsafe` blocks of this impl): only inlined into `super::x86::run_avx512`,
// compiled with AVX-512F (and AVX2 and FMA), which `CompiledNetwork::lower` selects only on a
// CPU that has them; every load and store is checked to stay inside its slice first.
impl Vector for Avx512 {
    vector_ops! {
        lanes: 16,
        zero: _mm512_setzero_ps,
        splat: _mm512_set1_ps,
        load: _mm512_loadu_ps,
        load_aligned: _mm512_load_ps,
        store: _mm512_storeu_ps,
        add: _mm512_add_ps,
        sub: _mm512_sub_ps,
        max: _mm512_max_ps,
    }

    const QUAD_BROADCAST: bool = false;

    #[inline(always)]
    unsafe fn splat4(values: *const f32) -> [Self; 4] {
        // SAFETY: the caller's promise.
        core::array::from_fn(|i| Self::splat(unsafe { *values.add(i) }))
    }

    #[inline(always)]
    fn mul_add(a: Self, b: Self, c: Self) -> Self {
        Self(unsafe { _mm512_fmadd_ps(a.0, b.0, c.0) })
    }
}

/// Rows `first_row..` of [`super::portable::conv`] (as many as `out` holds) over vectors:
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
    layer: &ConvLayer<'_>,
    padded: &[f32],
    first_row: usize,
    out: &mut [f32],
) -> bool {
    let ConvLayer {
        shape,
        weights,
        bias,
        relu,
    } = *layer;
    let oc = shape.out_channels;
    let group = VECS * V::LANES;
    // Every size below is checked arithmetic: a crafted shape makes a product wrap, and a
    // wrapped bound would pass (the lowering caps sizes too; this check stands alone).
    let fits = |end: Option<usize>, len: usize| end.is_some_and(|end| end <= len);
    let weights_needed = shape.kernel[0]
        .checked_mul(shape.kernel[1])
        .and_then(|n| n.checked_mul(shape.in_channels))
        .and_then(|n| n.checked_mul(oc));
    if oc == 0
        || !oc.is_multiple_of(group)
        || (IC != 0 && IC != shape.in_channels)
        || (KW != 0 && KW != shape.kernel[1])
        || !fits(weights_needed, weights.len())
        || bias.len() < oc
        || !weights
            .as_ptr()
            .addr()
            .is_multiple_of(V::LANES * size_of::<f32>())
    {
        return false;
    }
    let [_, ow] = shape.out;
    // Every block's inputs inside `padded`, checked once here rather than per kernel row.
    let ([kh, kw], [sy, sx]) = (shape.kernel, shape.stride);
    let (Some(row), Some(out_row)) = (
        shape.padded_width.checked_mul(shape.in_channels),
        ow.checked_mul(oc),
    ) else {
        return false;
    };
    let rows = out.len() / out_row.max(1);
    let window_width = (ow.saturating_sub(1))
        .checked_mul(sx)
        .and_then(|n| n.checked_add(kw))
        .and_then(|n| n.checked_mul(shape.in_channels));
    let window_rows = first_row
        .checked_add(rows.saturating_sub(1))
        .and_then(|n| n.checked_mul(sy))
        .and_then(|n| n.checked_add(kh))
        .and_then(|n| n.checked_mul(row));
    if ow > 0 && rows > 0 && !(fits(window_width, row) && fits(window_rows, padded.len())) {
        return false;
    }
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
    let first = ox * sx * ic;
    let whole_window = if P == 1
        && let Ok(window) = <&mut [V; 4]>::try_from(acc[0].as_mut_slice())
        // SAFETY: `conv_rows` checked that this pixel's window lies inside `padded`: kh rows
        // of kw * ic consecutive inputs, `row` floats apart, from the first's offset (as
        // below); the weights are [ky][kx][c][oc], so tap t of row ky (t = kx * ic + c) has
        // its channels from weights + (ky * kw * ic + t) * oc + channels, on a LANES
        // boundary, with VECS * LANES = 4 * LANES of them inside `weights`.
        && unsafe {
            V::window_of_taps4(
                window,
                padded.as_ptr().add(oy * sy * row + first),
                row,
                weights.as_ptr().add(channels),
                [kh, kw, ic],
                oc,
            )
        } {
        true
    } else {
        false
    };
    for ky in (0..kh).filter(|_| !whole_window) {
        // SAFETY: `conv_rows` checked that the inputs of every block it asks for lie inside
        // `padded`: row oy * sy + ky < (last row * sy + kh) and columns from `first` to
        // first + (P - 1) * step + kw * ic <= ((ow - 1) * sx + kw) * ic <= row; and that
        // `weights` holds kh * kw * ic * oc values, so row ky's taps start inside it.
        let span = unsafe { padded.as_ptr().add((oy * sy + ky) * row + first) };
        let taps = unsafe { weights.as_ptr().add(ky * kw * ic * oc) };
        for kx in 0..kw {
            if V::QUAD_BROADCAST && ic.is_multiple_of(4) {
                // Four channels of each pixel in one load, broadcast lane by lane.
                for c4 in (0..ic).step_by(4) {
                    // SAFETY: as below, for the channels c4..c4 + 4 <= ic.
                    let xs: [[V; 4]; P] = core::array::from_fn(|p| unsafe {
                        V::splat4(span.add(p * step + kx * ic + c4))
                    });
                    for j in 0..4 {
                        // SAFETY: as below, for channel c4 + j < ic.
                        let w: [V; VECS] = core::array::from_fn(|v| unsafe {
                            V::load_aligned_unchecked(
                                taps.add((kx * ic + c4 + j) * oc + channels + v * V::LANES),
                            )
                        });
                        for (acc, xs) in acc.iter_mut().zip(&xs) {
                            for (acc, &w) in acc.iter_mut().zip(&w) {
                                *acc = V::mul_add(xs[j], w, *acc);
                            }
                        }
                    }
                }
                continue;
            }
            // Channels two at a time where they pair up (the loop's own instructions are a
            // quarter of a 32-bit SSE tap's otherwise), one at a time elsewhere.
            let pairs = if ic.is_multiple_of(2) { ic / 2 } else { 0 };
            for pair in 0..pairs {
                for c in [2 * pair, 2 * pair + 1] {
                    // SAFETY: c < ic; as below.
                    unsafe { conv_tap(&mut acc, taps, span, [kx, c], [ic, oc], step, channels) };
                }
            }
            for c in 2 * pairs..ic {
                // SAFETY: kx < kw, c < ic and channels + (v + 1) * LANES <= oc (`conv_rows`
                // checks that the groups tile the channels), so the weight offset plus LANES
                // stays inside `taps_row` (kw * ic * oc values); the offset is a multiple of
                // LANES (oc and channels are) and `conv_rows` checked that `weights` starts on
                // a LANES-float boundary, as `taps_row` does (ky * kw * ic * oc in); p < P, so
                // p * step + kx * ic + c < (P - 1) * step + kw * ic, the length of `span`.
                unsafe { conv_tap(&mut acc, taps, span, [kx, c], [ic, oc], step, channels) };
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

/// One tap `(kx, c)` of a block: its `VECS` weight vectors times each pixel's input value.
///
/// # Safety
/// `taps` must hold the row's weights `[kx][c][oc]` from a `LANES`-float boundary, with
/// `channels + VECS * LANES <= oc`, and `span` the block's inputs, `(P - 1) * step + kw * ic`
/// floats, for `kx < kw` and `c < ic`.
#[inline(always)]
#[allow(clippy::too_many_arguments)] // one tap of one block
unsafe fn conv_tap<V: Vector, const VECS: usize, const P: usize>(
    acc: &mut [[V; VECS]; P],
    taps: *const f32,
    span: *const f32,
    [kx, c]: [usize; 2],
    [ic, oc]: [usize; 2],
    step: usize,
    channels: usize,
) {
    // SAFETY: the caller's promise.
    let w: [V; VECS] = core::array::from_fn(|v| unsafe {
        V::load_aligned_unchecked(taps.add((kx * ic + c) * oc + channels + v * V::LANES))
    });
    for (p, acc) in acc.iter_mut().enumerate() {
        let x = V::splat(unsafe { *span.add(p * step + kx * ic + c) });
        for (acc, &w) in acc.iter_mut().zip(&w) {
            *acc = V::mul_add(x, w, *acc);
        }
    }
}

/// [`super::portable::max_pool_nhwc`] over vectors; channels that are not a whole number
/// of vectors go to that scalar version.
#[inline(always)]
pub(crate) fn max_pool<V: Vector>(input: &[f32], shape: PoolShape, out: &mut [f32]) {
    let ([_, w, c], [oh, ow]) = (shape.size, shape.out);
    let (kernel, stride) = (shape.kernel, shape.stride);
    if c == 0 || !c.is_multiple_of(V::LANES) {
        super::portable::max_pool_nhwc(input, shape, out);
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
                // Whole vectors from slices of exactly one vector: no check per load.
                let (upper_left, upper_right) = upper.split_at(c);
                let (lower_left, lower_right) = lower.split_at(c);
                let vectors = target
                    .chunks_exact_mut(V::LANES)
                    .zip(upper_left.chunks_exact(V::LANES))
                    .zip(lower_left.chunks_exact(V::LANES))
                    .zip(
                        upper_right
                            .chunks_exact(V::LANES)
                            .zip(lower_right.chunks_exact(V::LANES)),
                    );
                for (((target, ul), ll), (ur, lr)) in vectors {
                    let left = V::max(V::load(ul), V::load(ll));
                    let right = V::max(V::load(ur), V::load(lr));
                    V::max(left, right).store(target);
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

/// [`super::kernels::dense`] over vectors: a panel's `VECS * LANES` outputs stay in
/// registers while the non-zero inputs stream past, each broadcast once and multiplied by
/// its row of the panel (aligned loads: panels start on a 64-byte boundary and their rows are
/// a multiple of eight floats). Returns false (nothing written) when the panels are not
/// `VECS` vectors wide or not aligned.
#[inline(always)]
pub(crate) fn dense<V: Vector, const VECS: usize>(
    x: &[f32],
    weights: &DenseWeights,
    bias: &[f32],
    y: &mut [f32],
    nonzero: &mut [u32],
) -> bool {
    let width = VECS * V::LANES;
    let (k, outputs) = (weights.inputs(), weights.outputs());
    let panels = weights.panels();
    if weights.width() != width
        || x.len() < k
        || y.len() < outputs
        || bias.len() < outputs
        || outputs
            .div_ceil(width)
            .checked_mul(k)
            .and_then(|n| n.checked_mul(width))
            .is_none_or(|needed| panels.len() < needed)
        || !panels
            .as_ptr()
            .addr()
            .is_multiple_of(V::LANES * size_of::<f32>())
    {
        return false;
    }
    let x = &x[..k];
    let count = nonzero_indices(x, nonzero);
    let nonzero = &nonzero[..count];
    for (panel, values) in panels.chunks_exact(k * width).enumerate() {
        let first = panel * width;
        if first >= outputs {
            break;
        }
        let rows = values.as_ptr();
        let mut acc = [V::zero(); VECS];
        for &i in nonzero {
            let i = i as usize;
            // SAFETY: `nonzero_indices` wrote indices below `x.len()` = k, so `x[i]` is
            // there and row i of the panel (`width` floats from `i * width`) lies inside
            // `values` (k * width floats); it starts on a LANES boundary (checked above for
            // `panels`; panel and row offsets are multiples of `width`, itself of LANES).
            let value = V::splat(unsafe { *x.get_unchecked(i) });
            let row = unsafe { rows.add(i * width) };
            for (v, acc) in acc.iter_mut().enumerate() {
                let w = unsafe { V::load_aligned_unchecked(row.add(v * V::LANES)) };
                *acc = V::mul_add(value, w, *acc);
            }
        }
        for (v, acc) in acc.iter().enumerate() {
            let start = first + v * V::LANES;
            if start >= outputs {
                break;
            }
            let mut lanes = [0.0f32; 16];
            acc.store(&mut lanes);
            let end = (start + V::LANES).min(outputs);
            for ((t, &a), &b) in y[start..end].iter_mut().zip(&lanes).zip(&bias[start..end]) {
                *t = a + b;
            }
        }
    }
    true
}
