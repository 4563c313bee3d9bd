#![allow(unsafe_code)]

#[cfg(target_arch = "x86")]
use std::arch::x86::*;
#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
use super::avx2::{u8s8_max_product_2x16c_avx2, u8s8_max_product_32c_avx2};
use super::reference::u8s8_max_product_scalar;
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
use super::ssse3::u8s8_max_product_ssse3;
use super::*;
use crate::policy::engine::layout::Grid;

/// The definition: `[out][in]` rows, one product at a time, in i64 so nothing can wrap.
fn reference(x: &[u8], rows: &[i8], outputs: usize, inputs: usize) -> Vec<i32> {
    (0..outputs)
        .map(|o| {
            let sum: i64 = (0..inputs)
                .map(|i| i64::from(x[i]) * i64::from(rows[o * inputs + i]))
                .sum();
            i32::try_from(sum).expect("fits")
        })
        .collect()
}

struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        self.0 >> 33
    }
}

/// Every kernel this CPU runs, on the rows `xs` (each padded to whole groups) and the
/// weights `rows`: the largest product per output. Each vector kernel runs with and
/// without the zero-group test, and in one call over two cells: `xs`, then the same rows
/// with every byte `b` as `255 - b` ([`flipped`]), so its result is two cells' sums.
fn every_kernel(
    xs: &[Vec<u8>],
    rows: &[i8],
    outputs: usize,
    inputs: usize,
) -> Vec<(String, Vec<i32>)> {
    let pad = |xs: &[Vec<u8>]| -> Vec<u8> {
        xs.iter()
            .flat_map(|x| {
                let mut x = x.clone();
                x.resize(inputs.div_ceil(GROUP) * GROUP, 0);
                x
            })
            .collect()
    };
    let padded = pad(xs);
    let mut results = Vec::new();
    for width in [4, 8, 16] {
        let weights = QuadPanels::new(rows, outputs, inputs, width).expect("in range");
        let mut acc = vec![0; outputs];
        u8s8_max_product_scalar(&padded, &weights, &mut acc);
        let mut second = vec![0; outputs];
        u8s8_max_product_scalar(&pad(&flipped(xs)), &weights, &mut second);
        acc.extend(second);
        results.push((format!("portable {width}"), acc));
    }
    #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
    {
        let two_cells = [padded.clone(), pad(&flipped(xs))].concat();
        for zeros in [ZeroGroups::Skip, ZeroGroups::Compute] {
            // Panels of 16, of 8 (as for layers of at most 8 outputs; wider ones in
            // pieces) and of 4 (at most 4), each maximum with SSE2 and with SSE4.1.
            for sse41 in [false, true] {
                if !std::arch::is_x86_feature_detected!("ssse3")
                    || (sse41 && !std::arch::is_x86_feature_detected!("sse4.1"))
                {
                    continue;
                }
                for width in [16, 8, 4] {
                    let weights = QuadPanels::new(rows, outputs, inputs, width).expect("in range");
                    let mut acc = vec![0; 2 * outputs];
                    // SAFETY: SSSE3 detected, and SSE4.1 where `sse41`.
                    unsafe { u8s8_max_product_ssse3(&two_cells, &weights, &mut acc, zeros, sse41) };
                    let set = if sse41 { "sse4.1" } else { "ssse3" };
                    results.push((format!("{set}, panels of {width}, {zeros:?}"), acc));
                }
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                let weights = QuadPanels::new(rows, outputs, inputs, 32).expect("in range");
                let mut acc = vec![0; 2 * outputs];
                // SAFETY: AVX2 detected; width 32.
                unsafe { u8s8_max_product_32c_avx2(&two_cells, &weights, &mut acc, zeros) };
                results.push((format!("avx2, {zeros:?}"), acc));
                // Two rows at a time: the layout for at most 16 outputs, in pieces of 16.
                let mut acc = Vec::new();
                for x in [&padded, &pad(&flipped(xs))] {
                    let mut cell = vec![0; outputs];
                    for (piece, out) in cell.chunks_mut(16).enumerate() {
                        let columns = out.len();
                        let piece_rows: Vec<i8> =
                            rows[piece * 16 * inputs..][..columns * inputs].to_vec();
                        let weights =
                            QuadPanels::pairs(&piece_rows, columns, inputs).expect("in range");
                        // SAFETY: AVX2 detected; laid out in pairs.
                        unsafe { u8s8_max_product_2x16c_avx2(x, &weights, out, zeros) };
                    }
                    acc.extend(cell);
                }
                results.push((format!("avx2, pairs of rows, {zeros:?}"), acc));
            }
        }
    }
    results
}

