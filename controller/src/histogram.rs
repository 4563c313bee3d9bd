//! The H-CNN gating feature: a 5-bin intensity histogram of each thumbnail.
//!
//! DESIGN.md: equal bins over 0..255, divided by the pixel count, top then bottom. For
//! integer pixels the bin edges are 0, 51, 102, 153, 204 and 255 (last bin closed), which is
//! exactly what `numpy.histogram(pixels, bins=5, range=(0, 255))` counts, so the training
//! side and the robot pick the same cluster.

use crate::thumbnail::{BottomThumbnail, Thumbnail, TopThumbnail};

pub const HISTOGRAM_BINS: usize = 5;
/// Length of the gating feature: top histogram, then bottom histogram.
pub const GATING_FEATURE_LEN: usize = 2 * HISTOGRAM_BINS;

/// Width of one bin in pixel values: 255 / 5.
const BIN_WIDTH: u8 = 51;

/// The bin of a pixel value: `[0, 51)` is bin 0, ..., `[204, 255]` is bin 4.
pub const fn bin_of(value: u8) -> usize {
    let bin = (value / BIN_WIDTH) as usize;
    if bin < HISTOGRAM_BINS {
        bin
    } else {
        HISTOGRAM_BINS - 1
    }
}

/// Fractions of the thumbnail's pixels in each of the five bins (they add up to 1).
pub fn intensity_histogram<const W: usize, const H: usize>(
    thumbnail: &Thumbnail<W, H>,
) -> [f32; HISTOGRAM_BINS] {
    let mut counts = [0u32; HISTOGRAM_BINS];
    for &value in thumbnail.as_bytes() {
        counts[bin_of(value)] += 1;
    }
    let pixels = (W * H) as f32;
    counts.map(|count| count as f32 / pixels)
}

/// The 10-value gating feature of H-CNN: top histogram then bottom histogram.
pub fn gating_feature(top: &TopThumbnail, bottom: &BottomThumbnail) -> [f32; GATING_FEATURE_LEN] {
    let mut feature = [0.0; GATING_FEATURE_LEN];
    let (top_part, bottom_part) = feature.split_at_mut(HISTOGRAM_BINS);
    top_part.copy_from_slice(&intensity_histogram(top));
    bottom_part.copy_from_slice(&intensity_histogram(bottom));
    feature
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn bin_edges_match_numpy_histogram_over_0_to_255() {
        let edges = [(0, 0), (50, 0), (51, 1), (101, 1), (102, 2), (152, 2)];
        let more = [(153, 3), (203, 3), (204, 4), (254, 4), (255, 4)];
        for (value, bin) in edges.into_iter().chain(more) {
            assert_eq!(bin_of(value), bin, "value {value}");
        }
    }

    #[test]
    fn a_constant_thumbnail_fills_one_bin() {
        let mut bottom = BottomThumbnail::black();
        bottom.as_bytes_mut().fill(120);
        assert_eq!(intensity_histogram(&bottom), [0.0, 0.0, 1.0, 0.0, 0.0]);
    }

    #[test]
    fn gating_feature_puts_top_before_bottom() {
        let top = TopThumbnail::black();
        let mut bottom = BottomThumbnail::black();
        bottom.as_bytes_mut().fill(255);
        let feature = gating_feature(&top, &bottom);
        assert_eq!(feature, [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
    }

    proptest! {
        #[test]
        fn histogram_counts_every_pixel_once(
            bytes in proptest::collection::vec(any::<u8>(), BottomThumbnail::PIXELS)
        ) {
            let thumbnail = BottomThumbnail::from_bytes(&bytes).expect("right length");
            let histogram = intensity_histogram(&thumbnail);
            // The oracle is numpy's rule, not `bin_of`: five equal bins over [0, 255], the
            // last one closed.
            let mut expected = [0.0f32; HISTOGRAM_BINS];
            for value in bytes {
                let bin = (f64::from(value) / 255.0 * 5.0).floor().min(4.0) as usize;
                expected[bin] += 1.0 / BottomThumbnail::PIXELS as f32;
            }
            for (got, want) in histogram.iter().zip(expected) {
                prop_assert!((got - want).abs() < 1e-4);
            }
            prop_assert!((histogram.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        }
    }
}
