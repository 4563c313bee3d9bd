//! Which int8 kernel a CPU runs, and the layout each kernel wants.
// The vector kernels are `unsafe`: intrinsics of a `#[target_feature]` the caller checked.
#![allow(unsafe_code)]

use super::WeightOutOfRange;
use super::panels::QuadPanels;
use super::reference::u8s8_max_product_scalar;
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
use super::{
    avx2::{u8s8_max_product_2x16c_avx2, u8s8_max_product_32c_avx2},
    ssse3::u8s8_max_product_ssse3,
};

/// Whether a kernel tests each group of sixteen inputs and skips the groups that are all
/// zero with their weights. The same sums either way; the test costs a few instructions a
/// group and pays where whole groups of zeros are common (after ReLU and max-pooling, and in
/// a dense layer's features, about 40 % zeros), not in a camera's pixels, where it almost
/// never skips (callgrind, V5, narrow int8 CNN on the test pattern: none of the 12,000
/// first-layer groups a tick).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum ZeroGroups {
    Skip,
    Compute,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Int8Kernel(Kind);

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Portable,
    Ssse3,
    /// The SSSE3 kernels with SSE4.1's `pmaxsd` for the maxima (the V6).
    Sse41,
    Avx2,
}

impl Int8Kernel {
    pub(crate) const PORTABLE: Self = Self(Kind::Portable);

    /// SSSE3's kernel where this CPU has SSSE3, else the portable one.
    pub(crate) fn ssse3() -> Self {
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        if std::arch::is_x86_feature_detected!("ssse3") {
            return Self(Kind::Ssse3);
        }
        Self::PORTABLE
    }

    /// The SSSE3 kernels with SSE4.1's `pmaxsd` where this CPU has SSE4.1, else
    /// [`Self::ssse3`].
    pub(crate) fn ssse3_pmaxsd() -> Self {
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        if std::arch::is_x86_feature_detected!("ssse3")
            && std::arch::is_x86_feature_detected!("sse4.1")
        {
            return Self(Kind::Sse41);
        }
        Self::ssse3()
    }

    /// AVX2's kernel where this CPU has AVX2, else the widest it has.
    pub(crate) fn avx2() -> Self {
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        if std::arch::is_x86_feature_detected!("avx2") {
            return Self(Kind::Avx2);
        }
        Self::ssse3_pmaxsd()
    }

