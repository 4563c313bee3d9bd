//! A convolution's kernel window for one output pixel in SSE assembly with the weight
//! offsets written into the instructions: for the Nao V5's 32-bit build, whose eight vector
//! registers the compiler's code spills (see [`super::simd`]'s `window_of_taps4`, the loop
//! these specialise).
//!
//! The general loop advances its weight pointer once per tap by a stride read from memory,
//! and pays a loop's counter, compare and branch per four taps and per row. Where the
//! stride is one of the networks' (16 or 32 output channels: 64 or 128 bytes a tap) the
//! offsets are known when the code is written, so here:
//! - [`window_5x5_one_channel_16`]: the first layer (one input channel, 5x5, 16 output
//!   channels) with its 25 taps written out: no loop, no pointer arithmetic but one `add`
//!   a row (callgrind, V5: this layer took 2.4 M of the CNN's 6.6 M instructions);
//! - [`window_of_pixels`]: rows of whole input pixels of 8 or 16 channels (the second
//!   layers), one pixel's channels per loop iteration, their weights at fixed offsets.
//!
//! The arithmetic and its order are the general loop's: per tap, `mulps` then `addps` into
//! each of the four accumulators, taps in order; so results are bit for bit the same.
//!
//! Written for both x86 targets (the registers are pointer-sized, counts are `usize`), so that
//! the host's tests check them against a scalar reference; only the 32-bit build calls them.
#![allow(unsafe_code)]
#![cfg_attr(not(target_arch = "x86"), allow(dead_code))]

#[cfg(target_arch = "x86")]
use std::arch::x86::__m128;
#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::__m128;

/// One tap: the broadcast input in {b} times the four weight vectors of tap `$k + $j`, `$s`
/// bytes a tap from {w}, into {a0}..{a3}. The last product is formed in {b} itself.
macro_rules! tap_at {
    ($s:literal, $k:literal, $j:literal) => {
        concat!(
            "movaps {t}, xmmword ptr [{w} + ",
            $s,
            "*(",
            $k,
            "+",
            $j,
            ")]\n",
            "mulps {t}, {b}\n",
            "addps {a0}, {t}\n",
            "movaps {t}, xmmword ptr [{w} + ",
            $s,
            "*(",
            $k,
            "+",
            $j,
            ") + 16]\n",
            "mulps {t}, {b}\n",
            "addps {a1}, {t}\n",
            "movaps {t}, xmmword ptr [{w} + ",
            $s,
            "*(",
            $k,
            "+",
            $j,
            ") + 32]\n",
            "mulps {t}, {b}\n",
            "addps {a2}, {t}\n",
            "mulps {b}, xmmword ptr [{w} + ",
            $s,
            "*(",
            $k,
            "+",
            $j,
            ") + 48]\n",
            "addps {a3}, {b}\n",
        )
    };
}

/// Four taps from the four inputs at byte `$at` from {x}: loaded once, each broadcast by
/// `pshufd`; taps `$k`..`$k + 3`.
macro_rules! quad_at {
    ($s:literal, $at:literal, $k:literal) => {
        concat!(
            "movups {v}, xmmword ptr [{x} + ",
            $at,
            "]\n",
            "pshufd {b}, {v}, 0x00\n",
            tap_at!($s, $k, 0),
            "pshufd {b}, {v}, 0x55\n",
            tap_at!($s, $k, 1),
            "pshufd {b}, {v}, 0xaa\n",
            tap_at!($s, $k, 2),
            "pshufd {b}, {v}, 0xff\n",
            tap_at!($s, $k, 3),
        )
    };
}

/// One row of a 5x5 window with one input channel: four taps from one load, the fifth
/// broadcast by itself; then {x} moves to the next row ({r} bytes on).
macro_rules! row_of_five {
    ($k:literal) => {
        concat!(
            quad_at!("64", "0", $k),
            "movss {b}, dword ptr [{x} + 16]\n",
            "shufps {b}, {b}, 0\n",
            tap_at!("64", $k, 4),
            "add {x}, {r}\n",
        )
    };
}

/// The window of one output pixel for the layouts written out here: `rows` rows of `pixels`
/// input pixels of `channels` channels, `x_row` floats apart, into 16 output channels of a
/// layer with `w_stride` output channels (the contract of `Vector::window_of_taps4`). Returns
/// false, having done nothing, for a layout that is not one of them.
///
/// # Safety
/// As [`window_5x5_one_channel_16`] or [`window_of_pixels`] for the layout given.
#[inline(always)]
pub(crate) unsafe fn window(
    acc: &mut [__m128; 4],
    x: *const f32,
    x_row: usize,
    w: *const f32,
    layout @ [rows, pixels, channels]: [usize; 3],
    w_stride: usize,
) -> bool {
    if [rows, pixels, channels, w_stride] == [5, 5, 1, 16] {
        // SAFETY: the caller's promise for this layout.
        unsafe { window_5x5_one_channel_16(acc, x, x_row, w) };
        return true;
    }
    // SAFETY: the caller's promise for this layout.
    unsafe { window_of_pixels(acc, x, x_row, w, layout, w_stride) }
}