/// `xs` with every byte `b` as `255 - b`: the second cell of [`every_kernel`].
fn flipped(xs: &[Vec<u8>]) -> Vec<Vec<u8>> {
    xs.iter()
        .map(|x| x.iter().map(|&b| 255 - b).collect())
        .collect()
}

/// [`largest_reference`] of `xs` and of [`flipped`] `xs`, one after the other: what
/// [`every_kernel`]'s two cells give.
fn two_cells_reference(xs: &[Vec<u8>], rows: &[i8], outputs: usize, inputs: usize) -> Vec<i32> {
    let mut expected = largest_reference(xs, rows, outputs, inputs);
    expected.extend(largest_reference(&flipped(xs), rows, outputs, inputs));
    expected
}

/// The largest of the definition's products over the rows `xs`.
fn largest_reference(xs: &[Vec<u8>], rows: &[i8], outputs: usize, inputs: usize) -> Vec<i32> {
    let products: Vec<Vec<i32>> = xs
        .iter()
        .map(|x| reference(x, rows, outputs, inputs))
        .collect();
    (0..outputs)
        .map(|o| products.iter().map(|p| p[o]).max().expect("a row"))
        .collect()
}

#[test]
fn every_kernel_equals_the_integer_definition_on_random_layers() {
    let mut rng = Lcg(29);
    // Whole groups of sixteen inputs and groups padded with zero weights; one row (a
    // dense layer) and the four windows of a 2x2 pool.
    let layers = [
        (128, 2560),
        (3, 128),
        (37, 13),
        (16, 4),
        (1, 1),
        (33, 7),
        (20, 30),
        (16, 25),
        (48, 100),
    ];
    for (outputs, inputs) in layers {
        let rows: Vec<i8> = (0..outputs * inputs)
            .map(|_| ((rng.next() % 129) as i16 - 64) as i8)
            .collect();
        for count in [1, 3, 4] {
            // Half the inputs zero, as after ReLU, and every other run of 24 inputs
            // zero, so that skipped groups of 16 are tested too.
            let xs: Vec<Vec<u8>> = (0..count)
                .map(|_| {
                    (0..inputs)
                        .map(|i| {
                            if rng.next().is_multiple_of(2) || (i / 24) % 2 == 1 {
                                0
                            } else {
                                rng.next() as u8
                            }
                        })
                        .collect()
                })
                .collect();
            let expected = two_cells_reference(&xs, &rows, outputs, inputs);
            for (kernel, acc) in every_kernel(&xs, &rows, outputs, inputs) {
                assert_eq!(
                    acc, expected,
                    "{kernel}, {outputs}x{inputs}, {count} row(s)"
                );
            }
        }
    }
}

#[test]
fn the_last_group_is_computed_up_to_its_last_nonzero_weight() {
    // A camera's 5x5 window of one channel (25 bytes: 3 of the last group's 4 quads), of
    // four and of eight channels (100: 1; 200: 2), whole groups (4) and the small cases.
    for (inputs, tail) in [
        (25, 3),
        (100, 1),
        (200, 2),
        (1280, 4),
        (16, 4),
        (17, 1),
        (1, 1),
        (4, 1),
        (5, 2),
        (13, 4),
        (0, 1),
    ] {
        let weights = QuadPanels::new(&vec![1; 3 * inputs], 3, inputs, 4).expect("in range");
        assert_eq!(weights.tail_quads(), tail, "{inputs} inputs");
    }
    // A window laid out in whole groups: zero weights after its 25 bytes (quads 4..6 of
    // the last group hold them), but another output's last nonzero weight may come later.
    for (last, tail) in [(24, 3), (27, 3), (28, 4), (31, 4), (16, 3), (3, 3)] {
        let mut rows = vec![0i8; 3 * 32];
        rows[..25].fill(5);
        rows[64 + last] = -1;
        let weights = QuadPanels::new(&rows, 3, 32, 8).expect("in range");
        assert_eq!(weights.tail_quads(), tail, "last nonzero {last}");
    }
    // Nothing but zeros in the last group: one quad of it is computed.
    let mut rows = vec![0i8; 2 * 32];
    rows[..16].fill(-7);
    assert_eq!(
        QuadPanels::new(&rows, 2, 32, 4)
            .expect("in range")
            .tail_quads(),
        1
    );
}

