//! Camera frames: packed YUYV images of a fixed size behind the header of DESIGN.md.
//!
//! A frame is one `#[repr(C)]` block with no pointers (header, then the pixel bytes inline),
//! so the same type can live in shared memory between the camera driver and the controller.
//! Its size is fixed by the camera: [`TopFrame`] is 640x480, [`BottomFrame`] 320x240.

use core::fmt;

use crate::units::Timestamp;

/// FourCC of packed YUV 4:2:2 (`Y0 U Y1 V` for each pixel pair), as V4L2 names it.
pub const YUYV_FOURCC: u32 = u32::from_le_bytes(*b"YUYV");

/// Which of the Nao's two head cameras a frame comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CameraPosition {
    Top,
    Bottom,
}

impl CameraPosition {
    pub const ALL: [Self; 2] = [Self::Top, Self::Bottom];

    pub const fn index(self) -> usize {
        match self {
            Self::Top => 0,
            Self::Bottom => 1,
        }
    }
}

impl fmt::Display for CameraPosition {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Top => "top",
            Self::Bottom => "bottom",
        })
    }
}

/// The header in front of every frame's pixels (DESIGN.md, "Shared memory").
///
/// Layout, little-endian, 32 bytes on both i686 and x86_64: `sequence: u64` at 0,
/// `timestamp_ns: u64` at 8, `width: u32` at 16, `height: u32` at 20, `format: u32` (FourCC)
/// at 24, `reserved: u32` (zero) at 28.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameHeader {
    /// Counts up by one per frame of this camera; gaps are dropped frames.
    pub sequence: u64,
    /// Exposure time on the shared monotonic clock.
    pub timestamp_ns: u64,
    pub width: u32,
    pub height: u32,
    /// FourCC of the pixel format; only [`YUYV_FOURCC`] is accepted.
    pub format: u32,
    /// Keeps the header the same size on 32- and 64-bit robots; always zero.
    pub reserved: u32,
}

impl FrameHeader {
    /// The header of a YUYV frame of the given size.
    pub const fn yuyv(sequence: u64, timestamp: Timestamp, width: u32, height: u32) -> Self {
        Self {
            sequence,
            timestamp_ns: timestamp.as_nanos(),
            width,
            height,
            format: YUYV_FOURCC,
            reserved: 0,
        }
    }

    pub const fn timestamp(&self) -> Timestamp {
        Timestamp::from_nanos(self.timestamp_ns)
    }
}

/// Why bytes or a header do not make a valid frame of the expected camera.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    #[error(
        "frame must be {expected_width}x{expected_height} pixels, found {found_width}x{found_height}"
    )]
    WrongSize {
        expected_width: u32,
        expected_height: u32,
        found_width: u32,
        found_height: u32,
    },
    #[error("frame must be packed YUYV (FourCC {:?}), found FourCC {}", "YUYV", FourCc(*found))]
    UnsupportedFormat { found: u32 },
    #[error("a {width}x{height} YUYV frame has {expected} bytes, found {found}")]
    WrongByteCount {
        width: u32,
        height: u32,
        expected: usize,
        found: usize,
    },
}

/// Prints a FourCC as its four characters where they are printable, else as hex.
struct FourCc(u32);

impl fmt::Display for FourCc {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let bytes = self.0.to_le_bytes();
        if bytes.iter().all(|b| b.is_ascii_graphic() || *b == b' ') {
            write!(f, "{:?}", core::str::from_utf8(&bytes).unwrap_or("????"))
        } else {
            write!(f, "{:#010x}", self.0)
        }
    }
}

/// One camera image of `WIDTH` x `HEIGHT` pixels, packed YUYV, with its header.
///
/// Each row holds `WIDTH` two-byte pixels: even pixels carry `[Y, U]`, odd pixels `[Y, V]`.
#[repr(C)]
pub struct CameraFrame<const WIDTH: usize, const HEIGHT: usize> {
    header: FrameHeader,
    pixels: [[[u8; 2]; WIDTH]; HEIGHT],
}

