//! Thumbnails: the grayscale images the policy sees, 4x4 block means of a frame's luma.
//!
//! DESIGN.md: 640x480 becomes 160x120 and 320x240 becomes 80x60, `u8`, row-major. Each
//! thumbnail pixel is the mean of the 16 Y values of its block, rounded half up:
//! `(sum + 8) / 16` in integers, so a block of 16 equal values keeps that value.

use crate::frame::CameraFrame;

/// A grayscale image of `WIDTH` x `HEIGHT` pixels, row-major.
#[repr(C)]
#[derive(Clone, PartialEq, Eq)]
pub struct Thumbnail<const WIDTH: usize, const HEIGHT: usize> {
    pixels: [[u8; WIDTH]; HEIGHT],
}

/// The top camera's thumbnail, 160x120.
pub type TopThumbnail = Thumbnail<160, 120>;
/// The bottom camera's thumbnail, 80x60.
pub type BottomThumbnail = Thumbnail<80, 60>;

/// Side of the square block that one thumbnail pixel averages.
pub const BLOCK: usize = 4;

impl<const WIDTH: usize, const HEIGHT: usize> Thumbnail<WIDTH, HEIGHT> {
    pub const WIDTH: usize = WIDTH;
    pub const HEIGHT: usize = HEIGHT;
    pub const PIXELS: usize = WIDTH * HEIGHT;

    /// A black thumbnail.
    pub const fn black() -> Self {
        Self {
            pixels: [[0; WIDTH]; HEIGHT],
        }
    }

    /// A thumbnail from row-major bytes; `None` unless there are exactly `WIDTH * HEIGHT`.
    pub fn from_bytes(bytes: &[u8]) -> Option<Self> {
        let mut thumbnail = Self::black();
        if bytes.len() != Self::PIXELS {
            return None;
        }
        thumbnail.as_bytes_mut().copy_from_slice(bytes);
        Some(thumbnail)
    }

    pub fn pixel(&self, x: usize, y: usize) -> u8 {
        self.pixels[y][x]
    }

    pub fn rows(&self) -> &[[u8; WIDTH]; HEIGHT] {
        &self.pixels
    }

    pub fn as_bytes(&self) -> &[u8] {
        self.pixels.as_flattened()
    }

    pub fn as_bytes_mut(&mut self) -> &mut [u8] {
        self.pixels.as_flattened_mut()
    }
}

impl<const WIDTH: usize, const HEIGHT: usize> core::fmt::Debug for Thumbnail<WIDTH, HEIGHT> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "Thumbnail<{WIDTH}x{HEIGHT}>")
    }
}

/// Luma bytes of a YUYV pixel pair group: bytes 0, 2, 4 and 6 of eight little-endian bytes,
/// each left in its own 16-bit lane.
const LUMA_LANES: u64 = 0x00FF_00FF_00FF_00FF;
/// Multiplying by this adds the four 16-bit lanes into the top lane.
const SUM_LANES: u64 = 0x0001_0001_0001_0001;

/// Downscales `frame` into `out` by 4x4 block means of the luma channel. Allocation-free.
/// On x86 (both Naos) with SSE2's `psadbw` ([`downscale_sse2`]), elsewhere in plain integers
/// ([`downscale_portable`]); the two give the same bytes.
pub fn downscale<const FW: usize, const FH: usize, const TW: usize, const TH: usize>(
    frame: &CameraFrame<FW, FH>,
    out: &mut Thumbnail<TW, TH>,
) {
    // SAFETY: this build's every function runs SSE2 (the cfg: both Nao targets and x86-64).
    #[cfg(all(
        any(target_arch = "x86", target_arch = "x86_64"),
        target_feature = "sse2"
    ))]
    #[allow(unsafe_code)]
    unsafe {
        downscale_sse2(frame, out);
    }
    #[cfg(not(all(
        any(target_arch = "x86", target_arch = "x86_64"),
        target_feature = "sse2"
    )))]
    downscale_portable(frame, out);
}

/// [`downscale`] in plain integer code, eight bytes (four pixels, one block row) at a time:
/// masking keeps the four Y bytes in separate 16-bit lanes, four block rows are added
/// lane-wise (at most 4 x 255 per lane, no overflow), and one multiplication adds the lanes.
pub fn downscale_portable<const FW: usize, const FH: usize, const TW: usize, const TH: usize>(
    frame: &CameraFrame<FW, FH>,
    out: &mut Thumbnail<TW, TH>,
) {
    const {
        assert!(
            FW == BLOCK * TW && FH == BLOCK * TH,
            "a thumbnail is a quarter of the frame in each direction"
        );
    }
    let block_rows = frame.rows().chunks_exact(BLOCK);
    for (out_row, block_row) in out.pixels.iter_mut().zip(block_rows) {
        let mut lane_sums = [0u64; TW];
        for frame_row in block_row {
            let (groups, _) = frame_row.as_flattened().as_chunks::<8>();
            for (lanes, group) in lane_sums.iter_mut().zip(groups) {
                *lanes += u64::from_le_bytes(*group) & LUMA_LANES;
            }
        }
        for (pixel, lanes) in out_row.iter_mut().zip(lane_sums) {
            let sum = lanes.wrapping_mul(SUM_LANES) >> 48;
            // sum <= 16 * 255, so the rounded mean fits a u8.
            *pixel = ((sum + 8) >> 4) as u8;
        }
    }
}