/// `acc[v] += x * w[..]` over a 5x5 window of one input channel into 16 output channels:
/// tap `t = 5 * row + column` reads the input `x[row * x_row + column]` and the weights
/// `w[16 * t .. 16 * t + 16]`, taps in order.
///
/// # Safety
/// `x` must point at 5 rows of 5 readable floats, `x_row` floats apart; `w` at 400 readable
/// floats aligned to 16 bytes.
#[inline(always)]
pub(crate) unsafe fn window_5x5_one_channel_16(
    acc: &mut [__m128; 4],
    x: *const f32,
    x_row: usize,
    w: *const f32,
) {
    let [mut a0, mut a1, mut a2, mut a3] = *acc;
    // SAFETY: the caller's promise: the rows' five inputs and the 25 taps' 16 weights, the
    // weight vectors on 16-byte boundaries (`movaps`); {x} and the vector temporaries are
    // the only other registers written.
    unsafe {
        core::arch::asm!(
            row_of_five!(0),
            row_of_five!(5),
            row_of_five!(10),
            row_of_five!(15),
            row_of_five!(20),
            x = inout(reg) x => _,
            w = in(reg) w,
            r = in(reg) x_row * size_of::<f32>(),
            a0 = inout(xmm_reg) a0,
            a1 = inout(xmm_reg) a1,
            a2 = inout(xmm_reg) a2,
            a3 = inout(xmm_reg) a3,
            v = out(xmm_reg) _,
            b = out(xmm_reg) _,
            t = out(xmm_reg) _,
            options(nostack, readonly),
        );
    }
    *acc = [a0, a1, a2, a3];
}

