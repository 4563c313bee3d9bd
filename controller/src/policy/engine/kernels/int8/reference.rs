//! The portable int8 kernel: exact integer sums, any CPU; the vector kernels equal it.

use super::panels::QuadPanels;

/// `acc[o] = max over rows r of (W x_r)[o]` in exact integers, `x` holding the rows one after
/// the other, any CPU: the reference the vector kernels equal. Where `acc` holds several
/// cells of `outputs` sums, `x` holds each cell's rows in turn, the same number for each
/// (one call for a row of max-pool cells or of pixels: the checks and the set-up once).
pub(crate) fn u8s8_max_product_scalar(x: &[u8], weights: &QuadPanels, acc: &mut [i32]) {
    assert!(!weights.pairs, "int8 weights laid out for AVX2's pairs");
    let (cells, rows) = weights.cells_in(x, acc);
    let (width, row) = (weights.width, weights.padded_inputs());
    let cell_rows = x
        .chunks_exact(rows * row)
        .zip(acc.chunks_mut(weights.outputs));
    for (x, acc) in cell_rows.take(cells) {
        for (panel, out) in acc.chunks_mut(width).enumerate() {
            let w = weights.panel(panel);
            let mut largest = [i32::MIN; 64];
            for r in 0..rows {
                let mut sums = [0i32; 64];
                let sums = &mut sums[..width.min(64)];
                for (q, bytes) in x[r * row..(r + 1) * row].chunks_exact(4).enumerate() {
                    if bytes == [0; 4] {
                        continue;
                    }
                    for (column, sum) in sums.iter_mut().enumerate() {
                        let ws = &w[(q * width + column) * 4..(q * width + column) * 4 + 4];
                        for (&xv, &wv) in bytes.iter().zip(ws) {
                            *sum += i32::from(xv) * i32::from(wv);
                        }
                    }
                }
                for (most, &sum) in largest.iter_mut().zip(sums.iter()) {
                    *most = (*most).max(sum);
                }
            }
            out.copy_from_slice(&largest[..out.len()]);
        }
    }
}
