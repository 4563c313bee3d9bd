//! A convolution's windows copied out of the int8 code map, kernel row after kernel row.
// The vector kernels are `unsafe`: intrinsics of a `#[target_feature]` the caller checked.
#![allow(unsafe_code)]

#[cfg(target_arch = "x86")]
use std::arch::x86::*;
#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

use super::GROUP;

/// The shape of an int8 convolution's input and window: the codes are the zero-bordered map
/// `[padded_h][padded_w][c]` (the border holds the zero point, the integer of 0.0). A window
/// is copied out of the map into a run of [`Self::padded_len`] bytes, kernel row after kernel
/// row, where the weights `[ky][kx][c]` meet it (zero weights after). Rows of at most 8 bytes
/// (the cameras' one-channel 5x5 layers: 5) are copied with one 8-byte load and store each,
/// longer rows with 16-byte loads and stores (the narrow CNN's 20- and 40-byte rows: two and
/// three): the extra bytes are overwritten by the next row, the last row's lie inside the run
/// and meet zero weights, and the map's buffer holds the bytes the bottom-right window's last
/// row reads past the map ([`Self::slack`]). A `memcpy` call per row was more than the V5
/// could afford: about 50 instructions a 40-byte row with the call, 10 for its three moves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Window {
    pub padded_width: usize,
    pub channels: usize,
    pub kernel: [usize; 2],
    pub stride: [usize; 2],
    /// [`Self::padded_len`], worked out once.
    len: usize,
}

/// Rows up to this many bytes are copied 8 bytes at a time.
const SHORT_ROW: usize = 8;
/// Longer rows are copied this many bytes at a time.
const CHUNK: usize = 16;

impl Window {
    pub(crate) fn new(
        padded_width: usize,
        channels: usize,
        kernel: [usize; 2],
        stride: [usize; 2],
    ) -> Self {
        let mut window = Self {
            padded_width,
            channels,
            kernel,
            stride,
            len: 0,
        };
        window.len = window.extent().div_ceil(GROUP) * GROUP;
        window
    }

    /// The bytes of one kernel row of a window.
    pub(crate) fn row(&self) -> usize {
        self.kernel[1] * self.channels
    }

    /// The bytes one row's copy moves: 8 for a short row, else the row rounded up to whole
    /// 16-byte chunks.
    fn copied(&self) -> usize {
        let row = self.row();
        if row <= SHORT_ROW {
            SHORT_ROW
        } else {
            row.div_ceil(CHUNK) * CHUNK
        }
    }

    /// The bytes a window's copy spans: its rows, the last one's copy whole.
    fn extent(&self) -> usize {
        match self.kernel[0] {
            0 => 0,
            kh => (kh - 1) * self.row() + self.copied(),
        }
    }

    /// The weights' inputs and the bytes of one copied window: its extent rounded up to
    /// whole groups of 16.
    pub(crate) fn padded_len(&self) -> usize {
        self.len
    }

    /// How many bytes past the map a bottom-right window's last row reads (its last load
    /// whole): the codes buffer holds them too.
    pub(crate) fn slack(&self) -> usize {
        self.copied() - self.row()
    }

    /// `rows`, `[out][ky][kx * c]`, laid out as a copied window is: each output's
    /// [`Self::padded_len`] weights, zero after the window.
    pub(crate) fn weights(&self, rows: &[i8], outputs: usize) -> Vec<i8> {
        let len = self.kernel[0] * self.row();
        let mut laid_out = vec![0; outputs * self.padded_len()];
        for (o, weights) in rows.chunks_exact(len.max(1)).take(outputs).enumerate() {
            laid_out[o * self.padded_len()..][..len].copy_from_slice(weights);
        }
        laid_out
    }

    /// Copies the windows of the `rows x columns` output pixels from `(y, x)` on (a max-pool
    /// cell's), row by row, into `out`, one after the other, each [`Self::padded_len`]
    /// bytes: one block of [`Self::gather_cells`].
    #[cfg(test)]
    pub(crate) fn gather_block(
        &self,
        codes: &[u8],
        pixel: [usize; 2],
        block: [usize; 2],
        out: &mut [u8],
    ) {
        self.gather_cells(codes, pixel, block, [1, 1], out);
    }

