//! The instruction sets the engine's kernels are compiled for, and which of them this CPU
//! runs. The kernels are written once, generically ([`super::kernels`]), and compiled once
//! per set inside a `#[target_feature]` function, so each copy uses the widest registers
//! and, where the CPU has it, fused multiply-add. The choice is made at load from CPU
//! detection and can be forced (tests run every path the machine has).
//!
//! Own dispatch instead of a crate: it is a five-way `match` over functions the compiler
//! generates from one generic body, and the tests need to force each path by name, which
//! runtime-dispatch crates hide.

use core::fmt;

use super::kernels::int8::Int8Kernel;
use super::kernels::winograd::Fit;
use core::str::FromStr;

/// A set of instructions the kernels can be compiled for, from the most portable up.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Isa {
    /// No target features beyond the compiler's baseline: runs on any CPU Rust targets.
    Portable,
    /// SSE2: every x86-64 CPU, and the i686 build's baseline.
    Sse2,
    /// SSSE3: the Nao V5's Atom Z530.
    Ssse3,
    /// SSE4.1 and SSE4.2: the Nao V6's Atom E3845.
    Sse42,
    /// AVX2 with FMA: development machines.
    Avx2Fma,
    /// AVX-512 (foundation) with AVX2 and FMA: newer development and server machines;
    /// sixteen lanes and thirty-two registers.
    Avx512,
}

impl Isa {
    pub const ALL: [Self; 6] = [
        Self::Portable,
        Self::Sse2,
        Self::Ssse3,
        Self::Sse42,
        Self::Avx2Fma,
        Self::Avx512,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Self::Portable => "portable",
            Self::Sse2 => "sse2",
            Self::Ssse3 => "ssse3",
            Self::Sse42 => "sse4.2",
            Self::Avx2Fma => "avx2+fma",
            Self::Avx512 => "avx512",
        }
    }

    /// Whether this CPU can run the kernels compiled for `self`.
    pub fn is_available(self) -> bool {
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        {
            match self {
                Self::Portable => true,
                Self::Sse2 => std::arch::is_x86_feature_detected!("sse2"),
                Self::Ssse3 => {
                    Self::Sse2.is_available() && std::arch::is_x86_feature_detected!("ssse3")
                }
                Self::Sse42 => {
                    Self::Ssse3.is_available()
                        && std::arch::is_x86_feature_detected!("sse4.1")
                        && std::arch::is_x86_feature_detected!("sse4.2")
                }
                Self::Avx2Fma => {
                    Self::Sse42.is_available()
                        && std::arch::is_x86_feature_detected!("avx")
                        && std::arch::is_x86_feature_detected!("avx2")
                        && std::arch::is_x86_feature_detected!("fma")
                }
                Self::Avx512 => {
                    Self::Avx2Fma.is_available() && std::arch::is_x86_feature_detected!("avx512f")
                }
            }
        }
        #[cfg(not(any(target_arch = "x86", target_arch = "x86_64")))]
        {
            self == Self::Portable
        }
    }

    /// How many outputs of a dense layer the set's kernel keeps in registers at once: eight
    /// accumulators of AVX2 or of SSE on x86-64 (sixteen registers), four of AVX-512 (a
    /// 2560x128 layer's 128 outputs in two panels), four of SSE on the 32-bit V5 build
    /// (eight registers, two of them for the input and a product).
    pub(crate) fn dense_panel_width(self) -> usize {
        match self {
            Self::Portable => 16,
            Self::Sse2 | Self::Ssse3 | Self::Sse42 if cfg!(target_arch = "x86") => 16,
            Self::Sse2 | Self::Ssse3 | Self::Sse42 => 32,
            Self::Avx2Fma | Self::Avx512 => 64,
        }
    }

    /// Which 5x5 stride-two convolutions with their 2x2 pool this set's kernels compute with
    /// fewer multiplications ([`super::kernels::winograd`]): channels in whole vectors of its
    /// lanes, on every SSE and AVX set; not the portable path. On the 32-bit V5 build (blocks
    /// of one tile by two vectors, what its eight registers hold) only layers of at least 16
    /// input channels: callgrind (`cross/count v5`, `cnn-observable`) counted 5.96 M
    /// instructions a forward with the direct kernels, 5.73 M with both second layers by
    /// Winograd and 5.70 M with the top camera's (16 inputs) alone; the narrow CNN's (8 and
    /// 4 inputs) went from 6.61 M to 6.70 M with its two, where the hand-written direct
    /// kernels win (`cross/README.md`, "Winograd on the V5").
    pub(crate) fn winograd_fit(self) -> Option<Fit> {
        let lanes = match self {
            Self::Portable => return None,
            Self::Sse2 | Self::Ssse3 | Self::Sse42 => 4,
            // AVX-512 takes the AVX2 kernel where its channels are not whole 16-lane vectors.
            Self::Avx2Fma | Self::Avx512 => 8,
        };
        let min_in_channels = if cfg!(target_arch = "x86") { 16 } else { lanes };
        Some(Fit {
            lanes,
            min_in_channels,
        })
    }

    /// The int8 kernel an int8 policy's layers run with under this set: `pmaddubsw` from
    /// SSSE3 on (the V5 and V6 Atoms; with SSE4.2, the V6's set, the maxima with SSE4.1's
    /// `pmaxsd`), on 32 bytes with AVX2 (AVX-512 too: its VNNI is not used), the portable one
    /// below SSSE3.
    pub(crate) fn int8_kernel(self) -> Int8Kernel {
        match self {
            Self::Portable | Self::Sse2 => Int8Kernel::PORTABLE,
            Self::Ssse3 => Int8Kernel::ssse3(),
            Self::Sse42 => Int8Kernel::ssse3_pmaxsd(),
            Self::Avx2Fma | Self::Avx512 => Int8Kernel::avx2(),
        }
    }

    /// Every set this CPU runs, most portable first.
    pub fn available() -> impl Iterator<Item = Self> {
        Self::ALL.into_iter().filter(|isa| isa.is_available())
    }

    /// The widest set this CPU runs.
    pub fn detect() -> Self {
        Self::available().last().unwrap_or(Self::Portable)
    }
}

impl fmt::Display for Isa {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Isa {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|isa| isa.name() == text)
            .ok_or_else(|| {
                let names: Vec<&str> = Self::ALL.iter().map(|isa| isa.name()).collect();
                format!(
                    "unknown instruction set {text:?}; one of {}",
                    names.join(", ")
                )
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The layers each set takes by Winograd: the paper's second layers (16 -> 32, 8 -> 16)
    /// on x86-64; on the V5's i686 only the 16-input one (its direct kernels win below).
    #[test]
    fn winograd_takes_whole_vectors_and_on_the_v5_only_wide_inputs() {
        assert_eq!(Isa::Portable.winograd_fit(), None);
        for isa in [Isa::Sse2, Isa::Ssse3, Isa::Sse42] {
            let fit = isa.winograd_fit().expect("SSE takes Winograd");
            assert!(fit.takes(16, 32), "{isa}");
            assert_eq!(fit.takes(8, 16), cfg!(target_arch = "x86_64"), "{isa}");
            assert_eq!(fit.takes(4, 8), cfg!(target_arch = "x86_64"), "{isa}");
            assert!(
                !fit.takes(18, 32) && !fit.takes(16, 36),
                "{isa}: not whole vectors"
            );
        }
        let avx = Isa::Avx2Fma.winograd_fit().expect("AVX2 takes Winograd");
        assert!(avx.takes(16, 32) && !avx.takes(4, 8));
        assert_eq!(avx.takes(8, 16), cfg!(target_arch = "x86_64"));
    }
}
