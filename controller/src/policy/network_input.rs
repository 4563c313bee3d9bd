//! The network's input made from a thumbnail: the one place both engines and the load-time
//! check turn u8 pixels into f32 values, as the manifest's `[normalisation]` says.
//!
//! Two rules (DESIGN.md, "Policies"):
//! - scaled (the paper's and every model before issue 48): `pixel * scale`;
//! - standardised (`standardise = true`): `(pixel - mean) / max(spread, 4)`, with the mean
//!   and the spread (population standard deviation) of that thumbnail's own pixels, in pixel
//!   levels. A global gain or offset of the image (exposure, sensor gain, halved contrast)
//!   leaves the values unchanged up to rounding and clipping; the floor keeps a nearly blank
//!   thumbnail (a covered lens, a dark frame) at its noise's size instead of raising the
//!   noise to unit spread.
//!
//! One pass for the sums (integers, so the order of additions cannot change the result),
//! one for the values; nothing is allocated. Python computes the same values
//! (`dribble_models.contract.network_input`).

use super::manifest::Normalisation;

/// The smallest spread, in pixel levels, a standardised thumbnail is divided by.
pub const STANDARDISE_FLOOR_LEVELS: f32 = 4.0;

/// Writes the network's values for `pixels` into `values` (the first `pixels.len()` of them).
pub fn write_network_input(normalisation: &Normalisation, pixels: &[u8], values: &mut [f32]) {
    if !normalisation.standardise {
        let scale = normalisation.scale;
        for (value, &pixel) in values.iter_mut().zip(pixels) {
            *value = f32::from(pixel) * scale;
        }
        return;
    }
    let (mean, inverse_spread) = standardisation(pixels);
    for (value, &pixel) in values.iter_mut().zip(pixels) {
        *value = (f32::from(pixel) - mean) * inverse_spread;
    }
}

/// The mean of `pixels` and one over their floored spread, in pixel levels.
fn standardisation(pixels: &[u8]) -> (f32, f32) {
    if pixels.is_empty() {
        return (0.0, 1.0 / STANDARDISE_FLOOR_LEVELS);
    }
    let (mut sum, mut squares) = (0u64, 0u64);
    // 32-bit sums over chunks whose squares cannot overflow them (255^2 * 65,536 < 2^32),
    // which the compiler turns into vector code on every target (64-bit additions in the
    // loop cost a carry chain a pixel on the V5's 32-bit build); exact, like the u64 sums.
    for chunk in pixels.chunks(1 << 16) {
        let (mut chunk_sum, mut chunk_squares) = (0u32, 0u32);
        for &pixel in chunk {
            let pixel = u32::from(pixel);
            chunk_sum += pixel;
            chunk_squares += pixel * pixel;
        }
        sum += u64::from(chunk_sum);
        squares += u64::from(chunk_squares);
    }
    let count = pixels.len() as f64;
    let mean = sum as f64 / count;
    let variance = (squares as f64 / count - mean * mean).max(0.0);
    let spread = variance.sqrt().max(f64::from(STANDARDISE_FLOOR_LEVELS));
    (mean as f32, (1.0 / spread) as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn normalisation(standardise: bool) -> Normalisation {
        Normalisation {
            scale: 1.0 / 255.0,
            standardise,
        }
    }

    #[test]
    fn scaled_input_is_pixel_times_scale() {
        let mut values = [0.0f32; 3];
        write_network_input(&normalisation(false), &[0, 51, 255], &mut values);
        for (value, expected) in values.iter().zip([0.0, 0.2, 1.0]) {
            assert!(
                (value - expected).abs() < 1e-6,
                "{value} against {expected}"
            );
        }
    }

    #[test]
    fn standardised_input_has_zero_mean_and_unit_spread() {
        let pixels: Vec<u8> = (0..=255u8).cycle().take(1000).collect();
        let mut values = vec![0.0f32; pixels.len()];
        write_network_input(&normalisation(true), &pixels, &mut values);
        let n = values.len() as f64;
        let mean = values.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
        let spread = (values
            .iter()
            .map(|&v| (f64::from(v) - mean).powi(2))
            .sum::<f64>()
            / n)
            .sqrt();
        assert!(mean.abs() < 1e-5, "mean {mean}");
        assert!((spread - 1.0).abs() < 1e-5, "spread {spread}");
    }

    #[test]
    fn standardised_input_ignores_gain_and_offset() {
        let dim: Vec<u8> = (0..600u32).map(|i| (20 + (i * 7) % 50) as u8).collect();
        let bright: Vec<u8> = dim.iter().map(|&p| p * 2 + 30).collect();
        let (mut a, mut b) = (vec![0.0f32; 600], vec![0.0f32; 600]);
        write_network_input(&normalisation(true), &dim, &mut a);
        write_network_input(&normalisation(true), &bright, &mut b);
        for (x, y) in a.iter().zip(&b) {
            assert!((x - y).abs() < 1e-5, "{x} against {y}");
        }
    }

    #[test]
    fn the_sums_are_exact_past_a_chunk_of_white_pixels() {
        // Three chunks and a bit of 255s and a 0: 32-bit squares of a whole image would
        // overflow; the chunked sums give the 64-bit reference's mean and spread.
        let mut pixels = vec![255u8; 3 * (1 << 16) + 5];
        pixels[7] = 0;
        let (mean, inverse_spread) = standardisation(&pixels);
        let n = pixels.len() as f64;
        let reference_mean = 255.0 * (n - 1.0) / n;
        let reference_spread = (255.0f64 * 255.0 * (n - 1.0) / n - reference_mean * reference_mean)
            .sqrt()
            .max(4.0);
        assert_eq!(mean, reference_mean as f32);
        assert_eq!(inverse_spread, (1.0 / reference_spread) as f32);
    }

    #[test]
    fn a_flat_thumbnail_is_divided_by_the_floor() {
        let pixels = [100u8, 100, 100, 104];
        let mut values = [0.0f32; 4];
        write_network_input(&normalisation(true), &pixels, &mut values);
        // mean 101, spread sqrt(3) < 4: the floor divides.
        assert_eq!(values, [-0.25, -0.25, -0.25, 0.75]);
    }
}