#[test]
fn coding_a_run_equals_coding_each_value() {
    // Halves (rounded to even), the ends of the range and past them, the clamp at +-512
    // steps, infinities, NaN, negative zero; runs of every length around 16.
    let mut rng = Lcg(17);
    for (scale, zero) in [(0.02f32, 0u8), (0.013, 128), (1.0 / 255.0, 3), (7.5, 255)] {
        let grid = Grid::new(scale, zero).expect("a grid");
        let mut values: Vec<f32> = Vec::new();
        for k in -600..600 {
            values.push((k as f32 + 0.5) * scale);
            values.push(k as f32 * scale);
        }
        values.extend([
            f32::NAN,
            -f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            -0.0,
            f32::MAX,
            f32::MIN,
            f32::MIN_POSITIVE,
        ]);
        values.extend((0..200).map(|_| (rng.next() as f32 / 2f32.powi(31) - 0.5) * 600.0 * scale));
        for start in 0..3 {
            for len in [0, 1, 15, 16, 17, 31, 32, 33, values.len() - start] {
                let run = &values[start..start + len];
                let mut codes = vec![0xeeu8; len];
                code_run(grid, run, &mut codes);
                let expected: Vec<u8> = run.iter().map(|&v| grid.code(v)).collect();
                assert_eq!(
                    codes, expected,
                    "scale {scale}, zero {zero}, {len} from {start}"
                );
            }
        }
    }
}

#[test]
fn several_cells_in_one_call_equal_one_call_each() {
    // A row of max-pool cells (or of pixels) goes to the kernel in one call: each cell's
    // outputs must be those of the cell alone, for every layout and row count.
    let mut rng = Lcg(41);
    for (outputs, inputs) in [(16, 32), (8, 25), (4, 25), (32, 400), (37, 13)] {
        let rows: Vec<i8> = (0..outputs * inputs)
            .map(|_| ((rng.next() % 129) as i16 - 64) as i8)
            .collect();
        for (cells, per_cell) in [(1, 1), (5, 1), (7, 4), (3, 3)] {
            for kernel in [
                Int8Kernel::PORTABLE,
                Int8Kernel::ssse3(),
                Int8Kernel::ssse3_pmaxsd(),
                Int8Kernel::avx2(),
            ] {
                let weights = kernel.lay_out(&rows, outputs, inputs).expect("in range");
                let row = weights.padded_inputs();
                let x: Vec<u8> = (0..cells * per_cell * row)
                    .map(|i| {
                        if i % row < inputs {
                            rng.next() as u8
                        } else {
                            0
                        }
                    })
                    .collect();
                let mut together = vec![0i32; cells * outputs];
                // One call without the zero-group test, each cell alone with it.
                kernel.largest(&x, &weights, &mut together, ZeroGroups::Compute);
                for cell in 0..cells {
                    let mut alone = vec![0i32; outputs];
                    let part = &x[cell * per_cell * row..(cell + 1) * per_cell * row];
                    kernel.largest(part, &weights, &mut alone, ZeroGroups::Skip);
                    assert_eq!(
                        together[cell * outputs..(cell + 1) * outputs],
                        alone,
                        "{}, {outputs}x{inputs}, cell {cell} of {cells}, {per_cell} row(s)",
                        kernel.name()
                    );
                    let xs: Vec<Vec<u8>> = part
                        .chunks_exact(row)
                        .map(|r| r[..inputs].to_vec())
                        .collect();
                    assert_eq!(alone, largest_reference(&xs, &rows, outputs, inputs));
                }
            }
        }
    }
}