/// [`downscale`] with SSE2, eight thumbnail pixels (a 64-byte stretch of four frame rows) at a
/// time, in 16-bit lanes throughout: per 16 bytes (two blocks' rows) the four rows are loaded,
/// masked to their Y bytes and added lane-wise (column sums, at most 4 x 255), one `pmaddwd`
/// against ones adds neighbouring columns into 32-bit lanes, and two packs and one more
/// `pmaddwd` finish the eight block sums (at most 16 x 255, exact in 16 bits), which are
/// rounded, shifted and packed to bytes. About 8.4 instructions a thumbnail pixel on the
/// V5's build (callgrind, `forward --whole-tick`), where the block-row `psadbw` variant
/// before it took about thirteen and the 64-bit integer code about twenty on 32-bit
/// registers. Why intrinsics: no crate downscales YUYV luma by 4x4 means, and the tick's
/// budget is the point of the module.
#[cfg(all(
    any(target_arch = "x86", target_arch = "x86_64"),
    target_feature = "sse2"
))]
#[allow(unsafe_code)]
#[target_feature(enable = "sse2")]
fn downscale_sse2<const FW: usize, const FH: usize, const TW: usize, const TH: usize>(
    frame: &CameraFrame<FW, FH>,
    out: &mut Thumbnail<TW, TH>,
) {
    #[cfg(target_arch = "x86")]
    use core::arch::x86::*;
    #[cfg(target_arch = "x86_64")]
    use core::arch::x86_64::*;
    const {
        assert!(
            FW == BLOCK * TW && FH == BLOCK * TH,
            "a thumbnail is a quarter of the frame in each direction"
        );
        assert!(TW.is_multiple_of(8), "eight thumbnail pixels a step");
    }
    let luma = _mm_set1_epi16(0x00ff);
    let ones = _mm_set1_epi16(1);
    let half = _mm_set1_epi16(8);
    let block_rows = frame.rows().chunks_exact(BLOCK);
    for (out_row, block_row) in out.pixels.iter_mut().zip(block_rows) {
        // Each frame row is 2 x FW = 8 x TW bytes: TW / 8 stretches of 64, read through
        // pointers stepped 64 bytes a stretch (the row lengths are the const assertion's).
        let mut rows: [*const u8; BLOCK] =
            core::array::from_fn(|k| block_row[k].as_flattened().as_ptr());
        let mut pixels = out_row.as_mut_ptr();
        for _ in 0..TW / 8 {
            // The column sums of 16 bytes of the four rows, neighbours added: 32-bit lanes
            // [a01, a23, b01, b23] for the two blocks a and b those bytes cover.
            let pairs = |offset: usize| {
                // SAFETY: offset + 16 <= 64 and the stretch lies inside each row (above).
                let load = |k: usize| unsafe {
                    _mm_and_si128(_mm_loadu_si128(rows[k].add(offset).cast::<__m128i>()), luma)
                };
                let columns = _mm_add_epi16(
                    _mm_add_epi16(load(0), load(1)),
                    _mm_add_epi16(load(2), load(3)),
                );
                _mm_madd_epi16(columns, ones)
            };
            // [a01, a23, b01, b23, c01, c23, d01, d23] in 16 bits, then [a, b, c, d] in 32.
            let low = _mm_madd_epi16(_mm_packs_epi32(pairs(0), pairs(16)), ones);
            let high = _mm_madd_epi16(_mm_packs_epi32(pairs(32), pairs(48)), ones);
            let sums = _mm_packs_epi32(low, high);
            let means = _mm_srli_epi16::<4>(_mm_add_epi16(sums, half));
            let bytes = _mm_packus_epi16(means, means);
            // SAFETY: eight pixels of the row remain (TW / 8 steps of eight); the store
            // writes the low 8 bytes. The row pointers step to the next 64-byte stretch.
            unsafe {
                _mm_storel_epi64(pixels.cast::<__m128i>(), bytes);
                pixels = pixels.add(8);
                for row in &mut rows {
                    *row = row.add(64);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::{BottomFrame, FrameHeader, TopFrame};
    use crate::units::Timestamp;
    use proptest::prelude::*;

    /// The definition, written the obvious way.
    fn naive_downscale<const FW: usize, const FH: usize, const TW: usize, const TH: usize>(
        frame: &CameraFrame<FW, FH>,
    ) -> Thumbnail<TW, TH> {
        let mut out = Thumbnail::black();
        for ty in 0..TH {
            for tx in 0..TW {
                let mut sum = 0u32;
                for y in ty * 4..ty * 4 + 4 {
                    for x in tx * 4..tx * 4 + 4 {
                        sum += u32::from(frame.luma(x, y));
                    }
                }
                out.pixels[ty][tx] = ((sum as f64 / 16.0) + 0.5).floor() as u8;
            }
        }
        out
    }

    fn frame_from<const W: usize, const H: usize>(bytes: &[u8]) -> Box<CameraFrame<W, H>> {
        let header = FrameHeader::yuyv(
            0,
            Timestamp::ZERO,
            CameraFrame::<W, H>::WIDTH,
            CameraFrame::<W, H>::HEIGHT,
        );
        CameraFrame::from_yuyv(header, bytes).expect("valid frame")
    }

    /// A frame whose every pixel has luma `luma` and chroma `chroma` (YUYV: Y in the even
    /// bytes, U and V in the odd ones).
    fn uniform_frame<const W: usize, const H: usize>(
        luma: u8,
        chroma: u8,
    ) -> Box<CameraFrame<W, H>> {
        let bytes: Vec<u8> = (0..CameraFrame::<W, H>::PIXEL_BYTES)
            .map(|i| if i % 2 == 0 { luma } else { chroma })
            .collect();
        frame_from::<W, H>(&bytes)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]

        #[test]
        fn block_means_equal_the_naive_reference_on_random_bottom_images(
            bytes in proptest::collection::vec(any::<u8>(), BottomFrame::PIXEL_BYTES)
        ) {
            let frame = frame_from::<320, 240>(&bytes);
            let mut fast = BottomThumbnail::black();
            downscale(&frame, &mut fast);
            prop_assert!(fast == naive_downscale(&frame));
            let mut portable = BottomThumbnail::black();
            downscale_portable(&frame, &mut portable);
            prop_assert!(portable == fast);
        }

        #[test]
        fn block_means_equal_the_naive_reference_on_random_top_images(seed in any::<u64>()) {
            // A 600 KiB strategy shrinks slowly; derive the bytes from a seed instead.
            let mut state = seed | 1;
            let bytes: Vec<u8> = (0..TopFrame::PIXEL_BYTES)
                .map(|_| {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    (state >> 32) as u8
                })
                .collect();
            let frame = frame_from::<640, 480>(&bytes);
            let mut fast = TopThumbnail::black();
            downscale(&frame, &mut fast);
            prop_assert!(fast == naive_downscale(&frame));
            let mut portable = TopThumbnail::black();
            downscale_portable(&frame, &mut portable);
            prop_assert!(portable == fast);
        }

        #[test]
        fn a_constant_luma_gives_that_constant(luma in any::<u8>(), chroma in any::<u8>()) {
            let mut thumbnail = TopThumbnail::black();
            downscale(&uniform_frame::<640, 480>(luma, chroma), &mut thumbnail);
            prop_assert!(thumbnail.as_bytes().iter().all(|&p| p == luma));
        }
    }

    #[test]
    fn the_largest_block_sums_do_not_saturate() {
        // Every luma 255: each block sums to 16 x 255, the most any lane of the packs holds.
        let mut thumbnail = TopThumbnail::black();
        downscale(&uniform_frame::<640, 480>(255, 0), &mut thumbnail);
        assert!(thumbnail.as_bytes().iter().all(|&p| p == 255));
    }

    #[test]
    fn chroma_does_not_leak_into_the_thumbnail() {
        let mut thumbnail = BottomThumbnail::black();
        downscale(&uniform_frame::<320, 240>(0, 255), &mut thumbnail);
        assert!(thumbnail.as_bytes().iter().all(|&p| p == 0));
    }

    #[test]
    fn means_round_half_up() {
        // Eight 0s and eight 1s per block: mean 0.5 rounds to 1; one 1 in 16 rounds to 0.
        let mut frame = BottomFrame::new_boxed();
        for (y, row) in frame.rows_mut().iter_mut().enumerate() {
            for (x, pixel) in row.iter_mut().enumerate() {
                let left_half = x % 4 < 2;
                let in_first_block_column = x < 4;
                pixel[0] = if in_first_block_column {
                    u8::from(x == 0 && y % 4 == 0 && y < 4)
                } else {
                    u8::from(left_half)
                };
            }
        }
        let mut thumbnail = BottomThumbnail::black();
        downscale(&frame, &mut thumbnail);
        assert_eq!(thumbnail.pixel(0, 0), 0, "1/16 rounds down");
        assert_eq!(thumbnail.pixel(1, 0), 1, "8/16 rounds up");
        assert_eq!(thumbnail.pixel(1, 5), 1);
    }

    #[test]
    fn thumbnail_from_bytes_checks_the_length() {
        assert!(BottomThumbnail::from_bytes(&[0; 4800]).is_some());
        assert!(BottomThumbnail::from_bytes(&[0; 4799]).is_none());
    }
}