/// A frame of the top camera, 640x480 (614,400 pixel bytes).
pub type TopFrame = CameraFrame<640, 480>;
/// A frame of the bottom camera, 320x240 (153,600 pixel bytes).
pub type BottomFrame = CameraFrame<320, 240>;

impl<const WIDTH: usize, const HEIGHT: usize> CameraFrame<WIDTH, HEIGHT> {
    pub const WIDTH: u32 = {
        assert!(
            WIDTH.is_multiple_of(2) && WIDTH <= u32::MAX as usize,
            "YUYV needs an even width"
        );
        WIDTH as u32
    };
    pub const HEIGHT: u32 = {
        assert!(HEIGHT <= u32::MAX as usize);
        HEIGHT as u32
    };
    /// Bytes of pixel data: two per pixel.
    pub const PIXEL_BYTES: usize = WIDTH * HEIGHT * 2;

    /// An all-zero frame on the heap. Frames are large (a top frame is 600 KiB), so they are
    /// made once at start-up and filled in place afterwards.
    pub fn new_boxed() -> Box<Self> {
        let frame = Box::<Self>::new_zeroed();
        // SAFETY: every field is an integer or an array of integers, for which all-zero bytes
        // are a valid value.
        #[allow(unsafe_code)]
        unsafe {
            frame.assume_init()
        }
    }

    /// Checks that `header` describes a YUYV frame of this size.
    pub fn check_header(header: &FrameHeader) -> Result<(), FrameError> {
        if header.width != Self::WIDTH || header.height != Self::HEIGHT {
            return Err(FrameError::WrongSize {
                expected_width: Self::WIDTH,
                expected_height: Self::HEIGHT,
                found_width: header.width,
                found_height: header.height,
            });
        }
        if header.format != YUYV_FOURCC {
            return Err(FrameError::UnsupportedFormat {
                found: header.format,
            });
        }
        Ok(())
    }

    /// Overwrites this frame with `header` and the packed YUYV `bytes`, after checking both.
    /// On error the frame is left unchanged.
    pub fn fill_from_yuyv(&mut self, header: FrameHeader, bytes: &[u8]) -> Result<(), FrameError> {
        Self::check_header(&header)?;
        if bytes.len() != Self::PIXEL_BYTES {
            return Err(FrameError::WrongByteCount {
                width: Self::WIDTH,
                height: Self::HEIGHT,
                expected: Self::PIXEL_BYTES,
                found: bytes.len(),
            });
        }
        self.header = header;
        self.as_bytes_mut().copy_from_slice(bytes);
        Ok(())
    }

    /// A boxed frame from `header` and packed YUYV `bytes`.
    pub fn from_yuyv(header: FrameHeader, bytes: &[u8]) -> Result<Box<Self>, FrameError> {
        let mut frame = Self::new_boxed();
        frame.fill_from_yuyv(header, bytes)?;
        Ok(frame)
    }

    pub const fn header(&self) -> &FrameHeader {
        &self.header
    }

    /// The header, for a producer that writes a frame in place (a camera driver filling
    /// shared memory). Consumers must not trust it: they call [`Self::check_header`].
    pub fn header_mut(&mut self) -> &mut FrameHeader {
        &mut self.header
    }

    /// Sets the sequence number and time stamp, keeping size and format valid.
    pub fn restamp(&mut self, sequence: u64, timestamp: Timestamp) {
        self.header = FrameHeader::yuyv(sequence, timestamp, Self::WIDTH, Self::HEIGHT);
    }

    /// Row `y` as `WIDTH` two-byte pixels.
    pub fn row(&self, y: usize) -> &[[u8; 2]; WIDTH] {
        &self.pixels[y]
    }

    pub fn rows(&self) -> &[[[u8; 2]; WIDTH]; HEIGHT] {
        &self.pixels
    }

    /// Mutable pixel rows, for a camera driver or renderer writing into the frame.
    pub fn rows_mut(&mut self) -> &mut [[[u8; 2]; WIDTH]; HEIGHT] {
        &mut self.pixels
    }

    /// Luma (Y) of pixel (`x`, `y`).
    pub fn luma(&self, x: usize, y: usize) -> u8 {
        self.pixels[y][x][0]
    }