#[test]
fn the_worst_cases_of_pmaddubsw_do_not_saturate() {
    // Every input 255 against every weight at an end of the range: each 16-bit pair sum
    // is then +-32,640, the largest magnitudes the range allows; mixed signs in a row
    // and alternating patterns too. A saturating sum (or a kernel that adds pairs in 16
    // bits) would differ from the definition here. Two rows: the largest of a sum and
    // its negative (all-negative sums must win over nothing).
    let inputs = 2560;
    let outputs = 32;
    let x = vec![255u8; inputs];
    let patterns: [&dyn Fn(usize, usize) -> i8; 4] = [
        &|_, _| MAX_WEIGHT,
        &|_, _| -MAX_WEIGHT,
        &|o, i| {
            if (o + i).is_multiple_of(2) {
                MAX_WEIGHT
            } else {
                -MAX_WEIGHT
            }
        },
        &|o, i| {
            if (i / 2 + o).is_multiple_of(2) {
                MAX_WEIGHT
            } else {
                -MAX_WEIGHT
            }
        },
    ];
    for (p, pattern) in patterns.iter().enumerate() {
        let rows: Vec<i8> = (0..outputs * inputs)
            .map(|k| pattern(k / inputs, k % inputs))
            .collect();
        for xs in [vec![x.clone()], vec![x.clone(), x.clone()]] {
            let expected = two_cells_reference(&xs, &rows, outputs, inputs);
            for (kernel, acc) in every_kernel(&xs, &rows, outputs, inputs) {
                assert_eq!(acc, expected, "{kernel}, pattern {p}");
            }
        }
    }
    assert_eq!(
        reference(&[255; 2560], &[64; 2560], 1, 2560),
        [255 * 64 * 2560]
    );
}

#[test]
fn weights_pmaddubsw_could_saturate_on_are_refused() {
    let mut rows = vec![0i8; 8 * 5];
    rows[3 * 5 + 2] = -65;
    assert_eq!(
        QuadPanels::new(&rows, 8, 5, 8),
        Err(WeightOutOfRange {
            output: 3,
            input: 2,
            value: -65
        })
    );
    // Laid out in pairs of rows, the error names the real output too.
    assert_eq!(
        QuadPanels::pairs(&rows, 8, 5),
        Err(WeightOutOfRange {
            output: 3,
            input: 2,
            value: -65
        })
    );
    rows[3 * 5 + 2] = 127;
    assert!(QuadPanels::new(&rows, 8, 5, 8).is_err());
    assert!(QuadPanels::pairs(&rows, 8, 5).is_err());
    rows[3 * 5 + 2] = -64;
    assert!(QuadPanels::new(&rows, 8, 5, 8).is_ok());
}

#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
#[test]
fn a_full_range_weight_would_saturate_pmaddubsw() {
    // Why the range is refused: with -128..127 weights two products of 255 overflow the
    // 16-bit pair sum, and `pmaddubsw` answers 32,767 instead of 64,770.
    if !std::arch::is_x86_feature_detected!("ssse3") {
        return;
    }
    // SAFETY: SSSE3 detected.
    let lane = unsafe {
        let pairs = _mm_maddubs_epi16(_mm_set1_epi8(-1), _mm_set1_epi8(127));
        _mm_extract_epi16::<0>(pairs)
    };
    assert_eq!(lane, 32_767);
    assert_eq!(255 * 127 * 2, 64_770);
}

#[test]
fn a_row_count_the_weights_do_not_divide_is_refused() {
    let weights = QuadPanels::new(&[1; 3 * 20], 3, 20, 16).expect("in range");
    assert_eq!(weights.padded_inputs(), 32);
    let mut acc = [0; 3];
    for x in [vec![0u8; 31], vec![0u8; 33], Vec::new()] {
        let refused = std::panic::catch_unwind(|| {
            u8s8_max_product_scalar(&x, &weights, &mut acc.clone());
        });
        assert!(refused.is_err(), "{} bytes", x.len());
    }
    u8s8_max_product_scalar(&[1; 64], &weights, &mut acc);
    assert_eq!(acc, [20; 3]);
}