    /// Copies the windows of `cells` blocks of `rows x columns` output pixels, the first
    /// from pixel `(y, x)` on, each next one `step` pixels to the right (a row of max-pool
    /// cells, or with 1 x 1 blocks a row of pixels), into `out`: block by block, each block
    /// row by row, each window [`Self::padded_len`] bytes. Bounds are checked and the
    /// offsets worked out once per call, not per window or row (the V5's first layer copies
    /// 24,000 rows a forward; callgrind, host AVX2, int8 CNN forward: a check and the
    /// offsets per window cost 0.3 to 0.5 M instructions).
    #[inline(always)]
    pub(crate) fn gather_cells(
        &self,
        codes: &[u8],
        [y, x]: [usize; 2],
        [rows, columns]: [usize; 2],
        [cells, step]: [usize; 2],
        out: &mut [u8],
    ) {
        let (row, kh, len, c) = (self.row(), self.kernel[0], self.len, self.channels);
        if kh == 0 || rows == 0 || columns == 0 || cells == 0 {
            return;
        }
        let pitch = self.padded_width * c;
        // The last block's last window's last row ends furthest into `codes` (its last load
        // whole).
        let copied = self.copied();
        let end = (y + rows - 1)
            .checked_mul(self.stride[0])
            .and_then(|top| top.checked_add(kh - 1))
            .and_then(|bottom| bottom.checked_mul(self.padded_width))
            .and_then(|offset| {
                let last = (cells - 1)
                    .checked_mul(step)?
                    .checked_add(x + columns - 1)?;
                offset.checked_add(last.checked_mul(self.stride[1])?)
            })
            .and_then(|pixel| pixel.checked_mul(c))
            .and_then(|first| first.checked_add(copied));
        let windows = cells.checked_mul(rows * columns);
        assert!(
            end.is_some_and(|end| end <= codes.len())
                && windows.is_some_and(|n| n.checked_mul(len).is_some_and(|n| n <= out.len()))
                && (kh - 1) * row + copied <= len,
            "int8 window outside its map"
        );
        // Byte offsets: of the first window, from block to block, from window row to window
        // row and window to window inside a block.
        let first = ((y * self.stride[0]) * self.padded_width + x * self.stride[1]) * c;
        let (block_step, window_down, window_right) = (
            step * self.stride[1] * c,
            self.stride[0] * pitch,
            self.stride[1] * c,
        );
        let (source, target) = (codes.as_ptr(), out.as_mut_ptr());
        // Window `k` of the call (block by block, each row by row) and where it starts.
        let windows = (0..cells).flat_map(|cell| {
            (0..rows).flat_map(move |dy| {
                (0..columns)
                    .map(move |dx| first + cell * block_step + dy * window_down + dx * window_right)
            })
        });
        // SAFETY (every copy below): row `ky` of each window reads `copied` bytes from
        // `start + ky * pitch`, at most the last window's last row's end, inside `codes`
        // (checked above), and writes them `ky * row` bytes into the window's `len` bytes
        // of `out`, the windows one after the other (all inside `out`, checked above).
        if row > SHORT_ROW {
            // Whole 16-byte chunks; the rows of the CNNs' second layers, specialised.
            let rows = (windows, kh, [pitch, row, len], (source, target));
            // SAFETY: the checks above (`long_rows`' contract).
            unsafe {
                match copied / CHUNK {
                    2 => long_rows(rows, |from, to| copy_chunks::<2>(from, to)),
                    3 => long_rows(rows, |from, to| copy_chunks::<3>(from, to)),
                    chunks => long_rows(rows, |from, to| {
                        for k in 0..chunks {
                            copy_chunks::<1>(from.add(k * CHUNK), to.add(k * CHUNK));
                        }
                    }),
                }
            }
            return;
        }
        if kh == 5 {
            // The CNNs' 5 x 5 kernels, unrolled: five loads and five stores a window, the
            // pointers stepped, not multiplied out again for each window from the iterator's
            // indices (about 30 instructions a window on the V5 that way, callgrind), and the
            // cameras' one-channel rows (5 bytes, windows of 32) with constant offsets: the
            // V5's eight registers then hold the loop (22 instructions a window with the row
            // and the window's length in registers too, 19 without; callgrind).
            macro_rules! five_rows {
                ($row:expr, $len:expr) => {{
                    let (row, len, three) = ($row, $len, 3 * pitch);
                    let mut to = target;
                    for cell in 0..cells {
                        for dy in 0..rows {
                            let mut from =
                                unsafe { source.add(first + cell * block_step + dy * window_down) };
                            for _ in 0..columns {
                                unsafe {
                                    copy_short(from, to);
                                    copy_short(from.add(pitch), to.add(row));
                                    copy_short(from.add(2 * pitch), to.add(2 * row));
                                    copy_short(from.add(three), to.add(3 * row));
                                    copy_short(from.add(three + pitch), to.add(4 * row));
                                    from = from.add(window_right);
                                    to = to.add(len);
                                }
                            }
                        }
                    }
                }};
            }
            if row == 5 && len == 32 {
                five_rows!(5, 32);
            } else {
                five_rows!(row, len);
            }
        } else {
            // SAFETY: the checks above (`long_rows`' contract).
            unsafe {
                long_rows(
                    (windows, kh, [pitch, row, len], (source, target)),
                    |from, to| copy_short(from, to),
                )
            };
        }
    }
}