    /// All pixel bytes, row-major, as the camera delivers them.
    pub fn as_bytes(&self) -> &[u8] {
        self.pixels.as_flattened().as_flattened()
    }

    pub fn as_bytes_mut(&mut self) -> &mut [u8] {
        self.pixels.as_flattened_mut().as_flattened_mut()
    }

    /// Makes this frame a copy of `other`, header and pixels, without a temporary.
    pub fn copy_from(&mut self, other: &Self) {
        self.header = other.header;
        self.pixels.copy_from_slice(&other.pixels);
    }
}

impl<const WIDTH: usize, const HEIGHT: usize> fmt::Debug for CameraFrame<WIDTH, HEIGHT> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("CameraFrame")
            .field("header", &self.header)
            .finish_non_exhaustive()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(width: u32, height: u32) -> FrameHeader {
        FrameHeader::yuyv(7, Timestamp::from_nanos(1_000), width, height)
    }

    #[test]
    fn header_is_32_bytes_with_the_documented_offsets() {
        assert_eq!(size_of::<FrameHeader>(), 32);
        assert_eq!(core::mem::offset_of!(FrameHeader, sequence), 0);
        assert_eq!(core::mem::offset_of!(FrameHeader, timestamp_ns), 8);
        assert_eq!(core::mem::offset_of!(FrameHeader, width), 16);
        assert_eq!(core::mem::offset_of!(FrameHeader, height), 20);
        assert_eq!(core::mem::offset_of!(FrameHeader, format), 24);
    }

    #[test]
    fn frames_hold_their_pixels_inline() {
        assert_eq!(size_of::<TopFrame>(), 32 + 640 * 480 * 2);
        assert_eq!(size_of::<BottomFrame>(), 32 + 320 * 240 * 2);
    }

    #[test]
    fn builds_a_frame_from_matching_bytes() {
        let bytes: Vec<u8> = (0..BottomFrame::PIXEL_BYTES).map(|i| i as u8).collect();
        let frame = BottomFrame::from_yuyv(header(320, 240), &bytes).expect("valid frame");
        assert_eq!(frame.header().sequence, 7);
        assert_eq!(frame.as_bytes(), &bytes[..]);
        assert_eq!(frame.luma(1, 0), 2);
        assert_eq!(frame.luma(0, 1), (640 % 256) as u8);
    }

    #[test]
    fn rejects_a_frame_of_the_other_camera() {
        let bytes = vec![0; TopFrame::PIXEL_BYTES];
        let error = BottomFrame::from_yuyv(header(640, 480), &bytes).expect_err("wrong size");
        assert_eq!(
            error,
            FrameError::WrongSize {
                expected_width: 320,
                expected_height: 240,
                found_width: 640,
                found_height: 480
            }
        );
        assert_eq!(
            error.to_string(),
            "frame must be 320x240 pixels, found 640x480"
        );
    }

    #[test]
    fn rejects_a_truncated_buffer_and_leaves_the_frame_unchanged() {
        let mut frame = BottomFrame::new_boxed();
        let error = frame
            .fill_from_yuyv(header(320, 240), &[1; 1000])
            .expect_err("short buffer");
        assert_eq!(
            error,
            FrameError::WrongByteCount {
                width: 320,
                height: 240,
                expected: 153_600,
                found: 1000
            }
        );
        assert_eq!(frame.header().sequence, 0);
        assert!(frame.as_bytes().iter().all(|&b| b == 0));
    }

    #[test]
    fn rejects_other_pixel_formats_and_names_them() {
        let mut nv12 = header(320, 240);
        nv12.format = u32::from_le_bytes(*b"NV12");
        let error = BottomFrame::check_header(&nv12).expect_err("wrong format");
        assert_eq!(
            error.to_string(),
            "frame must be packed YUYV (FourCC \"YUYV\"), found FourCC \"NV12\""
        );
        let mut garbage = header(320, 240);
        garbage.format = 0x0102_0304;
        let error = BottomFrame::check_header(&garbage).expect_err("wrong format");
        assert!(
            error.to_string().ends_with("found FourCC 0x01020304"),
            "{error}"
        );
    }
}