#[test]
fn pooled_windows_of_a_convolution_equal_the_integer_definition() {
    let mut rng = Lcg(5);
    for (ph, pw, c, oc, [kh, kw], stride) in [
        (13, 17, 3, 10, [5, 5], [2, 2]),
        (9, 11, 1, 16, [5, 5], [2, 2]),
        (7, 7, 8, 33, [3, 3], [1, 1]),
        (8, 8, 1, 4, [4, 4], [1, 1]),
        // The narrow CNN's second layers: rows of 40 and 20 bytes (three and two
        // 16-byte chunks), and a row of 72 (five chunks, the general loop).
        (11, 13, 8, 16, [5, 5], [2, 2]),
        (9, 9, 4, 8, [5, 5], [2, 2]),
        (7, 9, 24, 6, [3, 3], [1, 1]),
    ] {
        let window = Window::new(pw, c, [kh, kw], stride);
        assert!(window.padded_len().is_multiple_of(GROUP));
        // The map's codes, then the slack a last window row reads past it.
        let mut codes: Vec<u8> = (0..ph * pw * c).map(|_| rng.next() as u8).collect();
        codes.extend((0..window.slack()).map(|_| rng.next() as u8));
        let rows: Vec<i8> = (0..oc * kh * kw * c)
            .map(|_| ((rng.next() % 129) as i16 - 64) as i8)
            .collect();
        let laid_out = window.weights(&rows, oc);
        let (oh, ow) = ((ph - kh) / stride[0] + 1, (pw - kw) / stride[1] + 1);
        // A row of pixels as one block: the same bytes as window by window.
        let len = window.padded_len();
        for y in 0..oh {
            let mut block = vec![0x5au8; ow * len];
            window.gather_block(&codes, [y, 0], [1, ow], &mut block);
            let mut one_by_one = vec![0x5au8; ow * len];
            for x in 0..ow {
                let slot = &mut one_by_one[x * len..(x + 1) * len];
                window.gather_block(&codes, [y, x], [1, 1], slot);
            }
            assert_eq!(block, one_by_one, "row {y}");
        }
        // A row of whole 2x2 cells as one call: the same bytes as cell by cell.
        for y in (0..oh.saturating_sub(1)).step_by(2) {
            let cells = ow / 2;
            let mut row_of_cells = vec![0x3cu8; cells * 4 * len];
            window.gather_cells(&codes, [y, 0], [2, 2], [cells, 2], &mut row_of_cells);
            let mut cell_by_cell = vec![0x3cu8; cells * 4 * len];
            for cell in 0..cells {
                let slot = &mut cell_by_cell[cell * 4 * len..(cell + 1) * 4 * len];
                window.gather_block(&codes, [y, 2 * cell], [2, 2], slot);
            }
            assert_eq!(row_of_cells, cell_by_cell, "cells of row {y}");
        }
        let definition = |y: usize, x: usize, o: usize| -> i64 {
            let mut sum = 0i64;
            for ky in 0..kh {
                for kx in 0..kw {
                    for i in 0..c {
                        let pixel = ((y * stride[0] + ky) * pw + x * stride[1] + kx) * c;
                        let w = rows[((o * kh + ky) * kw + kx) * c + i];
                        sum += i64::from(codes[pixel + i]) * i64::from(w);
                    }
                }
            }
            sum
        };
        for kernel in [
            Int8Kernel::PORTABLE,
            Int8Kernel::ssse3(),
            Int8Kernel::ssse3_pmaxsd(),
            Int8Kernel::avx2(),
        ] {
            let weights = kernel
                .lay_out(&laid_out, oc, window.padded_len())
                .expect("in range");
            let len = window.padded_len();
            // Stale bytes in the scratch must not matter.
            let mut windows = vec![0xa5u8; 4 * len];
            let mut sums = vec![0i32; oc];
            // Each 2x2 cell of pixels (the last row and column alone where odd).
            for (y, x) in (0..oh)
                .step_by(2)
                .flat_map(|y| (0..ow).step_by(2).map(move |x| (y, x)))
            {
                let pixels: Vec<[usize; 2]> = [[y, x], [y, x + 1], [y + 1, x], [y + 1, x + 1]]
                    .into_iter()
                    .filter(|&[py, px]| py < oh && px < ow)
                    .collect();
                for (i, &pixel) in pixels.iter().enumerate() {
                    let slot = &mut windows[i * len..(i + 1) * len];
                    window.gather_block(&codes, pixel, [1, 1], slot);
                }
                if pixels.len() == 4 {
                    // The cell as one block: the same bytes as window by window.
                    let mut block = vec![0xa5u8; 4 * len];
                    window.gather_block(&codes, [y, x], [2, 2], &mut block);
                    assert_eq!(block, windows[..4 * len], "cell ({y}, {x})");
                }
                kernel.largest(
                    &windows[..pixels.len() * len],
                    &weights,
                    &mut sums,
                    ZeroGroups::Skip,
                );
                for (o, &sum) in sums.iter().enumerate() {
                    let expected = pixels
                        .iter()
                        .map(|&[py, px]| definition(py, px, o))
                        .max()
                        .expect("a pixel");
                    assert_eq!(
                        i64::from(sum),
                        expected,
                        "{}, {c} channels: cell ({y}, {x}) output {o}",
                        kernel.name(),
                    );
                }
            }
        }
    }
}