/// Each window's `kh` rows through `copy_row(from, to)`: from `pitch` bytes apart in the map
/// to `row` bytes apart in the window's `len`, the windows' starts in the map from `windows`.
///
/// # Safety
/// Inside [`Window::gather_cells`], whose checks bound every row `copy_row` is given, and
/// `copy_row` may read and write that row's copy (its `copied` bytes) and no more.
#[inline(always)]
unsafe fn long_rows(
    (windows, kh, [pitch, row, len], (source, target)): (
        impl Iterator<Item = usize>,
        usize,
        [usize; 3],
        (*const u8, *mut u8),
    ),
    copy_row: impl Fn(*const u8, *mut u8),
) {
    for (k, start) in windows.enumerate() {
        for ky in 0..kh {
            // SAFETY: the caller's checks (the window's row `ky`).
            let (from, to) = unsafe {
                (
                    source.add(start + ky * pitch),
                    target.add(k * len + ky * row),
                )
            };
            copy_row(from, to);
        }
    }
}

/// Copies `N` 16-byte chunks from `from` to `to` (unaligned).
///
/// # Safety
/// `16 * N` bytes readable at `from` and writable at `to`.
#[inline(always)]
unsafe fn copy_chunks<const N: usize>(from: *const u8, to: *mut u8) {
    for k in 0..N {
        // SAFETY: the caller's contract; SSE2 is part of every x86 target this crate builds
        // for (i686, x86-64).
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        unsafe {
            _mm_storeu_si128(
                to.add(k * CHUNK).cast::<__m128i>(),
                _mm_loadu_si128(from.add(k * CHUNK).cast::<__m128i>()),
            );
        }
        #[cfg(not(any(target_arch = "x86", target_arch = "x86_64")))]
        unsafe {
            to.add(k * CHUNK)
                .cast::<[u8; CHUNK]>()
                .write_unaligned(from.add(k * CHUNK).cast::<[u8; CHUNK]>().read_unaligned());
        }
    }
}

/// Copies one short row's 8 bytes from `from` to `to` (unaligned). On i686 through an SSE2
/// register (`movq`, a load and a store): as `[u8; 8]` the compiler moved the 8 bytes in two
/// 32-bit halves, four instructions a row (the V5's first layers copy 30,000 short rows a
/// tick; callgrind).
///
/// # Safety
/// 8 bytes readable at `from` and writable at `to`.
#[inline(always)]
unsafe fn copy_short(from: *const u8, to: *mut u8) {
    // SAFETY: the caller's contract; SSE2 as above.
    #[cfg(target_arch = "x86")]
    unsafe {
        _mm_storel_epi64(
            to.cast::<__m128i>(),
            _mm_loadl_epi64(from.cast::<__m128i>()),
        );
    }
    #[cfg(not(target_arch = "x86"))]
    unsafe {
        to.cast::<[u8; SHORT_ROW]>()
            .write_unaligned(from.cast::<[u8; SHORT_ROW]>().read_unaligned());
    }
}