    pub(crate) fn name(self) -> &'static str {
        match self.0 {
            Kind::Portable => "portable",
            Kind::Ssse3 => "ssse3",
            Kind::Sse41 => "sse4.1",
            Kind::Avx2 => "avx2",
        }
    }

    /// `rows`, `[out][in]`, laid out for this kernel: panels of 16 outputs, or on AVX2
    /// panels of 32 where the layer has more than 16 outputs and [`QuadPanels::pairs`]
    /// where it has 9 to 16 (a 32-wide panel of a 16-output layer would be half zeros),
    /// and on SSSE3 (and on AVX2, with SSE4.1's kernels) one panel of 8 where it has at
    /// most 8 (of 4 where at most 4).
    pub(crate) fn lay_out(
        self,
        rows: &[i8],
        outputs: usize,
        inputs: usize,
    ) -> Result<QuadPanels, WeightOutOfRange> {
        match self.0 {
            // At most eight outputs (the narrow networks' first layers) the SSE4.1 kernels'
            // 4- and 8-wide panels beat AVX2's pairs of 16, half of them zeros (robot
            // package, avx2+fma: the top camera's 1->4 layer 42.5 µs with the pairs, 25.2 µs
            // on SSSE3's panel: `dribble-controller forward --layers`).
            Kind::Avx2 if outputs <= 4 => QuadPanels::new(rows, outputs, inputs, 4),
            Kind::Avx2 if outputs <= 8 => QuadPanels::new(rows, outputs, inputs, 8),
            Kind::Avx2 if outputs > 16 => QuadPanels::new(rows, outputs, inputs, 32),
            Kind::Avx2 => QuadPanels::pairs(rows, outputs, inputs),
            Kind::Ssse3 | Kind::Sse41 if outputs <= 4 => QuadPanels::new(rows, outputs, inputs, 4),
            Kind::Ssse3 | Kind::Sse41 if outputs <= 8 => QuadPanels::new(rows, outputs, inputs, 8),
            _ => QuadPanels::new(rows, outputs, inputs, 16),
        }
    }

    /// The pooled sums of row `py` of a one-channel layer's 2x2 pool (`pool`: window,
    /// stride, pooled size), `sums[q * 4 + o]`, by [`super::pooled_pixels`] from the code map
    /// `codes`, where this kernel has it (SSSE3 and up) and the layer and pool are its;
    /// false, nothing written, where not. The same exact sums as [`Self::largest`] on the
    /// pool cells' windows.
    #[cfg(target_arch = "x86_64")]
    #[inline]
    pub(crate) fn pooled_pixel_row(
        self,
        weights: &super::PooledPixelWeights,
        codes: &[u8],
        pool: [[usize; 2]; 3],
        py: usize,
        sums: &mut [i32],
    ) -> bool {
        use super::pooled_pixels::{OUTPUTS, pooled_row_sse41, pooled_row_ssse3};
        let [_, _, [ph, pw]] = pool;
        if py >= ph || sums.len() < pw * OUTPUTS || !weights.takes_pool(pool, codes.len()) {
            return false;
        }
        match self.0 {
            // SAFETY: a `Kind::Ssse3` is made only where SSSE3 was detected; the shapes
            // checked above (`takes_pool`, the row, the sums).
            Kind::Ssse3 => unsafe { pooled_row_ssse3(weights, codes, py, pw, sums) },
            // SAFETY: a `Kind::Sse41` or `Kind::Avx2` only where SSE4.1 was detected too (every
            // AVX2 CPU has it); shapes as above.
            Kind::Sse41 | Kind::Avx2 => unsafe { pooled_row_sse41(weights, codes, py, pw, sums) },
            Kind::Portable => return false,
        }
        true
    }

    /// `acc[o] = max over rows r of (W x_r)[o]` in exact integers for each cell of `acc`,
    /// `x` holding each cell's whole rows of [`QuadPanels::padded_inputs`] bytes one after
    /// the other ([`u8s8_max_product_scalar`]); `weights` laid out for this kernel
    /// ([`Self::lay_out`]; each kernel checks its layout). One row is a plain product.
    #[inline]
    pub(crate) fn largest(
        self,
        x: &[u8],
        weights: &QuadPanels,
        acc: &mut [i32],
        zeros: ZeroGroups,
    ) {
        match self.0 {
            #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
            // SAFETY: a `Kind::Ssse3` is made only where SSSE3 was detected, a `Kind::Sse41`
            // only where SSE4.1 was too; each kernel checks its layout.
            Kind::Ssse3 | Kind::Sse41 => unsafe {
                u8s8_max_product_ssse3(x, weights, acc, zeros, self.0 == Kind::Sse41)
            },
            #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
            // SAFETY: a `Kind::Avx2` is made only where AVX2 was detected, and every AVX2
            // CPU has SSE4.1; the 4- and 8-wide panels are SSE4.1's (`Self::lay_out`).
            Kind::Avx2 if weights.width <= 8 && !weights.pairs => unsafe {
                u8s8_max_product_ssse3(x, weights, acc, zeros, true)
            },
            #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
            // SAFETY: a `Kind::Avx2` is made only where AVX2 was detected; layout checked.
            Kind::Avx2 if weights.pairs => unsafe {
                u8s8_max_product_2x16c_avx2(x, weights, acc, zeros)
            },
            #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
            // SAFETY: as above; 32 wide.
            Kind::Avx2 => unsafe { u8s8_max_product_32c_avx2(x, weights, acc, zeros) },
            _ => u8s8_max_product_scalar(x, weights, acc),
        }
    }
}