/// The loop of [`window_of_pixels`] for one layout: `$quads` loads of four inputs (one
/// input pixel's channels) per iteration, the taps' weights `$s` bytes apart.
macro_rules! pixels_loop {
    ($acc:ident, $x:ident, $w:ident, $counts:ident, $s:literal, [$($at:literal $k:literal),+]) => {{
        let [mut a0, mut a1, mut a2, mut a3] = *$acc;
        // SAFETY: [`window_of_pixels`]' caller's promise; the loops write only the counts'
        // rows-left field, {x}, {w}, {n} and the vector temporaries.
        unsafe {
            core::arch::asm!(
                "3:",
                "mov {n}, [{p}]",
                "2:",
                $(quad_at!($s, $at, $k),)+
                "add {x}, [{p} + {one}]",
                "add {w}, [{p} + 2*{one}]",
                "dec {n}",
                "jnz 2b",
                "add {x}, [{p} + 3*{one}]",
                "mov {n}, [{p} + 4*{one}]",
                "dec {n}",
                "mov [{p} + 4*{one}], {n}",
                "jnz 3b",
                x = inout(reg) $x => _,
                w = inout(reg) $w => _,
                n = out(reg) _,
                p = in(reg) $counts.as_mut_ptr(),
                one = const size_of::<usize>(),
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
        *$acc = [a0, a1, a2, a3];
    }};
}

/// `acc[v] += x * w[..]` over `rows` rows of `pixels` input pixels of `channels` channels
/// each (8 or 16), into 16 output channels of a layer with `w_stride` (16 or 32) output
/// channels: tap `t = (row * pixels + pixel) * channels + channel` reads the input
/// `x[row * x_row + pixel * channels + channel]` and the weights `w[t * w_stride ..][..16]`,
/// taps in order. Returns false, having done nothing, for another layout.
///
/// # Safety
/// `x` must point at `rows` rows of `pixels * channels` readable floats, `x_row` floats apart;
/// `w` at `rows * pixels * channels` taps `w_stride` floats apart, each with 16 readable
/// floats from a 16-byte boundary.
#[inline(always)]
pub(crate) unsafe fn window_of_pixels(
    acc: &mut [__m128; 4],
    x: *const f32,
    x_row: usize,
    w: *const f32,
    [rows, pixels, channels]: [usize; 3],
    w_stride: usize,
) -> bool {
    if rows == 0 || pixels == 0 {
        return true;
    }
    let float = size_of::<f32>();
    // Pixels a row, bytes from one pixel's inputs to the next, bytes from one pixel's weights
    // to the next, bytes from a row's end to the next row's start, rows left.
    let mut counts: [usize; 5] = [
        pixels,
        channels * float,
        channels * w_stride * float,
        (x_row - pixels * channels) * float,
        rows,
    ];
    match (channels, w_stride) {
        (8, 16) => pixels_loop!(acc, x, w, counts, "64", ["0" 0, "16" 4]),
        (16, 32) => pixels_loop!(acc, x, w, counts, "128", ["0" 0, "16" 4, "32" 8, "48" 12]),
        _ => return false,
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    #[cfg(target_arch = "x86")]
    use std::arch::x86::{_mm_loadu_ps, _mm_storeu_ps};
    #[cfg(target_arch = "x86_64")]
    use std::arch::x86_64::{_mm_loadu_ps, _mm_storeu_ps};

    /// Weights on a 16-byte boundary (`movaps`).
    #[repr(C, align(16))]
    struct Aligned<const N: usize>([f32; N]);

    /// A deterministic spread of values, some negative.
    fn values<const N: usize>(seed: u32) -> [f32; N] {
        let mut state = seed.wrapping_mul(2_654_435_761).wrapping_add(1);
        core::array::from_fn(|_| {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            (state % 2001) as f32 / 1000.0 - 1.0
        })
    }

    fn to_vectors(values: &[f32; 16]) -> [__m128; 4] {
        // SAFETY: four vectors of four floats from a 16-float array; SSE is baseline on x86.
        core::array::from_fn(|v| unsafe { _mm_loadu_ps(values[4 * v..].as_ptr()) })
    }

    fn from_vectors(vectors: &[__m128; 4]) -> [f32; 16] {
        let mut out = [0.0; 16];
        for (v, vector) in vectors.iter().enumerate() {
            // SAFETY: four floats into a 16-float array.
            unsafe { _mm_storeu_ps(out[4 * v..].as_mut_ptr(), *vector) };
        }
        out
    }

    /// The same sums in the same order as the assembly: per tap, product then sum.
    fn reference(
        start: &[f32; 16],
        taps: impl Iterator<Item = (f32, usize)>,
        w: &[f32],
    ) -> [f32; 16] {
        let mut acc = *start;
        for (x, at) in taps {
            for (o, acc) in acc.iter_mut().enumerate() {
                *acc += x * w[at + o];
            }
        }
        acc
    }

    #[test]
    fn the_first_layers_window_adds_every_tap_in_order() {
        let x_row = 9;
        let x: [f32; 5 * 9] = values(1);
        let w = Aligned::<400>(values(2));
        let start: [f32; 16] = values(3);
        let mut acc = to_vectors(&start);
        // SAFETY: 5 rows of 9 floats; 25 taps of 16 aligned weights.
        let done = unsafe { window(&mut acc, x.as_ptr(), x_row, w.0.as_ptr(), [5, 5, 1], 16) };
        assert!(done);
        let taps = (0..25).map(|t| (x[(t / 5) * x_row + t % 5], 16 * t));
        let expected = reference(&start, taps, &w.0);
        assert_eq!(
            from_vectors(&acc).map(f32::to_bits),
            expected.map(f32::to_bits)
        );
    }

    fn check_pixels(channels: usize, w_stride: usize) {
        let (rows, pixels, x_row) = (5, 5, 5 * channels + 3);
        let x: [f32; 5 * (5 * 16 + 3)] = values(4);
        let w = Aligned::<{ 25 * 16 * 32 }>(values(5));
        let start: [f32; 16] = values(6);
        let mut acc = to_vectors(&start);
        // Inside the arrays: rows of x_row floats, 25 * channels taps of w_stride floats.
        let done = unsafe {
            window(
                &mut acc,
                x.as_ptr(),
                x_row,
                w.0.as_ptr(),
                [rows, pixels, channels],
                w_stride,
            )
        };
        assert!(done);
        let per_row = pixels * channels;
        let taps =
            (0..rows * per_row).map(|t| (x[(t / per_row) * x_row + t % per_row], t * w_stride));
        let expected = reference(&start, taps, &w.0);
        assert_eq!(
            from_vectors(&acc).map(f32::to_bits),
            expected.map(f32::to_bits)
        );
    }

    #[test]
    fn a_window_of_eight_channel_pixels_adds_every_tap_in_order() {
        check_pixels(8, 16);
    }

    #[test]
    fn a_window_of_sixteen_channel_pixels_adds_every_tap_in_order() {
        check_pixels(16, 32);
    }

    #[test]
    fn other_layouts_are_left_to_the_general_loop() {
        let mut acc = to_vectors(&[0.0; 16]);
        let w = Aligned::<64>([0.0; 64]);
        let x = [0.0f32; 4];
        // SAFETY: refused before anything is read.
        let done = unsafe { window(&mut acc, x.as_ptr(), 4, w.0.as_ptr(), [1, 1, 4], 16) };
        assert!(!done);
    }
}
